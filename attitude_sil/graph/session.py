"""Run episodes on a live graph: the runner's and the tuner's.

:class:`GraphSession` starts the graph once (:mod:`attitude_sil.graph.launcher`:
nodes in this process, or one process per node), adds a recorder and waits for
discovery by condition. Each :meth:`GraphSession.run_episode` sets controller
parameters through the parameter service, calls ``plant/reset``, spins until
every step topic holds all K+1 messages (applying scheduled controller swaps
at the plant's holds), and returns the episode as a
:class:`~attitude_sil.core.trajectory.Trajectory` with its metrics and bag.
:func:`run_graph` is one episode on a fresh graph (``attitude-sil run``).

Unless the user chose a domain or a discovery range, the graph stays on this
machine (:func:`attitude_sil.ros.environment.localhost_environment`).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions

from attitude_sil.core.analysis.latency import CommandArrivals, latency_summary
from attitude_sil.core.analysis.metrics import episode_report
from attitude_sil.core.analysis.running_metrics import EpisodeAccumulator
from attitude_sil.core.control import registry
from attitude_sil.core.sim.build import build_scene, check_episode, schedule_from_scenario
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.lockstep import command_period_ns, is_tick, tick_period_ns
from attitude_sil.core.sim.params import spec_for
from attitude_sil.core.sim.scenario import Scenario
from attitude_sil.core.trajectory import Trajectory
from attitude_sil.errors import AttitudeSilError, BagWriteError, RunError
from attitude_sil.graph.launcher import (
    check_children,
    namespace_kwargs,
    start_nodes,
    start_processes,
    stop_processes,
    wait_connected,
    wait_external,
)
from attitude_sil.graph.trajectory import KEPT_TOPICS, StepAssembler, trajectory_from_messages
from attitude_sil.nodes.recorder_node import Recorder
from attitude_sil.ros.contract import (
    APPLIED_COMMAND_TOPIC,
    ATTITUDE,
    CLOCK,
    COMMAND_TOPICS,
    EXTERNAL,
    MAGNETIC_FIELD,
    MAGNETIC_TOPICS,
    PRODUCERS,
    ROLE_OUTPUTS,
    SENSING_STEP_TOPICS,
    UNKNOWN_NODE,
    WHEEL_TORQUE,
    check_namespace,
    episode_topics,
    recorded_topics,
)
from attitude_sil.ros.environment import isolated_domain, localhost_environment
from attitude_sil.ros.services import PlantReset, set_remote_parameters
from attitude_sil.ros.signals import STOP_SIGNALS, Interrupted, StopSignals
from attitude_sil.storage.writer import PARAMETERS_KEY, SCENARIO_KEY, BagWriter, check_bag_dir

__all__ = ["RunError", "RunResult", "GraphSession", "Interrupted", "Progress", "STOP_SIGNALS", "run_graph",
           "extra_parameters", "spin_episode", "episode_complete", "hold_for_viewer", "CommandsLost"]


class CommandsLost(RunError):
    """The episode reached its end, every step topic whole, without some of its commands: a volatile publisher
    (flight software of the user's) wrote them before its side of the DDS match with a reader that had just
    joined, or past its history's depth while that reader fell behind."""


@dataclass
class RunResult:
    """Outcome of one graph episode.

    Attributes
    ----------
    metrics : dict
        The ``run --json`` object (docs/architecture.md, "Command line").
    bag : Path or None
        The bag recorded, if any.
    counts : dict
        Messages received per topic.
    trajectory : Trajectory or None
        The episode (P = 1), the batch engine's type, if it was asked for
        (``keep_trajectory``).
    """

    metrics: dict[str, Any]
    bag: Path | None
    counts: dict[str, int]
    trajectory: Trajectory | None


def _schedule(scn: Scenario, duration: float) -> list[tuple[float, int, str]]:
    """Scheduled swaps inside the episode as (time s, step index, controller_type)."""
    k_end = scn.steps(duration)
    return [(k * scn.dt, k, kind) for k, kind in schedule_from_scenario(scn) if k <= k_end]


def extra_parameters(scn: Scenario, duration: float | None, controller: str | None, real_time: bool) -> dict:
    """What a graph episode sets on top of the scenario: no autostart, the first hold, duration, law, pacing."""
    extra: dict[str, Any] = {"autostart": False}
    sched = _schedule(scn, scn.duration if duration is None else duration)
    if sched:
        extra["hold_at"] = sched[0][0]
    if duration is not None:
        extra["duration"] = float(duration)
    if controller is not None:
        extra["controller_type"] = controller
    if real_time:
        extra["real_time_factor"] = 1.0
    return extra


class Progress:
    """A progress line on stderr: sim time, wall time, real-time factor (``enabled=False``: none)."""

    def __init__(self, enabled: bool, sim_end: float) -> None:
        self.enabled = enabled
        self.sim_end = sim_end
        self.tty = sys.stderr.isatty()
        self.t0 = time.monotonic()
        self.last = self.t0

    def update(self, sim_t: float, force: bool = False) -> None:
        now = time.monotonic()
        if not self.enabled or (not force and now - self.last < (0.25 if self.tty else 2.0)):
            return
        self.last = now
        wall = now - self.t0
        rtf = sim_t / wall if wall > 0 else 0.0
        line = f"sim {sim_t:7.2f} / {self.sim_end:.2f} s   wall {wall:6.2f} s   {rtf:6.1f}x real time"
        if self.tty:
            print("\r" + line, end="\n" if force else "", file=sys.stderr, flush=True)
        else:
            print(line, file=sys.stderr, flush=True)


class GraphSession:
    """A running graph that can play several episodes (the runner's and the tuner's).

    ``with GraphSession(scn, ...) as g: g.run_episode(...)``. The graph is started
    once: nodes in this process (or one process per node), a recorder, discovery
    awaited by condition. Each :meth:`run_episode` optionally sets controller
    parameters through the parameter service, calls ``plant/reset`` and spins
    until every step topic holds all K+1 messages.

    With ``namespace`` the whole graph, its ``/clock`` included (remapped to
    ``/<ns>/clock``), lives under that namespace, so replicas on one ROS domain
    do not hear each other.

    Parameters
    ----------
    scn : Scenario
    duration : float, optional
        Episode length, s (default ``plant.duration``).
    controller : str, optional
        ``controller_type`` to start with.
    processes : bool
        One process per node instead of one process for all.
    real_time : bool
        Pace the plant at real time (``real_time_factor`` 1.0).
    namespace : str, optional
        Run the whole graph (and its clock) under this namespace.
    connect_timeout : float
        Wall seconds to wait for discovery.
    live : FoxgloveLive, optional
        Serve every message live too.
    external : sequence of str
        Graph nodes (``controller``, ...) not started: a node outside the
        package plays each (docs/flight-software.md), waited for up to
        ``external_timeout`` s once the graph's own nodes are up.
    external_timeout : float
        Wall seconds to wait for the external nodes.
    quiet : bool
        The graph's nodes log warnings and errors only (``run --quiet``).
    wait_for_viewer : float, optional
        With ``live``: hold the first episode's step 0 until a client has
        subscribed to a channel (:meth:`FoxgloveLive.viewer_ready`) or this
        many wall seconds have passed (``math.inf``: no limit); None: do not wait.
    """

    def __init__(self, scn: Scenario, *, duration: float | None = None, controller: str | None = None,
                 processes: bool = False, real_time: bool = False, namespace: str | None = None,
                 connect_timeout: float = 20.0, live=None, external=(), external_timeout: float = 60.0,
                 quiet: bool = False, wait_for_viewer: float | None = None) -> None:
        if controller is not None:
            spec_for("controller", "controller_type").validate(controller, "controller")
            # the law flown first is the scenario's from here: what it starts (bdot: the magnetorquers) follows
            scn = scn.with_values("controller", controller_type=controller)
        self.external = check_external(external, controller, scn)
        self.timing = scn.param("wheels", "command_timing")
        if self.timing == "sim_timer" and processes:
            raise RunError("--external-timing sim_timer runs the graph's nodes in one process (there the setpoints "
                           "of a tick are delivered before its /clock); leave out --processes")
        if self.timing == "wall" and not real_time:
            raise RunError("--external-timing wall: the plant must run at real time for a controller on the wall "
                           "clock; add --real-time")
        self.external_timeout = external_timeout
        self.quiet = quiet
        self.scn = scn
        self.extra = extra_parameters(scn, duration, controller, real_time)
        self.duration = scn.duration if duration is None else float(duration)
        if self.duration <= 0.0:
            raise RunError(f"{scn.source}: plant.duration is 0 (run until stopped), but the runner needs a finite "
                           "episode: give plant.duration or --duration > 0")
        check_episode(scn.with_values("plant", duration=self.duration) if duration is not None else scn,
                      controller)  # what the nodes would refuse at reset is refused before the graph starts
        self.processes = processes
        self.namespace = check_namespace(namespace)
        self.connect_timeout = connect_timeout
        self.controller = EXTERNAL if "controller" in self.external else (
            controller or scn.param("controller", "controller_type"))
        self.live = live  # a FoxgloveLive that serves every message, or None
        self.wait_for_viewer = wait_for_viewer  # hold step 0 of the first episode for a live client, s (None: no)

    def __enter__(self) -> GraphSession:
        isolated_domain()  # a graph of its own unless the user chose a domain
        localhost_environment()
        # compile (or load from numba's cache) every law's kernels before the clock
        # starts, so no node compiles mid-episode and node processes find the cache
        first = self.scn.param("controller", "controller_type")
        for law in [] if "controller" in self.external else registry.names():
            # each law's step, and a swap (the bumpless entry) where it is not the first
            try:
                simulate(self.scn, 1, duration=2 * self.scn.dt, controller=first, driver="stepwise",
                         schedule=[] if law == first else [(1, law)])
            except (AttitudeSilError, ValueError):
                pass  # a law this preset's actuator cannot take (e.g. torque into speed-loop wheels)
        self.context = rclpy.Context()
        self.interrupt = StopSignals().__enter__()  # checked between callbacks: stops at a clean point
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.nodes: list = []
        self.children: list[subprocess.Popen] = []
        self.tmpdir = None
        self.recorder = None
        self.foreign = None
        try:
            kw = namespace_kwargs(self.namespace)
            outside = [t for t, producer in PRODUCERS.items() if producer in self.external]
            field = self.scn.param("plant", "environment.magnetic_field.model") != "none"
            topics = recorded_topics(self.scn.has_sensors, applied=self.timing != "stamped", field=field,
                                     magnetic=self.scn.has_magnetorquers)
            self.recorder = Recorder(None, keep=KEPT_TOPICS, topics=topics,
                                     live=self.live, context=self.context, volatile_topics=outside, **kw)
            self.recorder.latency = [] if "controller" in self.external and self.timing != "wall" else None
            self.recorder.latency_from = CLOCK if self.timing == "sim_timer" else ATTITUDE  # a tick: from /clock
            self._new_arrivals()  # wall: its commands carry the controller's clock, from the first
            self.recorder.set_scene(build_scene(self.scn.values))  # the 3D view's frames and body model
            self.reset = PlantReset(self.recorder)  # before the nodes: matched by the first reset (PlantReset)
            self.executor = EventsExecutor(context=self.context)
            self.executor.add_node(self.recorder)
            self.plant = None
            if self.processes:
                self.tmpdir = tempfile.TemporaryDirectory(prefix="attitude_sil_")
                self.children = start_processes(self.scn, self.extra, Path(self.tmpdir.name), self.namespace,
                                                skip=self.external, quiet=self.quiet)
            else:
                self.plant = start_nodes(self.scn, self.extra, self.context, self.executor, self.nodes, kw,
                                         skip=self.external, quiet=self.quiet)
            wait_connected(self.recorder, self.spin, self.nodes, self.children, self.connect_timeout,
                           external=self.external, feedback=self.scn.feedback if self.scn.has_sensors else None,
                           magnetic=self.scn.has_magnetorquers)
            if self.external:
                wait_external(self.recorder, self.spin, self.nodes, self.children, self.external,
                              self.external_timeout)
            self.foreign = ForeignPublishers(self.recorder, self.namespace, skip=self.external)
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def spin(self, timeout_sec: float) -> None:
        """Process callbacks for up to ``timeout_sec``; raises KeyboardInterrupt after Ctrl-C."""
        self.interrupt.check()
        self.executor.spin_once(timeout_sec=timeout_sec)

    def run_episode(self, *, record_dir: str | Path | None = None, controller_params: dict | None = None,
                    progress: bool = False, keep_trajectory: bool = False) -> RunResult:
        """Play one episode; returns its metrics, counts, bag and (if asked) trajectory.

        Without ``keep_trajectory`` the metrics come from running sums
        (:class:`~attitude_sil.core.analysis.running_metrics.EpisodeAccumulator`): the
        episode's memory does not grow with its length. With it, the episode's
        messages are kept and decoded into a Trajectory (about 1.5 kB a step).

        Raises
        ------
        RunError
            A refused parameter or reset, a bag that cannot be created, an
            input timeout or a failed node.
        KeyboardInterrupt
            After Ctrl-C, once the bag is closed (nothing recorded is lost).
        """
        if controller_params and "controller" in self.external:
            raise RunError("the controller is external (--external controller): its parameters are its own, "
                           "not set by attitude-sil")
        writer = None if record_dir is None else self._bag_writer(record_dir, controller_params)
        if self.live is not None:
            self.live.set_controller((controller_params or {}).get("controller_type", self.controller), 0)
        prog = Progress(progress, self.duration)
        schedule = _schedule(self.scn, self.duration)
        accumulator = EpisodeAccumulator(self.scn.values["scenario"], self.scn.param("guidance", "step_time"),
                                         self.controller, schedule or None, self.scn.has_magnetorquers)
        assembler = StepAssembler(accumulator, estimate=self.scn.has_sensors, applied=self.timing != "stamped")
        self.recorder.on_controller = _live_swaps(accumulator, schedule, int(round(self.scn.dt * 1e9)))
        self.recorder.start_episode(writer, keeping=keep_trajectory,
                                    sink=None if keep_trajectory else assembler.add)
        self.recorder.controller_type = (controller_params or {}).get("controller_type", self.controller)
        try:
            if controller_params:
                set_remote_parameters(self.recorder, self.spin, "controller", controller_params)
            if schedule:  # a scheduled swap ends with the plant released: hold it again
                set_remote_parameters(self.recorder, self.spin, "plant", {"hold_at": schedule[0][0]})
            if self.live is not None and self.wait_for_viewer is not None:
                hold_for_viewer(self.live, self.spin, self.wait_for_viewer)
                self.wait_for_viewer = None  # the first episode only
            self.reset(self.spin, self.connect_timeout)
            wall0 = time.monotonic()
            prog.t0 = wall0
            if self.recorder.latency is not None:
                self.recorder.latency.clear()
            self._new_arrivals()
            spin_episode(self.recorder, self.spin, self.plant, self.children, self.scn.steps(self.duration),
                         self.scn, prog, schedule, self.foreign, self.episode_topics(),
                         lambda: self.reset(self.spin, self.connect_timeout))
            wall = time.monotonic() - wall0
            prog.update(self.duration, force=True)
        finally:
            self.recorder.writer = None  # stop recording; the kept messages stay for the metrics
            if writer is not None:
                try:
                    writer.close()
                except BagWriteError:
                    if not self.recorder.error:  # else the error is on its way up already
                        raise
        self.recorder.sink = None
        self.recorder.on_controller = None
        if keep_trajectory:
            traj = trajectory_from_messages(self.recorder.kept)
            metrics = episode_report(self.scn, traj, self.controller, self.duration, wall,
                                     schedule if schedule else None)
            for kept in self.recorder.kept.values():
                kept.clear()
        else:
            traj = None
            metrics = assembler.accumulator.report(self.scn.name, self.duration, wall)
        metrics.update(self._timing_summary())
        metrics["faults"] = list(self.recorder.faults)  # what became active, as /diagnostics said
        bag = None if writer is None else writer.run_dir
        metrics["bag"] = None if bag is None else str(bag)
        return RunResult(metrics=metrics, bag=bag, counts=dict(self.recorder.counts), trajectory=traj)

    def _new_arrivals(self) -> None:
        """A wall-clock controller's command arrivals counted afresh (None for the other styles)."""
        self.recorder.arrivals = CommandArrivals(command_period_of(self.scn) * 1e-9) if self.timing == "wall" \
            else None

    def _timing_summary(self) -> dict:
        """The outside controller's timing for the summary: its latency, and on a timer its style, its period
        and, on sim time, the delay of one period with which its commands take effect (on the wall clock, the
        steps and periods it missed)."""
        out: dict = {}
        if self.recorder.latency:
            out.update(latency_summary(self.recorder.latency))
        if self.timing == "stamped":
            return out
        period_ms = command_period_of(self.scn) * 1e-6
        out.update(command_timing=self.timing, command_period_ms=period_ms)
        if self.timing == "sim_timer":
            out["command_delay_ms"] = period_ms  # logical execution time: a tick's command acts one period later
        elif self.recorder.arrivals is not None:
            out.update(self.recorder.arrivals.summary())
        return out

    def episode_topics(self) -> list[str]:
        """The topics an episode fills, one message per step each: the lockstep's, and the sensing loop's and
        the magnetorquers' where they run (their nodes not external)."""
        topics = episode_topics(self.external)
        if self.scn.has_sensors:
            topics += [t for t in SENSING_STEP_TOPICS if PRODUCERS[t] not in self.external]
        if self.scn.has_magnetorquers:
            topics += [t for t in (MAGNETIC_FIELD, *MAGNETIC_TOPICS) if PRODUCERS[t] not in self.external]
        return topics

    def _bag_writer(self, record_dir: str | Path, controller_params: dict | None) -> BagWriter:
        """The episode's bag, with the parameters of the nodes the runner started and the scenario section."""
        extra = dict(self.extra)
        if controller_params:
            extra.update(controller_params)
        own = [n for n in self.scn.nodes if n not in self.external]  # what it knows of the nodes it ran
        try:
            return BagWriter(record_dir, custom_data={PARAMETERS_KEY: self.scn.parameters_yaml(extra, own),
                                                      SCENARIO_KEY: self.scn.scenario_yaml()})
        except (FileExistsError, ValueError, OSError) as exc:
            raise RunError(str(exc)) from None

    def __exit__(self, *exc) -> None:
        if getattr(self, "executor", None) is not None:
            self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        self.nodes = []
        stop_processes(self.children)
        self.children = []
        if self.recorder is not None:
            try:
                self.recorder.destroy_node()
            except Exception:  # noqa: BLE001 - best effort during teardown
                pass
        rclpy.try_shutdown(context=self.context)
        if self.tmpdir is not None:
            self.tmpdir.cleanup()
            self.tmpdir = None
        self.interrupt.__exit__()


def run_graph(
    scn: Scenario,
    *,
    record_dir: str | Path | None = None,
    progress: bool = True,
    controller_params: dict | None = None,
    before_start: Callable[[], None] | None = None,
    keep_trajectory: bool = False,
    live=None,
    **options,
) -> RunResult:
    """Run one episode of ``scn`` through the ROS graph.

    Parameters
    ----------
    scn : Scenario
    record_dir : path, optional
        Bag directory to record to; None records nothing.
    progress : bool
        Print a progress line on stderr.
    controller_params : dict, optional
        Controller parameters set through the parameter service before the episode.
    before_start : callable, optional
        Called once the input is validated, before the graph starts (``run`` announces its domain there).
    keep_trajectory : bool
        Keep the episode's messages and return its Trajectory; without it the
        metrics come from running sums and memory stays flat however long the run.
    live : FoxgloveLive or callable, optional
        Serve every message of the run live too (``run --foxglove``); a callable
        is called after ``before_start`` for the sink (or None), so a server
        starts only once the input is validated.
    **options
        How the graph runs: the keywords of :class:`GraphSession` (``duration``,
        ``controller``, ``processes``, ``real_time``, ``namespace``,
        ``connect_timeout``).

    Returns
    -------
    RunResult

    Raises
    ------
    RunError
        The graph did not connect, an input timed out, or a node failed.
    KeyboardInterrupt
        After the bag is closed, so nothing recorded is lost.
    """
    if record_dir is not None:
        try:
            check_bag_dir(record_dir)  # before the graph starts, not after discovery
        except (ValueError, OSError) as exc:
            raise RunError(str(exc)) from None
    session = GraphSession(scn, **options)  # validates
    if before_start is not None:
        before_start()
    session.live = live() if callable(live) else live
    with session as graph:
        return graph.run_episode(record_dir=record_dir, controller_params=controller_params, progress=progress,
                                 keep_trajectory=keep_trajectory)


def hold_for_viewer(live, spin: Callable[[float], None], timeout_s: float) -> bool:
    """Spin the graph until a client of ``live`` watches (:meth:`FoxgloveLive.viewer_ready`) or ``timeout_s`` wall
    seconds have passed (``math.inf``: no limit); says on stderr what it waits for and, at a timeout, that the run
    starts unwatched. True if a client came."""
    limit = "" if timeout_s == float("inf") else f" (at most {timeout_s:g} s)"
    print(f"Foxglove: holding step 0 until a client subscribes{limit}", file=sys.stderr, flush=True)
    deadline = time.monotonic() + timeout_s
    while not live.viewer_ready():
        if time.monotonic() >= deadline:
            print(f"Foxglove: no client subscribed within {timeout_s:g} s; the run starts", file=sys.stderr,
                  flush=True)
            return False
        spin(0.02)  # the graph's callbacks (parameters, Ctrl-C) go on while the client is awaited
    return True


def _live_swaps(accumulator: EpisodeAccumulator, schedule: list[tuple[float, int, str]], dt_ns: int):
    """The recorder's ``on_controller``: a ``controller_type`` set while the run goes (``param set``, a Foxglove
    client) into the accumulator, the law from the step after the last command taken."""
    scheduled = {k for _, k, _ in schedule}

    def swap(kind: str, last_ns: int) -> None:
        k = last_ns // dt_ns + 1 if last_ns >= 0 else 0
        if not scheduled & {k - 1, k, k + 1}:  # the runner's own scheduled swaps are in the schedule already
            accumulator.swap(k, kind)

    return swap


def check_external(external, controller: str | None, scn: Scenario) -> tuple[str, ...]:
    """``--external`` names: graph nodes, once each; an external controller takes no law, swap or gains of ours.

    Raises
    ------
    RunError
        A name that is not a graph node, or an external controller asked for a law or a swap.
    """
    names = tuple(dict.fromkeys(external or ()))
    unknown = [n for n in names if n not in scn.nodes]
    if unknown:
        raise RunError(f"--external: {unknown[0]!r} is not a node of the graph (one of: {', '.join(scn.nodes)})")
    if "controller" in names:
        if controller is not None:
            raise RunError("--external controller: the controller is not attitude-sil's, so --controller "
                           f"{controller} has no law to start; leave it out")
        if schedule_from_scenario(scn):
            raise RunError("--external controller: the run schedules controller swaps (--swap or the scenario's "
                           "schedule.*), which only attitude-sil's controller can make")
    check_command_timing(names, scn)
    return names


def check_command_timing(external: tuple[str, ...], scn: Scenario) -> None:
    """``wheels.command_timing`` other than ``stamped`` (``--external-timing``) is for an outside controller on a
    timer of its own, beside the package's plant, wheels (and, on sim time, guidance); its rate fits the step.

    Raises
    ------
    RunError
        A timer style without ``--external controller``, with a node it needs played from outside, or with a
        rate whose period is not a whole number of control periods.
    """
    timing = scn.param("wheels", "command_timing")
    if timing == "stamped":
        return
    if "controller" not in external:
        raise RunError(f"--external-timing {timing} (wheels.command_timing) is for a controller of yours on a timer: "
                       "add --external controller (attitude-sil's controller answers each step's stamp)")
    if timing == "sim_timer" and scn.has_sensors:
        raise RunError("--external-timing sim_timer does not order the sensing loop's topics (imu, star_tracker, "
                       "estimate/*) before a tick's /clock yet: run it on the truth (feedback: truth, no sensors) "
                       "or stamped")
    needs = ("plant", "wheels", "guidance") if timing == "sim_timer" else ("plant", "wheels")
    outside = [n for n in needs if n in external]
    if outside:
        raise RunError(f"--external-timing {timing} needs attitude-sil's {outside[0]} (it holds the commands and "
                       "orders /clock after the step's setpoints); leave out --external " + outside[0])
    try:
        command_period_of(scn)
    except ValueError as exc:
        raise RunError(f"--external-rate: {exc}") from None


#: how long the first step of an episode may take before the episode is started again (spin_episode), wall s
RESTART_AFTER_S = 5.0
#: how many times an episode whose first step does not complete is started again
MAX_RESTARTS = 3



class ForeignPublishers:
    """Warns once for each publisher on a lockstep topic that is not the graph's own producer.

    The lockstep's nodes refuse what is not finite, not stamped for the step
    they wait for, or a second message for it; a plausible message from a
    foreign node stamped for the current step is told apart only by who sent
    it, and rclpy's message info carries no publisher GID (and the
    EventsExecutor hands callbacks no message info at all). So the run names
    every foreign publisher it sees on the ROS graph (node and topic), once,
    as soon as it appears.
    """

    def __init__(self, node, namespace: str | None, period_s: float = 1.0, skip=()) -> None:
        self.node = node
        self.own = f"/{namespace}" if namespace else "/"
        self.period_s = period_s
        self.next_check = 0.0
        self.warned: set[tuple[str, str]] = set()
        # a topic of a node played from outside (``skip``: run --external) has a publisher of somebody else's
        self.topics = {node.resolve_topic_name(t): producer for t, producer in PRODUCERS.items()
                       if producer not in skip}

    def check(self, now: float) -> list[str]:
        """Look at the graph if a period has passed; returns (and logs) the new warnings."""
        if now < self.next_check:
            return []
        self.next_check = now + self.period_s
        new = []
        for topic, producer in self.topics.items():
            for info in self.node.get_publishers_info_by_topic(topic):
                ns = info.node_namespace or "/"
                if info.node_name == producer and ns == self.own:
                    continue
                if info.node_name == UNKNOWN_NODE:
                    continue  # its node's name is not discovered yet (another process): look again next time
                who = f"{ns.rstrip('/')}/{info.node_name}"
                if (topic, who) not in self.warned:
                    self.warned.add((topic, who))
                    text = (f"{topic} has a second publisher, {who} (the graph's is {self.own.rstrip('/')}/"
                            f"{producer}); a finite message it stamps for the step waited on can be taken for the "
                            "producer's")
                    self.node.get_logger().warning(text)
                    new.append(text)
        return new


def command_period_of(scn: Scenario) -> int:
    """An outside controller's timer period (``wheels.command_rate``; 0: the control period), ns: on sim time a
    whole number of steps (:func:`~attitude_sil.core.sim.lockstep.command_period_ns`), on the wall clock any."""
    rate, dt_ns = scn.param("wheels", "command_rate"), int(round(scn.dt * 1e9))
    if scn.param("wheels", "command_timing") == "sim_timer":
        return command_period_ns(rate, dt_ns)
    return int(round(1e9 / rate)) if rate else dt_ns


#: what a stall line says of a controller that sent nothing the lockstep could take, per ``command_timing``
_STYLE_HINT = {
    "stamped": "a timer-driven node? see --external-timing, docs/flight-software.md",
    "sim_timer": "its timer fires at whole periods of sim time from 0: is its use_sim_time true, and --external-rate "
                 "its rate? docs/flight-software.md",
    "wall": "docs/flight-software.md",
}


@dataclass(frozen=True)
class CommandWatch:
    """Where the runner finds each step's command, and at which steps the controller owes one.

    Attributes
    ----------
    topics : tuple of str
        One of these carries each step's command: the controller's command
        topics, or the wheels' applied ones for a controller on a timer.
    tick_ns : int or None
        The controller owes a command stamped t_k at every step (None), at
        the steps that are whole multiples of this period (``sim_timer``), or
        at none (0: ``wall``).
    hint : str
        What a stall line suggests when the controller's command is missing.
    """

    topics: tuple[str, ...] = COMMAND_TOPICS
    tick_ns: int | None = None
    hint: str = _STYLE_HINT["stamped"]

    @classmethod
    def of(cls, scn: Scenario) -> CommandWatch:
        """The watch for ``scn``'s ``wheels.command_timing`` and ``wheels.command_rate``."""
        timing = scn.param("wheels", "command_timing")
        if timing == "stamped":
            return cls()
        tick = tick_period_ns(timing, scn.param("wheels", "command_rate"), int(round(scn.dt * 1e9)))
        return cls(tuple(APPLIED_COMMAND_TOPIC.values()), tick, _STYLE_HINT[timing])

    def owes(self, step_ns: int) -> bool:
        """The controller owes a command stamped ``step_ns`` (ns)."""
        if self.tick_ns is None:
            return True
        return is_tick(step_ns, self.tick_ns)


def episode_complete(newest_stamp: dict[str, int], step_topics: list[str], final_ns: int,
                     commands: tuple[str, ...] = COMMAND_TOPICS) -> bool:
    """Every step topic, and one of the ``commands`` topics, holds the episode's last step (stamp ``final_ns``).

    By the greatest stamp taken on each topic (``Recorder.newest_stamp``), on
    top of the counts (:func:`spin_episode` asks both): counts alone were
    fooled, a foreign node's finite messages stamped steps back (in order on
    their own topic, so taken) filling them before the last real ones came,
    and the run's metrics missed its last step; the
    latest stamp would not do either, a stray taken after the last step
    being older.
    """
    return (max(newest_stamp.get(t, -1) for t in commands) >= final_ns
            and all(newest_stamp.get(t, -1) >= final_ns for t in step_topics))


#: wall s a non-finite command may wait for a finite one of its step before the run stops on it: the graph's own
#: controller follows a foreign node's stray at once; a law that made it never does
NONFINITE_GRACE_S = 1.0


def nonfinite_command(bad: tuple[str, int, list[float], float], law: str, dt: float) -> str:
    """The line that stops an episode whose controller commanded non-finite values (``bad``: the recorder's
    such command that no finite one of its step followed, (topic, stamp ns, values, wall s))."""
    topic, t, values, _ = bad
    who = "the external controller" if law == EXTERNAL else f"controller_type {law}"
    shown = ", ".join(f"{v:.6g}" for v in values)
    return (f"{who} commanded a non-finite {topic} at step {int(round(t * 1e-9 / dt))} (t={t * 1e-9:.6f} s): "
            f"[{shown}]; the episode stops")


#: the roles that answer the plant's step k, in the order their outputs depend on each other
STEP_ROLES = ("guidance", "disturbance", "sensors", "estimator", "controller", "wheels")


def _with_culprit(line: str, recorder: Recorder, step_topics: list[str], elapsed: float,
                  watch: CommandWatch = CommandWatch()) -> str:
    """A stopped episode's line, with the wall time since it started and who its last step waited for."""
    culprit = stall_culprit(recorder, step_topics, watch=watch)
    return f"{line} ({elapsed:.1f} s into the episode)" + (f"; {culprit}" if culprit else "")


def stall_culprit(recorder: Recorder, step_topics: list[str], refused_only: bool = False,
                  watch: CommandWatch = CommandWatch()) -> str:
    """Who the step the plant waits on waits for: the first role, in the lockstep's order, none of whose messages
    of one of its outputs came stamped with that step, what came instead, and what may cause it ('' if every
    output of the step is in; with ``refused_only``, also '' unless that role's messages came and were refused,
    the sign of a node that stamps with its own clock rather than a first message lost).

    The step is the plant's newest ``attitude``; the outputs are those of
    :data:`~attitude_sil.ros.contract.ROLE_OUTPUTS` among ``step_topics``
    and the command topics where the controller owes a command (``watch``).
    """
    step_ns = recorder.newest_stamp.get(ATTITUDE)
    if step_ns is None:
        return "the plant published no attitude"
    wanted = set(step_topics) | (set(COMMAND_TOPICS) if watch.owes(step_ns) else set())
    for role in STEP_ROLES:
        for alternatives in ROLE_OUTPUTS[role]:
            topics = [t for t in alternatives if t in wanted]
            if not topics or max(recorder.newest_stamp.get(t, -1) for t in topics) >= step_ns:
                continue
            name = " or ".join(topics)
            newest = max(recorder.newest_stamp.get(t, -1) for t in topics)
            taken = "none taken" if newest < 0 else f"the newest taken stamped {newest * 1e-9:.6f} s"
            refused = sum(recorder.refused.get(t, 0) for t in topics)
            if refused_only and not refused:
                return ""
            stamps = [recorder.refused_stamp[t] for t in topics if t in recorder.refused_stamp]
            instead = taken if not refused else (f"{refused} message(s) refused, the last stamped "
                                                 f"{max(stamps) * 1e-9:.6f} s; {taken}")
            hint = watch.hint if role == "controller" else "docs/flight-software.md"
            return f"the {role} sent no {name} stamped {step_ns * 1e-9:.6f} s ({instead}): {hint}"
    return ""


def _raise_if_stopped(recorder: Recorder, plant, step_topics: list[str], started: float, dt: float,
                      watch: CommandWatch) -> None:
    """The RunError of an episode that cannot go on: the plant (in this process) failed, a command stayed
    non-finite, recording failed, or a publisher cannot match."""
    if plant is not None and plant.error:
        raise RunError(_with_culprit(plant.error, recorder, step_topics, time.monotonic() - started, watch))
    bad = recorder.bad_command
    if bad is not None and time.monotonic() - bad[3] > NONFINITE_GRACE_S:
        raise RunError(nonfinite_command(bad, recorder.controller_type, dt))
    if recorder.error:
        raise RunError(f"{recorder.error}; the bag is readable up to there")
    if recorder.qos_problems:
        raise RunError(recorder.qos_problems[0])


def _commands_in(taken: int, needed: int) -> bool:
    """Of an episode whose step topics are whole, ``taken`` of its ``needed`` commands: True if all, else
    :class:`CommandsLost` at once (a caller can run the episode again, the match now made), not a stall."""
    if taken < needed:
        raise CommandsLost(f"{needed - taken} of the episode's {needed} commands did not reach this tool's "
                           "reader (written before the publisher matched it, or past its history's depth)")
    return True


def spin_episode(recorder: Recorder, spin, plant, children, k_steps: int, scn: Scenario, prog: Progress,
                 schedule: list[tuple[float, int, str]], foreign: ForeignPublishers | None = None,
                 topics: list[str] | None = None, restart: Callable[[], None] | None = None) -> None:
    """Spin until every step topic has all K+1 messages; apply scheduled swaps at their holds.

    ``foreign``, if given, names publishers that are not the graph's own as they appear; ``topics`` are the
    step topics to wait for (default :func:`~attitude_sil.ros.contract.episode_topics`: all but the commands,
    of which one carries each step). A publisher the recorder cannot match stops the episode with its reason.

    ``restart`` (the plant's reset) starts the episode again when its first
    step has not completed within :data:`RESTART_AFTER_S` (or half the
    plant's ``input_timeout``, if less; up to :data:`MAX_RESTARTS` times): the
    nodes read volatile, and across processes a node's first message can be
    written before DDS has matched it with a reader, which then never gets it
    (:mod:`attitude_sil.ros.qos`). Step 0 is a pure function of the
    parameters, so a restart changes no number (a first step that was only
    slow, node processes loading their kernels, is done twice); the recorder
    drops the repeats, and the restart is logged at debug level.

    Raises
    ------
    RunError
        The plant (in this process) failed, recording failed, no step came for
        ``input_timeout`` + 2 s (the plant's, followed as it is set while the
        graph runs), or a node process exited.
    """
    counts = recorder.counts
    needed = k_steps + 1
    dt = scn.dt
    input_timeout = scn.param("plant", "input_timeout")
    restart_after = min(RESTART_AFTER_S, 0.5 * input_timeout)
    last_count, last_change = -1, time.monotonic()
    restarts = 0
    step_topics = episode_topics() if topics is None else topics
    pending = list(schedule)

    watch = CommandWatch.of(scn)

    def commands() -> int:
        return sum(counts[t] for t in watch.topics)

    final_ns = k_steps * int(round(dt * 1e9))
    started = time.monotonic()

    while True:
        spin(0.1)
        n = counts[WHEEL_TORQUE]
        if pending and counts[ATTITUDE] == pending[0][1] and n == pending[0][1] and commands() == n:
            # the plant holds before step k: swap, then release to the next hold
            _, _, kind = pending.pop(0)
            set_remote_parameters(recorder, spin, "controller", {"controller_type": kind})
            set_remote_parameters(recorder, spin, "plant", {"hold_at": pending[0][0] if pending else -1.0})
            last_change = time.monotonic()
        whole = n >= needed and all(counts[t] >= needed for t in step_topics) and episode_complete(
            recorder.newest_stamp, step_topics, final_ns, watch.topics)
        if whole and _commands_in(commands(), needed):
            return
        _raise_if_stopped(recorder, plant, step_topics, started, dt, watch)
        now = time.monotonic()
        if foreign is not None:
            foreign.check(now)
        if n != last_count:
            last_count, last_change = n, now
            prog.update(max(n - 1, 0) * dt)
        elif n == 0 and restart is not None and restarts < MAX_RESTARTS and now - last_change > restart_after:
            restarts += 1
            culprit = stall_culprit(recorder, step_topics, True, watch)  # a lost first message: quiet
            if restarts == 1 and culprit:
                print(f"attitude-sil: step 0 not complete after {now - started:.1f} s: {culprit}; the episode "
                      "starts again (a first message DDS had not yet matched is the usual cause)", file=sys.stderr)
            recorder.get_logger().debug(f"step 0 did not complete within {restart_after:g} s; episode restarted")
            restart()
            last_change = time.monotonic()
        elif now - last_change > (recorder.plant_input_timeout or input_timeout) + 2.0:
            missing = [t for t in step_topics if counts[t] < needed]
            raise RunError(_with_culprit(f"episode stalled at t={max(n - 1, 0) * dt:.3f} s: no progress on "
                                         f"{', '.join(missing)}", recorder, step_topics, now - started, watch))
        check_children(children)
