"""Headless runner: starts the node graph, runs one episode in lockstep, records it.

``launch`` is not available from PyPI, so this module is the project's own
launcher. Two modes:

* in one process (default): every node in one rclpy context, spun by the
  ``EventsExecutor`` (about 7x less overhead per message than the
  ``SingleThreadedExecutor`` here);
* ``processes=True``: one process per node (their console-script modules),
  talking over DDS; this process runs the recorder.

Discovery is awaited by condition (matched publisher/subscription counts and
``wait_for_service``), never by sleeping. Unless the user chose a domain or a
discovery range, the graph stays on this machine
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from attitude_sil.core.controllers import OUTPUT_KIND
from attitude_sil.core.engine import simulate
from attitude_sil.core.metrics import scenario_metrics, segment_metrics
from attitude_sil.core.params import spec_for
from attitude_sil.core.scenario import GRAPH_NODES, Scenario
from attitude_sil.topics import COMMAND_TOPICS, STEP_TOPICS

__all__ = ["RunError", "RunResult", "run_graph", "localhost_environment"]

_DISCOVERY_VARS = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY")

#: who subscribes to what in the graph (the recorder comes on top)
_SUBSCRIBERS = {
    "attitude": 2, "body_rate": 1, "attitude_setpoint": 1, "rate_setpoint": 1, "voltage_cmd": 1, "torque_cmd": 1,
    "wheel_torque": 1, "wheel_momentum": 1, "disturbance_torque": 1, "/clock": 1,
}


#: the --json keys of DESIGN.md section 5 that come from the metrics (null where the scenario has none)
METRIC_KEYS = ("time_constant_s", "rise_time_s", "settling_time_s", "overshoot_pct", "steady_state_error_rad",
               "control_effort_Nms", "cost_J", "iae", "ise", "itae")


class _Interrupt:
    """Turns Ctrl-C into a flag the spin loops check between callbacks.

    A ``KeyboardInterrupt`` raised inside a node callback would tear a step in
    half (and the executor logs it as a fatal callback error); checking a flag
    between ``spin_once`` calls stops the run at a clean point instead.
    """

    def __init__(self) -> None:
        self.requested = False
        self._old = None

    def __enter__(self) -> _Interrupt:
        try:
            self._old = signal.signal(signal.SIGINT, self._on_signal)
        except ValueError:  # not the main thread: leave signals alone
            self._old = None
        return self

    def _on_signal(self, signum, frame) -> None:
        self.requested = True

    def check(self) -> None:
        if self.requested:
            raise KeyboardInterrupt

    def __exit__(self, *exc) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


class RunError(RuntimeError):
    """The episode could not run or did not finish; the message is one line."""


@dataclass
class RunResult:
    """Outcome of one graph run."""

    metrics: dict[str, Any]
    bag: Path | None
    counts: dict[str, int]
    trajectory: dict[str, np.ndarray] = field(default_factory=dict)


def localhost_environment(env: dict[str, str] | None = None) -> dict[str, str]:
    """Keep discovery on this machine unless the user set a discovery variable.

    Returns the (possibly updated) mapping; with ``env=None`` it updates
    ``os.environ`` in place, which rmw reads at ``rclpy.init``.
    """
    target = os.environ if env is None else env
    if not any(v in target for v in _DISCOVERY_VARS):
        target["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return target


#: metadata.yaml custom_data key holding every node's parameters at the start of the run
PARAMETERS_KEY = "attitude_sil.parameters"


def parameters_snapshot(scn: Scenario, extra: dict[str, Any]) -> str:
    """Every graph node's full parameter set at the start, as a ROS 2 parameter YAML string.

    Stored in the bag so ``replay --verify-controller`` can configure a fresh
    controller as recorded; later changes are in ``/parameter_events``.
    """
    out = {}
    for node in GRAPH_NODES:
        values = dict(scn.values[node])
        values.update({k: v for k, v in extra.items() if k in values})
        out[node] = {"ros__parameters": values}
    return yaml.safe_dump(out, sort_keys=True)


def _node_overrides(scn: Scenario, node: str, extra: dict[str, Any]) -> dict[str, Any]:
    values = dict(scn.explicit.get(node, {}))
    values.update({k: v for k, v in extra.items() if k in scn.values[node]})
    return values


def _schedule(scn: Scenario, duration: float) -> list[tuple[float, int, str]]:
    """Scheduled swaps inside the episode as (time s, step index, controller_type)."""
    from attitude_sil.core.engine import schedule_from_scenario

    k_end = scn.steps(duration)
    return [(k * scn.dt, k, kind) for k, kind in schedule_from_scenario(scn) if k <= k_end]


def _extra_params(scn: Scenario, duration: float | None, controller: str | None, real_time: bool) -> dict:
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


class _Progress:
    """A progress line on stderr: sim time, wall time, real-time factor."""

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
    """

    def __init__(self, scn: Scenario, *, duration: float | None = None, controller: str | None = None,
                 processes: bool = False, real_time: bool = False, namespace: str | None = None,
                 connect_timeout: float = 20.0) -> None:
        if controller is not None:
            spec_for("controller", "controller_type").validate(controller, "controller")
        self.scn = scn
        self.extra = _extra_params(scn, duration, controller, real_time)
        self.duration = scn.duration if duration is None else float(duration)
        if self.duration <= 0.0:
            raise RunError("the runner needs a finite episode: give plant.duration or --duration > 0")
        self.processes = processes
        self.namespace = namespace.strip("/") if namespace else None
        self.connect_timeout = connect_timeout
        self.controller = controller or scn.param("controller", "controller_type")

    def __enter__(self) -> GraphSession:
        import rclpy
        from rclpy.experimental import EventsExecutor
        from rclpy.signals import SignalHandlerOptions

        from attitude_sil.bag.recorder import Recorder

        localhost_environment()
        # compile (or load from numba's cache) every law's kernels before the clock
        # starts, so no node compiles mid-episode and node processes find the cache
        for kind in OUTPUT_KIND:
            try:
                simulate(self.scn, 1, duration=self.scn.dt, controller=kind, schedule=[])
            except ValueError:
                pass  # a law this preset's actuator cannot take (e.g. torque into speed-loop wheels)
        self.context = rclpy.Context()
        self.interrupt = _Interrupt().__enter__()
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.nodes: list = []
        self.children: list[subprocess.Popen] = []
        self.tmpdir = None
        self.recorder = None
        try:
            kw = _namespace_kwargs(self.namespace)
            self.recorder = Recorder(None, keep=("attitude", "attitude_setpoint", "wheel_torque", "body_rate",
                                                 "voltage_cmd", "torque_cmd"), context=self.context, **kw)
            self.executor = EventsExecutor(context=self.context)
            self.executor.add_node(self.recorder)
            self.plant = None
            if self.processes:
                self.tmpdir = tempfile.TemporaryDirectory(prefix="attitude_sil_")
                self.children = _start_processes(self.scn, self.extra, Path(self.tmpdir.name), self.namespace)
            else:
                self.plant = _start_nodes(self.scn, self.extra, self.context, self.executor, self.nodes, kw)
            _wait_connected(self.recorder, self.spin, self.nodes, self.children, self.connect_timeout)
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def spin(self, timeout_sec: float) -> None:
        """Process callbacks for up to ``timeout_sec``; raises KeyboardInterrupt after Ctrl-C."""
        self.interrupt.check()
        self.executor.spin_once(timeout_sec=timeout_sec)

    def run_episode(self, *, record_dir: str | Path | None = None, controller_params: dict | None = None,
                    progress: bool = False) -> RunResult:
        """Play one episode; returns its metrics, counts, trajectory and bag."""
        from attitude_sil.bag.writer import BagWriter

        writer = None
        if record_dir is not None:
            extra = dict(self.extra)
            if controller_params:
                extra.update(controller_params)
            try:
                writer = BagWriter(record_dir, custom_data={PARAMETERS_KEY: parameters_snapshot(self.scn, extra)})
            except (FileExistsError, ValueError, OSError) as exc:
                raise RunError(str(exc)) from None
        self.recorder.start_episode(writer)
        prog = _Progress(progress, self.duration)
        schedule = _schedule(self.scn, self.duration)
        try:
            if controller_params:
                set_remote_parameters(self.recorder, self.spin, "controller", controller_params)
            if schedule:  # a scheduled swap ends with the plant released: hold it again
                set_remote_parameters(self.recorder, self.spin, "plant", {"hold_at": schedule[0][0]})
            _call_reset(self.recorder, self.spin, self.connect_timeout)
            wall0 = time.monotonic()
            prog.t0 = wall0
            _spin_episode(self.recorder, self.spin, self.plant, self.children, self.scn.steps(self.duration),
                          self.scn, prog, schedule)
            wall = time.monotonic() - wall0
            prog.update(self.duration, force=True)
        finally:
            self.recorder.writer = None  # stop recording; the kept messages stay for the metrics
            if writer is not None:
                writer.close()
        traj = _trajectory(self.recorder.kept)
        metrics = _metrics(self.scn, traj, self.controller, self.duration, wall, writer, schedule)
        return RunResult(metrics=metrics, bag=None if writer is None else writer.run_dir,
                         counts=dict(self.recorder.counts), trajectory=traj)

    def __exit__(self, *exc) -> None:
        import rclpy

        if getattr(self, "executor", None) is not None:
            self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        self.nodes = []
        _stop_processes(self.children)
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


def _namespace_kwargs(namespace: str | None) -> dict:
    if not namespace:
        return {}
    return {"namespace": "/" + namespace, "cli_args": ["--ros-args", "-r", f"/clock:=/{namespace}/clock"]}


def run_graph(
    scn: Scenario,
    *,
    duration: float | None = None,
    controller: str | None = None,
    record_dir: str | Path | None = None,
    processes: bool = False,
    real_time: bool = False,
    progress: bool = True,
    connect_timeout: float = 20.0,
    namespace: str | None = None,
    controller_params: dict | None = None,
) -> RunResult:
    """Run one episode of ``scn`` through the ROS graph.

    Parameters
    ----------
    scn : Scenario
    duration : float, optional
        Episode length, s (default ``plant.duration``).
    controller : str, optional
        ``controller_type`` to start with.
    record_dir : path, optional
        Bag directory to record to; None records nothing.
    processes : bool
        One process per node instead of one process for all.
    real_time : bool
        Pace the plant at real time (``real_time_factor`` 1.0).
    progress : bool
        Print a progress line on stderr.
    connect_timeout : float
        Wall seconds to wait for discovery.
    namespace : str, optional
        Run the whole graph (and its clock) under this namespace.
    controller_params : dict, optional
        Controller parameters set through the parameter service before the episode.

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
    with GraphSession(scn, duration=duration, controller=controller, processes=processes, real_time=real_time,
                      namespace=namespace, connect_timeout=connect_timeout) as graph:
        return graph.run_episode(record_dir=record_dir, controller_params=controller_params, progress=progress)


def _start_nodes(scn, extra, context, executor, nodes, node_kwargs=None):
    from rclpy.parameter import Parameter

    from attitude_sil.nodes.common import typed_parameter
    from attitude_sil.nodes.controller_node import ControllerNode
    from attitude_sil.nodes.disturbance_node import DisturbanceNode
    from attitude_sil.nodes.guidance_node import GuidanceNode
    from attitude_sil.nodes.plant_node import PlantNode
    from attitude_sil.nodes.wheels_node import WheelsNode

    classes = {"plant": PlantNode, "wheels": WheelsNode, "disturbance": DisturbanceNode,
               "guidance": GuidanceNode, "controller": ControllerNode}
    plant = None
    for name in GRAPH_NODES:
        values = _node_overrides(scn, name, extra)
        # an empty list cannot be typed through an override; every empty value is a default here
        overrides = [typed_parameter(spec_for(name, k), v) for k, v in values.items() if v != []]
        overrides.append(Parameter("use_sim_time", Parameter.Type.BOOL, True))
        try:
            node = classes[name](context=context, parameter_overrides=overrides, **(node_kwargs or {}))
        except ValueError as exc:
            raise RunError(str(exc)) from None
        nodes.append(node)
        executor.add_node(node)
        if name == "plant":
            plant = node
    return plant


def _start_processes(scn, extra, tmp: Path, namespace: str | None = None) -> list[subprocess.Popen]:
    children = []
    for name in GRAPH_NODES:
        values = {k: v for k, v in _node_overrides(scn, name, extra).items() if v != []}
        values["use_sim_time"] = True
        path = tmp / f"{name}.yaml"
        path.write_text(yaml.safe_dump({name: {"ros__parameters": values}}))
        cmd = [sys.executable, "-m", f"attitude_sil.nodes.{name}_node", "--ros-args", "--params-file", str(path)]
        if namespace:
            cmd += ["-r", f"__ns:=/{namespace}", "-r", f"/clock:=/{namespace}/clock"]
        children.append(subprocess.Popen(cmd, stdin=subprocess.DEVNULL))
    return children


def _stop_processes(children: list[subprocess.Popen]) -> None:
    for child in children:
        if child.poll() is None:
            child.send_signal(signal.SIGINT)
    deadline = time.monotonic() + 5.0
    for child in children:
        try:
            child.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def _wait_connected(recorder, spin, nodes, children, timeout: float) -> None:
    """Spin until every publisher has met every subscriber it should."""
    deadline = time.monotonic() + timeout

    def in_process_ready() -> bool:
        subs_per_topic: dict[str, int] = {}
        pubs_per_topic: dict[str, int] = {}
        for node in nodes + [recorder]:
            for s in node.subscriptions:
                subs_per_topic[s.topic_name] = subs_per_topic.get(s.topic_name, 0) + 1
            for p in node.publishers:
                pubs_per_topic[p.topic_name] = pubs_per_topic.get(p.topic_name, 0) + 1
        for node in nodes:
            for p in node.publishers:
                if p.get_subscription_count() < subs_per_topic.get(p.topic_name, 0):
                    return False
        for node in nodes + [recorder]:
            for s in node.subscriptions:
                if s.get_publisher_count() < pubs_per_topic.get(s.topic_name, 0):
                    return False
        return True

    def multi_process_ready() -> bool:
        for name, sub in recorder.subs.items():
            if name in STEP_TOPICS and sub.get_publisher_count() < 1:
                return False
        for name, n in _SUBSCRIBERS.items():
            if recorder.count_subscribers(recorder.resolved[name]) < n + 1:
                return False
        return True

    ready = multi_process_ready if children else in_process_ready
    while not ready():
        for child in children:
            if child.poll() is not None:
                raise RunError(f"node process {child.args[2]} exited with code {child.returncode} during start-up")
        if time.monotonic() > deadline:
            raise RunError(f"the graph did not connect within {timeout:g} s (DDS discovery)")
        spin(0.02)


def _call_reset(recorder, spin, timeout: float) -> None:
    from std_srvs.srv import Trigger

    client = recorder.create_client(Trigger, "plant/reset")
    deadline = time.monotonic() + timeout
    while not client.service_is_ready():
        if time.monotonic() > deadline:
            raise RunError("service plant/reset did not appear")
        spin(0.02)
    future = client.call_async(Trigger.Request())
    while not future.done():
        if time.monotonic() > deadline:
            raise RunError("plant/reset did not answer")
        spin(0.02)
    response = future.result()
    if not response.success:
        raise RunError(response.message)
    recorder.destroy_client(client)


def set_remote_parameters(node, spin, target: str, params: dict[str, Any], timeout: float = 10.0) -> None:
    """Set parameters of node ``target`` through its parameter service; raise RunError on refusal."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(node, target)
    deadline = time.monotonic() + timeout
    while not client.services_are_ready():
        if time.monotonic() > deadline:
            raise RunError(f"parameter service of {target} did not appear")
        spin(0.02)
    future = client.set_parameters([Parameter(k, value=v) for k, v in params.items()])
    while not future.done():
        if time.monotonic() > deadline:
            raise RunError(f"{target} did not answer a parameter set")
        spin(0.02)
    for name, result in zip(params, future.result().results, strict=True):
        if not result.successful:
            raise RunError(f"{target} refused {name}: {result.reason}")


def _spin_episode(recorder, spin, plant, children, k_steps, scn, prog, schedule) -> None:
    """Spin until every step topic has all K+1 messages; apply scheduled swaps at their holds."""
    counts = recorder.counts
    needed = k_steps + 1
    dt = scn.dt
    timeout = scn.param("plant", "input_timeout") + 2.0
    last_count, last_change = -1, time.monotonic()
    step_topics = [t for t in STEP_TOPICS if t not in COMMAND_TOPICS]
    pending = list(schedule)

    def commands() -> int:
        return sum(counts[t] for t in COMMAND_TOPICS)

    while True:
        spin(0.1)
        n = counts["wheel_torque"]
        if pending and counts["attitude"] == pending[0][1] and n == pending[0][1] and commands() == n:
            # the plant holds before step k: swap, then release to the next hold
            _, _, kind = pending.pop(0)
            set_remote_parameters(recorder, spin, "controller", {"controller_type": kind})
            set_remote_parameters(recorder, spin, "plant", {"hold_at": pending[0][0] if pending else -1.0})
            last_change = time.monotonic()
        if n >= needed and commands() >= needed and all(counts[t] >= needed for t in step_topics):
            return
        if plant is not None and plant.error:
            raise RunError(plant.error)
        now = time.monotonic()
        if n != last_count:
            last_count, last_change = n, now
            prog.update(max(n - 1, 0) * dt)
        elif now - last_change > timeout:
            missing = [t for t in step_topics if counts[t] < needed]
            raise RunError(f"episode stalled at t={max(n - 1, 0) * dt:.3f} s: no progress on {', '.join(missing)}")
        for child in children:
            if child.poll() is not None:
                raise RunError(f"node process {child.args[2]} exited with code {child.returncode}")


def _trajectory(kept: dict[str, list[tuple[int, bytes]]]) -> dict[str, np.ndarray]:
    """Decode the kept raw messages into arrays ordered by stamp (last copy per stamp wins)."""
    from rclpy.serialization import deserialize_message

    from attitude_sil.topics import message_class

    out = {}
    for name, items in kept.items():
        by_t: dict[int, bytes] = {}
        for t, data in items:
            by_t[t] = data
        cls = message_class(STEP_TOPICS[name])
        times = sorted(by_t)
        rows = []
        for t in times:
            m = deserialize_message(by_t[t], cls)
            if hasattr(m, "quaternion"):
                q = m.quaternion
                rows.append((q.x, q.y, q.z, q.w))
            else:
                v = m.vector
                rows.append((v.x, v.y, v.z))
        if not rows:
            continue
        out[name] = np.array(rows, dtype=float)
        out[name + "_t"] = np.array(times, dtype=np.int64)
    # the command of each step, whichever topic carried it
    cmd = {}
    for name in ("voltage_cmd", "torque_cmd"):
        if name in out:
            cmd.update(zip(out[name + "_t"].tolist(), out[name], strict=True))
    if cmd:
        out["command"] = np.array([cmd[t] for t in sorted(cmd)])
    return out


def _nan_to_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _metrics(scn, traj, ctrl_type, dur, wall, writer, schedule) -> dict[str, Any]:
    n = min(len(traj["attitude"]), len(traj["attitude_setpoint"]), len(traj["wheel_torque"]))
    t = traj["attitude_t"][:n] * 1e-9
    s = scn.values["scenario"]
    m = scenario_metrics(t, traj["attitude"][None, :n], traj["attitude_setpoint"][None, :n],
                         traj["wheel_torque"][None, :n], s, step_time=scn.param("guidance", "step_time"))
    out: dict[str, Any] = {
        "scenario": scn.name,
        "controller_type": ctrl_type,
        "sim_time_s": float(dur),
        "wall_time_s": float(wall),
        "real_time_factor": float(dur / wall) if wall > 0 else None,
    }
    for key in METRIC_KEYS:
        out[key] = _nan_to_none(float(m[key][0])) if key in m else None
    for key in ("mse", "max_abs_error_rad", "fitness_f", "final_error_rad"):
        if key in m:
            out[key] = _nan_to_none(float(m[key][0]))
    out["bag"] = None if writer is None else str(writer.run_dir)
    if schedule and "command" in traj:
        bounds = [0] + [k for _, k, _ in schedule] + [n]
        kinds = [ctrl_type] + [kind for _, _, kind in schedule]
        out["segments"] = [
            {"controller_type": kind, **segment_metrics(t, traj["attitude"][:n], traj["attitude_setpoint"][:n],
                                                        traj["wheel_torque"][:n], traj["command"][:n], k0, k1,
                                                        axis=s["metrics.axis"])}
            for kind, k0, k1 in zip(kinds, bounds[:-1], bounds[1:], strict=True) if k1 > k0
        ]
    return out
