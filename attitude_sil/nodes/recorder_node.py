"""``recorder`` node: writes every topic of the run to a rosbag2 MCAP bag.

Raw (serialized CDR) subscriptions go straight into
:class:`attitude_sil.storage.writer.BagWriter`, so recording costs no
deserialization. The log time of a message is its header stamp (sim time),
read from the CDR bytes, so a bag replays with its simulated timing;
``/parameter_events`` (stamped by each node's clock, wall time before
``use_sim_time`` takes effect) are logged at the latest lockstep stamp. The
node also keeps the raw messages of chosen topics in memory for the runner's
metrics, or hands them to a sink that keeps running sums. Stray messages (a
/clock that jumps, a stamp far ahead of the clock: foreign or corrupt
publishers) are not recorded, counted in ``refused`` and logged once a second.

Joining a running graph (``attitude-sil record``, ``episode``) it reads
without the publishers' transient-local history (``history=False``: that
history is the previous episode) and registers each topic in the bag when its
first publisher appears, with the QoS its publishers offer (``qos_from_graph``),
as ``ros2 bag record`` does. A ``live`` sink
(:class:`~attitude_sil.storage.foxglove.FoxgloveLive`) gets every recorded
message too, and the active ``controller_type`` from ``/parameter_events``.

The 3D view's topics (:data:`~attitude_sil.ros.contract.VIEW_TOPICS`) are
written here, to the bag and the live sink, since no node can publish
``tf2_msgs/msg/TFMessage`` (no wheel on PyPI): ``tf`` with each recorded
``attitude``, at its stamp (``body`` in ``inertial``, and ``lvlh`` in
``inertial`` where the scene has an orbit), and ``body_model`` with the
episode's first attitude (to the live sink again every
:data:`MODEL_PERIOD_NS` of sim time, for clients that connect later). The
frames and the model are the scene's (:func:`attitude_sil.core.plant.scene.body_scene`,
:meth:`Recorder.set_scene`); without one, ``tf`` carries the body alone.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable

import numpy as np
from rcl_interfaces.msg import ParameterEvent
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.serialization import deserialize_message

from attitude_sil.core.analysis.latency import CommandArrivals
from attitude_sil.core.plant.quaternion import unit_or_none
from attitude_sil.core.plant.scene import BODY, INERTIAL, BodyScene
from attitude_sil.errors import BagWriteError
from attitude_sil.ros.contract import (
    ATTITUDE,
    BODY_MODEL,
    CLOCK,
    COMMAND_TOPICS,
    DIAGNOSTICS,
    PARAMETER_EVENTS,
    RECORDED_TOPICS,
    TF,
    VIEW_TOPICS,
    message_class,
)
from attitude_sil.ros.convert import fault_lines
from attitude_sil.ros.qos import (
    INPUT_QOS,
    LOCKSTEP_QOS,
    PARAMETER_EVENTS_QOS,
    offered_qos_yaml,
    publishers_qos_yaml,
    qos_event_callbacks,
)
from attitude_sil.storage.cdr import TfLayout, marker_array_cdr, stamp_from_cdr, stamped_values
from attitude_sil.storage.writer import BagWriter

#: the most the clock may jump forward between two /clock messages (a control step is far less)
MAX_CLOCK_JUMP_NS = 10_000_000_000
#: how far ahead of the latest /clock a message may be stamped and still be recorded
MAX_CLOCK_LEAD_NS = 1_000_000_000
#: sim time between two body models sent to the live sink, ns
MODEL_PERIOD_NS = 1_000_000_000


class Recorder(Node):
    """Records topics to a bag and/or keeps them for metrics.

    Parameters
    ----------
    writer : BagWriter or None
        Where to record; None keeps only the in-memory copies.
    keep : iterable of str
        Relative topic names whose raw messages stay in memory (``kept``).
    topics : dict, optional
        ``name -> type``; default :data:`~attitude_sil.ros.contract.RECORDED_TOPICS`
        (every topic of the contract plus ``/parameter_events``).
    live : FoxgloveLive, optional
        A sink that gets every recorded message as well (``add_topic``, ``write``,
        ``tick``, ``set_controller``).
    history : bool
        Take the transient-local history of the lockstep publishers when matching
        (the runner's own graph); False for a tool that joins a running graph.
    volatile_topics : collection of str
        Topics read without history even with ``history``: those of a node
        outside the package (``run --external``), which may publish volatile.
    qos_from_graph : bool
        Register a topic in the bag when its first publisher appears, with the
        QoS its publishers offer (:meth:`register_discovered`), instead of the
        graph's known profiles at the start.
    name : str
        Node name.
    """

    def __init__(self, writer: BagWriter | None, keep=(), topics: dict[str, str] | None = None, *, live=None,
                 history: bool = True, qos_from_graph: bool = False, name: str = "recorder", volatile_topics=(),
                 **kwargs) -> None:
        super().__init__(name, **kwargs)
        self.live = live
        self.history = history
        self.qos_from_graph = qos_from_graph
        self.volatile_topics = set(volatile_topics)
        self._clock_known = history  # joining a running graph: the first /clock is taken as it comes
        self._registered: set[str] = set()
        self.writer = writer
        self.error = ""  # why recording stopped, if it did
        # a non-finite command that no finite one of its step has followed yet: (topic, stamp ns, values, wall s
        # it came), and the law active as the graph's parameter events tell it (the runner sets the first)
        self.bad_command: tuple[str, int, list[float], float] | None = None
        self.controller_type = ""
        self.qos_problems: list[str] = []  # publishers whose QoS this recorder cannot match
        # a list to time the controller into: wall s from each step's attitude (or, for a controller on a sim-time
        # timer, its /clock: the tick's release) to its command, as they arrive
        self.latency: list[float] | None = None
        self.latency_from = ATTITUDE
        # a controller on the wall clock (command_timing: wall): its commands' arrivals against the steps. Its
        # commands carry its clock's stamps: they are logged at the sim time they come
        self.arrivals: CommandArrivals | None = None
        # called as the graph's controller changes law: (controller_type, stamp of the last command taken or -1)
        self.on_controller: Callable[[str, int], None] | None = None
        # the plant's input_timeout (s) as last set while the graph runs (None: as at start); the runner's stall
        # watchdog follows it
        self.plant_input_timeout: float | None = None
        self._released_at: dict[int, float] = {}  # wall s each step's latency_from message came
        self.counts: dict[str, int] = defaultdict(int)
        self.last_stamp: dict[str, int] = {}  # the latest stamp taken per topic, ns
        self.newest_stamp: dict[str, int] = {}  # the greatest stamp taken per topic, ns (a stray can be older)
        self.refused: dict[str, int] = defaultdict(int)  # stray messages not recorded, per topic
        self.refused_stamp: dict[str, int] = {}  # the stamp of the last one refused per topic, ns
        self.clock_ns = 0  # the latest /clock, ns
        self.sim_now = 0  # latest lockstep stamp seen, ns
        self.newest_ns = 0  # the latest stamp taken on any topic this episode, ns
        self.kept: dict[str, list[tuple[int, bytes]]] = {name: [] for name in keep}
        self.keeping = True  # False: the kept topics go to ``sink`` only, nothing stays in memory
        self.across_episodes = False  # see start_episode
        self.faults: list[str] = []  # see start_episode
        self.sink: Callable[[str, int, bytes], None] | None = None  # (topic, stamp ns, CDR) of kept topics
        self.subs = {}
        for name, type_name in (topics or RECORDED_TOPICS).items():
            qos = PARAMETER_EVENTS_QOS if name == PARAMETER_EVENTS else (
                LOCKSTEP_QOS if history and name not in volatile_topics else INPUT_QOS)
            sub = self.create_subscription(
                message_class(type_name), name, lambda data, n=name: self._on_message(n, data), qos, raw=True,
                event_callbacks=qos_event_callbacks(self, name, qos, self.qos_problems),
            )
            self.subs[name] = sub
        self.resolved = {name: sub.topic_name for name, sub in self.subs.items()}
        self.types = dict(topics or RECORDED_TOPICS)
        # the 3D view's topics go with the attitude: their full names, and the frames of the scene (none yet)
        self.view = {name: self.resolve_topic_name(name) for name in VIEW_TOPICS} if ATTITUDE in self.subs else {}
        self.scene: BodyScene | None = None
        self._tf = TfLayout(((INERTIAL, BODY),))
        self._model_in_bag = False  # this episode's body model is in the bag
        self._model_live_ns: int | None = None  # stamp of the last body model sent live
        if live is not None:  # advertised at once, so a client can subscribe before the first episode
            for name, sub in self.subs.items():
                live.add_topic(sub.topic_name, self.types[name])
            for name, full in self.view.items():
                live.add_topic(full, VIEW_TOPICS[name])
            live.serve()
        # topics whose values are checked before recording: float64 count per message
        self._widths = {name: 4 if t.endswith("QuaternionStamped") else 3 for name, t in self.types.items()
                        if t.endswith(("QuaternionStamped", "Vector3Stamped"))}
        if writer is not None:
            self.start_episode(writer)

    def start_episode(self, writer: BagWriter | None, keeping: bool = True,
                      sink: Callable[[str, int, bytes], None] | None = None, across_episodes: bool = False) -> None:
        """Clear counts and kept messages and record to ``writer`` (None: stop recording).

        ``keeping``: keep the kept topics' messages in memory (``kept``);
        ``sink``: also hand each of them to this callable as it comes;
        ``across_episodes``: what follows may span episodes (a ``/clock`` back to 0 starts one); else it is one
        episode, and a ``/clock`` 0 within it, the plant sending its start again
        (``PlantNode._resend_clock``), is not recorded.
        """
        self.across_episodes = across_episodes
        self.keeping = keeping
        self.sink = sink
        self.counts.clear()
        self.faults = []  # the faults that became active, as /diagnostics said (fault_lines)
        self.last_stamp.clear()
        self.newest_stamp.clear()
        self.refused.clear()
        self.refused_stamp.clear()
        self.sim_now = 0
        self.newest_ns = 0
        self.clock_ns = 0
        self._clock_known = self.history
        self.error = ""
        self.bad_command = None
        for kept in self.kept.values():
            kept.clear()
        self.writer = writer
        self._registered = set()
        self._model_in_bag = False
        self._model_live_ns = None
        if writer is not None and not self.qos_from_graph:
            for name, sub in self.subs.items():
                # a node outside the package offers its own QoS: the bag states what its publishers offer
                offered = publishers_qos_yaml(self.get_publishers_info_by_topic(sub.topic_name)) \
                    if name in self.volatile_topics else ""
                writer.add_topic(sub.topic_name, self.types[name], offered or offered_qos_yaml(name))
            self._registered = set(self.subs)
        if self.live is not None:
            for name, sub in self.subs.items():
                self.live.add_topic(sub.topic_name, self.types[name])

    def set_scene(self, scene: BodyScene | None) -> None:
        """The frames and body model the view topics carry from now on (None: ``tf`` of the body alone)."""
        self.scene = scene
        self._tf = TfLayout(scene.frames if scene is not None else ((INERTIAL, BODY),))
        self._model_in_bag = False
        self._model_live_ns = None

    def register_discovered(self) -> list[str]:
        """Register in the bag each topic whose publishers this recorder has matched now, with the QoS they offer;
        returns the new ones.

        Only with ``qos_from_graph``; a topic whose first message comes before
        this is called is registered then. Matched, not merely discovered: a
        tool that says it is subscribed to a topic gets that topic's messages.
        """
        new = []
        if self.writer is None or not self.qos_from_graph:
            return new
        for name, sub in self.subs.items():
            if name not in self._registered and sub.get_publisher_count() > 0 \
                    and self.get_publishers_info_by_topic(self.resolved[name]):
                self._register(name)
                new.append(name)
        return new

    def _register(self, name: str) -> None:
        qos = publishers_qos_yaml(self.get_publishers_info_by_topic(self.resolved[name]))
        self.writer.add_topic(self.resolved[name], self.types[name], qos or offered_qos_yaml(name), wait=False)
        self._registered.add(name)

    def _on_message(self, name: str, data: bytes) -> None:
        t = stamp_from_cdr(data)
        if t is not None and name not in (PARAMETER_EVENTS, DIAGNOSTICS) and t == self.last_stamp.get(name):
            # a repeat of the step taken last (an episode restarted at its first step): taken once, and the
            # controller timed from the repeat
            if self.latency is not None and name == self.latency_from:
                self._released_at[t] = time.monotonic()
            return
        if name in COMMAND_TOPICS and self.arrivals is not None:
            t = self.sim_now  # a wall-clock controller's stamp is its own: logged at the sim time it came
        if name == PARAMETER_EVENTS:
            # events carry the node's clock: wall time until use_sim_time is on. Log
            # them at the sim time of the lockstep instead, so a bag spans sim time only.
            t = self.sim_now
        elif t is None:
            t = self.sim_now
        elif name == CLOCK:
            # the plant's clock goes forward a step at a time, or back to 0 at a reset
            if t == 0 and self.clock_ns > 0 and not self.across_episodes:
                return  # within one episode: the plant sending its start again for a sim-time timer out of phase
            if t != 0 and self._clock_known and not self.clock_ns <= t <= self.clock_ns + MAX_CLOCK_JUMP_NS:
                self._refuse(name, t, "jumps the clock")
                return
            self._clock_known = True
            self.clock_ns = t
            self.sim_now = t
        elif t > max(self.clock_ns, self.newest_ns) + MAX_CLOCK_LEAD_NS:
            # far ahead of the clock and of every topic taken (a step's messages may overtake
            # its /clock, never by seconds; a tool that joins a graph reads each topic on a
            # subscription of its own, and on a loaded machine its /clock can lag the others
            # by more): a stray (foreign or corrupt) message, which would stretch the bag
            self._refuse(name, t, "is ahead of the clock")
            return
        elif name in self._widths and not self._valid(name, data):
            # the nodes refuse non-finite values and non-unit quaternions: so does the bag
            self._refuse(name, t, "is not finite or not a unit quaternion")
            if name in COMMAND_TOPICS and self.bad_command is None:  # the runner stops unless a finite one follows
                self.bad_command = (name, t, stamped_values(data, self._widths[name]).tolist(), time.monotonic())
            return
        else:
            self.sim_now = max(self.sim_now, t)
        if self.bad_command is not None and name in COMMAND_TOPICS and t >= self.bad_command[1]:
            self.bad_command = None  # its step got a finite command: a stray (a foreign node's), not the law's
        self.counts[name] += 1
        self.last_stamp[name] = t
        if name == DIAGNOSTICS:
            self.faults += fault_lines(data)
        if t > self.newest_stamp.get(name, -1):
            self.newest_stamp[name] = t
        if self.latency is not None:
            self._time_controller(name, t)
        elif self.arrivals is not None:
            self._time_arrivals(name)
        self.newest_ns = max(self.newest_ns, t)
        if self.writer is not None:
            try:
                if name not in self._registered:
                    self._register(name)
                self.writer.write(self.resolved[name], data, t)
            except BagWriteError as exc:  # disk full, file too large: stop recording, keep what is written
                self.error = f"recording stopped at t={t * 1e-9:.3f} s: {exc}"
                self.writer = None
        if name == PARAMETER_EVENTS:  # rare (a node's start, a change): read each
            self._on_parameter_event(data, t)
        if self.live is not None:
            self._to_live(name, data, t)
        if name == ATTITUDE and self.view and (self.writer is not None or self.live is not None):
            self._write_view(data, t)
        kept = self.kept.get(name)
        if kept is not None:
            if self.keeping:
                kept.append((t, data))
            if self.sink is not None:
                self.sink(name, t, data)

    def _write_view(self, attitude: bytes, t: int) -> None:
        """The view topics of a recorded attitude stamped ``t``: its frames, and the body model when it is due."""
        scene = self.scene
        q = stamped_values(attitude, 4)
        tf = self._tf.encode_one(t, [q] if scene is None else scene.rotations(t * 1e-9, q))
        model = None
        if scene is not None:
            live_due = self.live is not None and (self._model_live_ns is None or t < self._model_live_ns
                                                  or t - self._model_live_ns >= MODEL_PERIOD_NS)
            if live_due or (self.writer is not None and not self._model_in_bag):
                model = marker_array_cdr(t, BODY, scene.markers)
            if live_due:
                self._model_live_ns = t
        else:
            live_due = False
        if self.writer is not None:
            try:
                self._write_derived(TF, tf, t)
                if model is not None and not self._model_in_bag:
                    self._write_derived(BODY_MODEL, model, t)
                    self._model_in_bag = True
            except BagWriteError as exc:
                self.error = f"recording stopped at t={t * 1e-9:.3f} s: {exc}"
                self.writer = None
        if self.live is not None:
            self.live.write(self.view[TF], tf, t)
            if live_due:
                self.live.write(self.view[BODY_MODEL], model, t)

    def _write_derived(self, name: str, data: bytes, t: int) -> None:
        if name not in self._registered:
            self.writer.add_topic(self.view[name], VIEW_TOPICS[name], offered_qos_yaml(name), wait=False)
            self._registered.add(name)
        self.writer.write(self.view[name], data, t)

    def _time_controller(self, name: str, t: int) -> None:
        if name == self.latency_from:
            self._released_at[t] = time.monotonic()
        elif name in COMMAND_TOPICS:
            sent = self._released_at.pop(t, None)
            for older in [s for s in self._released_at if s < t]:  # steps with no command (between a timer's ticks)
                del self._released_at[older]
            if sent is not None:
                self.latency.append(time.monotonic() - sent)

    def _time_arrivals(self, name: str) -> None:
        if name == ATTITUDE:
            self.arrivals.attitude(time.monotonic())
        elif name in COMMAND_TOPICS:
            self.arrivals.command(time.monotonic())
        elif name == CLOCK:
            self.arrivals.step(time.monotonic())

    def _on_parameter_event(self, data: bytes, t: int) -> None:
        # a live view's Parameters panel follows every change; a swap of our controller's law goes to the live
        # view's status and to on_controller(law, stamp of the last command taken); the plant's input_timeout
        # to the runner's stall watchdog
        event = deserialize_message(data, ParameterEvent)
        values = {}
        for p in (*event.new_parameters, *event.changed_parameters):
            v = parameter_value_to_python(p.value)
            values[p.name] = v if isinstance(v, (str, bytes, bool, int, float)) or v is None else list(v)
        if self.live is not None:
            self.live.parameters_changed(event.node, values)
        ns = self.get_namespace().rstrip("/")
        if event.node == ns + "/plant" and isinstance(values.get("input_timeout"), float):
            self.plant_input_timeout = values["input_timeout"]
        if event.node == ns + "/controller" and "controller_type" in values:
            self.controller_type = values["controller_type"]
            if self.live is not None:
                self.live.set_controller(values["controller_type"], t)
            if self.on_controller is not None and event.changed_parameters:
                last = max((self.last_stamp.get(c, -1) for c in COMMAND_TOPICS), default=-1)
                self.on_controller(values["controller_type"], last)

    def _to_live(self, name: str, data: bytes, t: int) -> None:
        self.live.write(self.resolved[name], data, t)
        if name == CLOCK:
            self.live.tick(t)

    def _refuse(self, name: str, t: int, why: str) -> None:
        self.refused[name] += 1
        self.refused_stamp[name] = t
        self.get_logger().warning(f"{name} stamped {t * 1e-9:.6f} s {why} (clock {self.clock_ns * 1e-9:.6f} s); "
                                  "not recorded", throttle_duration_sec=1.0)

    def _valid(self, name: str, data: bytes) -> bool:
        values = stamped_values(data, self._widths[name])
        if values is None or not np.all(np.isfinite(values)):
            return False
        return values.size != 4 or unit_or_none(values) is not None  # the nodes' own quaternion rule
