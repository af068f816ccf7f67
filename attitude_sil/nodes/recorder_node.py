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
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable

import numpy as np
from rclpy.node import Node

from attitude_sil.core.quaternion import unit_or_none
from attitude_sil.errors import BagWriteError
from attitude_sil.ros.contract import CLOCK, PARAMETER_EVENTS, RECORDED_TOPICS, message_class
from attitude_sil.ros.qos import LOCKSTEP_QOS, PARAMETER_EVENTS_QOS, offered_qos_yaml
from attitude_sil.storage.cdr import stamp_from_cdr, stamped_values
from attitude_sil.storage.writer import BagWriter

#: the most the clock may jump forward between two /clock messages (a control step is far less)
MAX_CLOCK_JUMP_NS = 10_000_000_000
#: how far ahead of the latest /clock a message may be stamped and still be recorded
MAX_CLOCK_LEAD_NS = 1_000_000_000


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
    """

    def __init__(self, writer: BagWriter | None, keep=(), topics: dict[str, str] | None = None, **kwargs) -> None:
        super().__init__("recorder", **kwargs)
        self.writer = writer
        self.error = ""  # why recording stopped, if it did
        self.counts: dict[str, int] = defaultdict(int)
        self.refused: dict[str, int] = defaultdict(int)  # stray messages not recorded, per topic
        self.clock_ns = 0  # the latest /clock, ns
        self.sim_now = 0  # latest lockstep stamp seen, ns
        self.kept: dict[str, list[tuple[int, bytes]]] = {name: [] for name in keep}
        self.keeping = True  # False: the kept topics go to ``sink`` only, nothing stays in memory
        self.sink: Callable[[str, int, bytes], None] | None = None  # (topic, stamp ns, CDR) of kept topics
        self.subs = {}
        for name, type_name in (topics or RECORDED_TOPICS).items():
            qos = PARAMETER_EVENTS_QOS if name == PARAMETER_EVENTS else LOCKSTEP_QOS
            sub = self.create_subscription(
                message_class(type_name), name, lambda data, n=name: self._on_message(n, data), qos, raw=True
            )
            self.subs[name] = sub
        self.resolved = {name: sub.topic_name for name, sub in self.subs.items()}
        self.types = dict(topics or RECORDED_TOPICS)
        # topics whose values are checked before recording: float64 count per message
        self._widths = {name: 4 if t.endswith("QuaternionStamped") else 3 for name, t in self.types.items()
                        if t.endswith(("QuaternionStamped", "Vector3Stamped"))}
        if writer is not None:
            self.start_episode(writer)

    def start_episode(self, writer: BagWriter | None, keeping: bool = True,
                      sink: Callable[[str, int, bytes], None] | None = None) -> None:
        """Clear counts and kept messages and record to ``writer`` (None: stop recording).

        ``keeping``: keep the kept topics' messages in memory (``kept``);
        ``sink``: also hand each of them to this callable as it comes.
        """
        self.keeping = keeping
        self.sink = sink
        self.counts.clear()
        self.refused.clear()
        self.sim_now = 0
        self.clock_ns = 0
        self.error = ""
        for kept in self.kept.values():
            kept.clear()
        self.writer = writer
        if writer is not None:
            for name, sub in self.subs.items():
                writer.add_topic(sub.topic_name, self.types[name], offered_qos_yaml(name))

    def _on_message(self, name: str, data: bytes) -> None:
        t = stamp_from_cdr(data)
        if name == PARAMETER_EVENTS:
            # events carry the node's clock: wall time until use_sim_time is on. Log
            # them at the sim time of the lockstep instead, so a bag spans sim time only.
            t = self.sim_now
        elif t is None:
            t = self.sim_now
        elif name == CLOCK:
            # the plant's clock goes forward a step at a time, or back to 0 at a reset
            if t != 0 and not self.clock_ns <= t <= self.clock_ns + MAX_CLOCK_JUMP_NS:
                self._refuse(name, t, "jumps the clock")
                return
            self.clock_ns = t
            self.sim_now = t
        elif t > self.clock_ns + MAX_CLOCK_LEAD_NS:
            # far ahead of the clock (a step's messages may overtake its /clock, never by
            # seconds): a stray (foreign or corrupt) message, which would stretch the bag
            self._refuse(name, t, "is ahead of the clock")
            return
        elif name in self._widths and not self._valid(name, data):
            # the nodes refuse non-finite values and non-unit quaternions: so does the bag
            self._refuse(name, t, "is not finite or not a unit quaternion")
            return
        else:
            self.sim_now = max(self.sim_now, t)
        self.counts[name] += 1
        if self.writer is not None:
            try:
                self.writer.write(self.resolved[name], data, t)
            except BagWriteError as exc:  # disk full, file too large: stop recording, keep what is written
                self.error = f"recording stopped at t={t * 1e-9:.3f} s: {exc}"
                self.writer = None
        kept = self.kept.get(name)
        if kept is not None:
            if self.keeping:
                kept.append((t, data))
            if self.sink is not None:
                self.sink(name, t, data)

    def _refuse(self, name: str, t: int, why: str) -> None:
        self.refused[name] += 1
        self.get_logger().warning(f"{name} stamped {t * 1e-9:.6f} s {why} (clock {self.clock_ns * 1e-9:.6f} s); "
                                  "not recorded", throttle_duration_sec=1.0)

    def _valid(self, name: str, data: bytes) -> bool:
        values = stamped_values(data, self._widths[name])
        if values is None or not np.all(np.isfinite(values)):
            return False
        return values.size != 4 or unit_or_none(values) is not None  # the nodes' own quaternion rule
