"""Tools for a graph started by hand (``plant_node``, ..., ``controller_node``): record it, play an episode, measure.

* :func:`record_graph` (``attitude-sil record``): records the topics of a running
  graph to a rosbag2/MCAP bag, as ``ros2 bag record`` does, until a stop
  signal or (``episode=True``) the end of the next episode. Each topic is
  registered when its first publisher appears, with the QoS its publishers
  offer; the bag also keeps a parameter snapshot of the graph's nodes,
  asked through their parameter services as soon as they answer, and the 3D
  view's ``/tf`` (from the snapshot on, with ``lvlh`` where the graph flies an
  orbit) and ``/body_model`` (the recorder's, :mod:`attitude_sil.nodes.recorder_node`).
* :func:`play_episode` (``attitude-sil episode``): starts an episode through
  ``plant/reset``, follows it on the step topics until the plant's duration is
  reached (every step topic holds K + 1 messages; the plant then stops
  publishing) and returns the ``run --json`` metrics.
* :func:`bag_metrics` (``attitude-sil metrics``): the same metrics from a bag.

Both live tools read without the lockstep publishers' transient-local history
(that history is the previous episode) and take the node parameters from the
live graph, so what is measured is what ran. The ``scenario`` section (name,
metrics settings), which no node holds, comes from ``--scenario FILE``, the
bag, or the defaults.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
import yaml
from rclpy.experimental import EventsExecutor
from rclpy.parameter_client import AsyncParameterClient
from rclpy.signals import SignalHandlerOptions

from attitude_sil.core import yaml12
from attitude_sil.core.analysis.metrics import episode_report
from attitude_sil.core.control import registry
from attitude_sil.core.sim.build import build_scene
from attitude_sil.core.sim.paramfile import node_key, section_node
from attitude_sil.core.sim.params import NODE_PARAMS, SCENARIO_NODE
from attitude_sil.core.sim.scenario import (
    ALL_NODES,
    DERIVED,
    GRAPH_NODES,
    SHARED_VALUES,
    Scenario,
    flatten_parameters,
    load_scenario,
    scenario_from_dict,
    yaml_problem,
)
from attitude_sil.errors import AttitudeSilError, BagError, RunError, ScenarioError
from attitude_sil.graph.launcher import namespace_kwargs
from attitude_sil.graph.session import CommandsLost, CommandWatch, Progress, spin_episode
from attitude_sil.graph.trajectory import KEPT_TOPICS, trajectory_from_messages
from attitude_sil.nodes.recorder_node import Recorder
from attitude_sil.ros.contract import (
    CLOCK,
    COMMAND_TOPICS,
    DIAGNOSTICS,
    EXTERNAL,
    MAGNETIC_TOPICS,
    MAGNETIC_TORQUE,
    OPTIONAL_TOPICS,
    RECORDED_TOPICS,
    ROLE_OUTPUTS,
    STEP_TOPICS,
    UNKNOWN_NODE,
    check_namespace,
    episode_topics,
)
from attitude_sil.ros.convert import fault_lines
from attitude_sil.ros.environment import localhost_environment
from attitude_sil.ros.services import PlantReset, get_remote_parameters
from attitude_sil.ros.signals import StopSignals
from attitude_sil.storage.reader import open_bag
from attitude_sil.storage.writer import PARAMETERS_KEY, SCENARIO_KEY, BagWriter, check_bag_dir
from attitude_sil.tools.snapshot import drop_uninstalled, notice

__all__ = ["RecordResult", "bag_metrics", "check_topics", "graph_scenario", "play_episode", "record_graph",
           "scenario_settings"]


def check_topics(topics: list[str] | None) -> dict[str, str]:
    """``--topics`` -> ``name -> type`` of the contract topics to record (all, plus /parameter_events, by default).

    Raises
    ------
    AttitudeSilError
        A name that is not a topic of the contract.
    """
    if not topics:
        return dict(RECORDED_TOPICS)
    by_name = {n.strip("/"): n for n in RECORDED_TOPICS}
    out = {}
    for t in topics:
        name = by_name.get(t.strip("/"))
        if name is None:
            raise AttitudeSilError(f"--topics: {t!r} is not a topic of the graph (one of: "
                                   f"{', '.join(sorted(n.strip('/') for n in RECORDED_TOPICS))})")
        out[name] = RECORDED_TOPICS[name]
    return out


def scenario_settings(path: str | Path | None) -> dict | None:
    """The ``scenario`` section (name, metrics settings) of a scenario file, or None without one.

    Raises
    ------
    ScenarioError
        The file is missing or not a valid scenario.
    """
    return None if path is None else dict(load_scenario(path).values[SCENARIO_NODE])


def _target(namespace: str | None, node: str) -> str:
    return f"/{namespace}/{node}" if namespace else node


def graph_scenario(values: dict[str, dict], settings: dict | None, source: str) -> Scenario:
    """A Scenario from the graph nodes' parameter values (``node -> name -> value``) and a scenario section.

    Raises
    ------
    ScenarioError
        The values break a rule of the schema (the message names ``source``).
    """
    # a value a node shares with its source follows the source (a node started by hand from a file does not
    # know it: the runner would have set it); the source's is what the graph flew
    values = {n: {k: x for k, x in v.items() if not (k in SHARED_VALUES and k in DERIVED.get(n, {}))}
              for n, v in values.items()}
    data: dict = {node_key(n): {"ros__parameters": v} for n, v in values.items()}
    # the control period every node shares: a node that did not answer runs with the graph's
    period = next((values[n]["control_period"] for n in ("plant", "controller")
                   if "control_period" in values.get(n, {})), None)
    if period is not None:
        data = {"/**": {"ros__parameters": {"control_period": period}}, **data}
    if settings:
        data[SCENARIO_NODE] = {"ros__parameters": settings}
    return scenario_from_dict(data, source=source)


#: what each node of the package publishes first (:data:`ROLE_OUTPUTS`, and the magnetorquers' torque)
_OUTPUTS = {**ROLE_OUTPUTS, "magnetorquers": ((MAGNETIC_TORQUE,),)}


def _own_nodes(node, namespace: str | None, spin, timeout: float) -> list[str]:
    """The graph nodes of the package running under ``namespace``.

    A graph node is the package's when the node publishing its outputs
    (:data:`~attitude_sil.ros.contract.ROLE_OUTPUTS`) has the node's name and
    answers for a parameter of the node's schema. Flight software of the
    user's in its place (docs/flight-software.md) does not: its parameters
    are not read. Publishers whose node is not discovered yet are waited for.
    """
    own_ns = f"/{namespace}" if namespace else "/"
    deadline = time.monotonic() + timeout
    own = []
    for name in ALL_NODES:
        optional = name not in GRAPH_NODES  # the sensing loop's and the magnetorquers': where they run
        if name == "magnetorquers" and "plant" in own:  # the plant says whether they fly: then they are waited for
            said = get_remote_parameters(node, spin, _target(namespace, "plant"), ["magnetorquers"],
                                         max(deadline - time.monotonic(), 0.1))
            optional = said.get("magnetorquers") is not True
        topics = [node.resolve_topic_name(t) for t in _OUTPUTS[name][0]]
        while True:
            infos = [i for t in topics for i in node.get_publishers_info_by_topic(t)]
            if infos and all(i.node_name != UNKNOWN_NODE for i in infos) or time.monotonic() > deadline \
                    or (optional and not infos):
                break
            spin(0.02)
        if not any(i.node_name == name and (i.node_namespace.rstrip("/") or "/") == own_ns for i in infos):
            continue
        # a parameter of this node's own (control_period is everyone's), declared with a value
        mark = next(sp.name for sp in NODE_PARAMS[name] if sp.name != "control_period" and sp.default != [])
        if get_remote_parameters(node, spin, _target(namespace, name), [mark], max(deadline - time.monotonic(), 0.1)):
            own.append(name)
    return own


def _ask_graph(node, spin, namespace: str | None, timeout: float,
               say: Callable[[str], None]) -> dict[str, dict]:
    """Every graph node's schema parameters, through their parameter services; warns of a node off sim time.

    A node played by software outside the package (:func:`_own_nodes`) is left out of the result."""
    out = {}
    for name in _own_nodes(node, namespace, spin, timeout):
        # one batch for what always has a value; an empty array is declared without one, and rclpy
        # answers nothing to a batch holding such a name, so those are asked apart
        empty = [s.name for s in NODE_PARAMS[name] if isinstance(s.default, list) and not s.default]
        target = _target(namespace, name)
        values = get_remote_parameters(node, spin, target, [s.name for s in NODE_PARAMS[name]
                                                            if s.name not in empty] + ["use_sim_time"], timeout)
        if empty:
            values.update(get_remote_parameters(node, spin, target, empty, timeout))
        if values.pop("use_sim_time", False) is not True:
            say(f"warning: {_target(namespace, name)} has use_sim_time false: its clock is not the plant's /clock")
        out[name] = values
    return out


class _Ros:
    """A private rclpy context with one node on the EventsExecutor; stop signals checked at every spin."""

    def __init__(self, make_node: Callable[..., Recorder]) -> None:
        localhost_environment()
        self.context = rclpy.Context()
        self.stop = StopSignals().__enter__()
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = None
        self.executor = None
        try:
            self.node = make_node(context=self.context)
            self.executor = EventsExecutor(context=self.context)
            self.executor.add_node(self.node)
        except BaseException:
            self.close()
            raise

    def spin(self, timeout_sec: float) -> None:
        """Process callbacks for up to ``timeout_sec``; raises Interrupted after a stop signal."""
        self.stop.check()
        self.executor.spin_once(timeout_sec=timeout_sec)

    def close(self) -> None:
        if self.executor is not None:
            self.executor.shutdown()
        if self.node is not None:
            self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self.stop.__exit__()


def _wait_publishers(recorder: Recorder, spin, deadline: float, what: str) -> None:
    """Spin until every node of the lockstep publishes what the others read (ROLE_OUTPUTS), whoever plays it
    (the sensing loop's nodes are optional: a hand-started graph may run without them)."""
    def missing() -> list[str]:
        return [" or ".join(alt) for role in GRAPH_NODES for alt in ROLE_OUTPUTS[role]
                if not any(recorder.subs[t].get_publisher_count() > 0 for t in alt)]

    while gaps := missing():
        if recorder.qos_problems:
            raise RunError(recorder.qos_problems[0])
        if time.monotonic() > deadline:
            raise RunError(f"no publisher of {', '.join(gaps)} within the timeout: is the graph running{what}?")
        spin(0.02)


def _graph_ready(recorder: Recorder, namespace: str | None, clients: dict) -> bool:
    """The whole graph is up, whoever plays each node: every lockstep role's outputs published, and the parameter
    service of each graph node that runs under its name ready."""
    if any(not any(recorder.subs[t].get_publisher_count() > 0 for t in alt)
           for role in GRAPH_NODES for alt in ROLE_OUTPUTS[role] if all(t in recorder.subs for t in alt)):
        return False
    present = {n for n, ns in recorder.get_node_names_and_namespaces()
               if (ns.rstrip("/") or "/") == (f"/{namespace}" if namespace else "/")}
    return all(c.services_are_ready() for n, c in clients.items() if n in present)


def _live_topics(recorder: Recorder, external: list[str]) -> list[str]:
    """The step topics an episode of a live graph fills: an optional one, and the magnetorquers' (which come
    after the step's command), only where somebody publishes it."""
    return [t for t in (*episode_topics(external), *MAGNETIC_TOPICS)
            if (t not in OPTIONAL_TOPICS and t not in MAGNETIC_TOPICS)
            or (t in recorder.subs and recorder.subs[t].get_publisher_count() > 0)]


def play_episode(namespace: str | None = None, scenario: str | Path | None = None, timeout: float = 20.0,
                 progress: bool = False, say: Callable[[str], None] = print) -> dict:
    """Start an episode on a running graph through ``plant/reset``, follow it to its end, return its metrics.

    Parameters
    ----------
    namespace : str, optional
        The graph's namespace.
    scenario : path, optional
        A scenario file whose ``scenario`` section (name, metrics settings) the
        metrics use; the node parameters are read from the live graph.
    timeout : float
        Wall seconds to wait for the graph (publishers, parameter and reset services).
    progress : bool
        A progress line on stderr.
    say : callable
        Where warnings go (a node off sim time).

    Returns
    -------
    dict
        The ``run --json`` object (``bag`` is null).

    Raises
    ------
    AttitudeSilError
        Bad input, a graph that does not answer, a refused reset, a stalled episode.
    Interrupted
        A stop signal (nothing is kept).
    """
    ns = check_namespace(namespace)
    settings = scenario_settings(scenario)  # before ROS: a bad file is one line
    where = f" under /{ns}" if ns else ""
    ros = _Ros(lambda **kw: Recorder(None, keep=KEPT_TOPICS, history=False, name="episode",
                                     **kw, **namespace_kwargs(ns)))
    try:
        rec = ros.node
        reset = PlantReset(rec, _target(ns, "plant") + "/reset")  # before the waits: matched by its first call
        deadline = time.monotonic() + timeout
        _wait_publishers(rec, ros.spin, deadline, where)
        values = _ask_graph(rec, ros.spin, ns, max(deadline - time.monotonic(), 0.1), say)
        external = [n for n in GRAPH_NODES if n not in values]  # played by software outside the package
        for name in external:
            say(f"note: {_target(ns, name)} is not attitude_sil's: its settings are the defaults or --scenario's")
        scn = graph_scenario(values, settings, f"the graph{where}")
        if scn.duration <= 0.0:
            raise RunError(f"plant.duration is 0 on the graph{where} (run until stopped): the episode would not end; "
                           f"set it, e.g. attitude-sil param set {_target(ns, 'plant')} duration 20.0")
        for again in (False, True):  # a second time where a volatile publisher's commands were lost
            rec.start_episode(None)
            reset(ros.spin, max(deadline - time.monotonic(), 0.1))
            wall0 = time.monotonic()
            prog = Progress(progress, scn.duration)
            prog.t0 = wall0
            try:
                spin_episode(rec, ros.spin, None, [], scn.steps(), scn, prog, [],
                             topics=_live_topics(rec, external), restart=lambda: reset(ros.spin, timeout))
                break
            except CommandsLost as exc:
                if again:
                    raise
                say(f"note: {exc}; the episode runs again")
        wall = time.monotonic() - wall0
        prog.update(scn.duration, force=True)
        traj = trajectory_from_messages(rec.kept)
    finally:
        ros.close()
    law = EXTERNAL if "controller" in external else scn.param("controller", "controller_type")
    metrics = episode_report(scn, traj, law, scn.duration, wall)
    metrics["faults"] = list(rec.faults)
    metrics["bag"] = None
    return metrics


@dataclass
class RecordResult:
    """What ``record`` wrote: the bag, its message count per topic, whether it has a parameter snapshot."""

    bag: Path
    counts: dict[str, int] = field(default_factory=dict)
    snapshot: bool = False
    episode_done: bool = False


def _record_topics(bag: str | Path, topics: list[str] | None, episode: bool) -> tuple[dict[str, str], list[str]]:
    """``record``'s checks before ROS starts: the topics to record and the per-step ones among them."""
    selected = check_topics(topics)
    try:
        check_bag_dir(bag)
    except (ValueError, OSError) as exc:
        raise AttitudeSilError(str(exc)) from None
    per_step = [n for n in selected if n in STEP_TOPICS and n not in COMMAND_TOPICS]
    if episode and not per_step:
        raise AttitudeSilError("--episode needs a step topic among --topics (e.g. attitude) to see the episode end")
    return selected, per_step


class _EpisodeEnds:
    """Watches ``record``'s per-step topics for the end of each episode and reports it once."""

    def __init__(self, per_step: list[str], selected: dict[str, str]) -> None:
        self.per_step = per_step
        self.selected = selected
        self.reported_end = False
        self.counted = 0  # messages of per_step[0] in the episodes reported

    def check(self, rec: Recorder, scn: Scenario, say: Callable[[str], None]) -> bool:
        """Report an episode that has just ended (with how many of its steps were recorded); True if one has."""
        # the plant's last step (t = duration) has reached every per-step topic: the plant stops there
        end_ns = scn.steps() * round(scn.dt * 1e9)
        # an optional topic (OPTIONAL_TOPICS) counts once somebody publishes it
        ended = all(rec.last_stamp.get(n) == end_ns for n in self.per_step
                    if n not in OPTIONAL_TOPICS or n in rec.last_stamp)
        # and the last step's command, which the controller sends after the state it answers: without it the bag's
        # trajectory (and its metrics) would end a step short
        commands = [n for n in CommandWatch.of(scn).topics if n in self.selected]
        ended = ended and (not commands or any(rec.last_stamp.get(n) == end_ns for n in commands))
        # and the magnetorquers' dipole and torque, which follow the command, where they fly
        ended = ended and all(rec.last_stamp.get(n) == end_ns for n in MAGNETIC_TOPICS
                              if n in self.selected and n in rec.last_stamp)
        new_end = ended and not self.reported_end
        if new_end:
            steps = rec.counts.get(self.per_step[0], 0) - self.counted
            self.counted += steps
            say(f"episode recorded to t={end_ns * 1e-9:.3f} s: {steps} of {scn.steps() + 1} steps on "
                f"{rec.resolved[self.per_step[0]]}" + ("" if steps == scn.steps() + 1 else
                                                      " (started recording after the episode began)"))
        self.reported_end = ended  # a new episode (stamps back at its start) is reported again at its end
        return new_end


def record_graph(bag: str | Path, topics: list[str] | None = None, namespace: str | None = None,
                 episode: bool = False, say: Callable[[str], None] = print) -> RecordResult:
    """Record a running graph to ``bag`` until a stop signal, or the end of the next episode with ``episode``.

    Parameters
    ----------
    bag : path
        The bag directory to create.
    topics : list of str, optional
        Topics of the contract to record (default: all of them and ``/parameter_events``).
    namespace : str, optional
        The graph's namespace.
    episode : bool
        Stop once an episode has started and reached the plant's duration.
    say : callable
        Where the progress lines go (one per topic subscribed, the snapshot,
        one at the end of each episode recorded).

    Returns
    -------
    RecordResult

    Raises
    ------
    AttitudeSilError
        Bad input, a bag that cannot be created, a failed write.
    """
    ns = check_namespace(namespace)
    selected, per_step = _record_topics(bag, topics, episode)
    where = f" under /{ns}" if ns else ""
    ros = _Ros(lambda **kw: Recorder(None, topics=selected, history=False, qos_from_graph=True, name="record",
                                     **kw, **namespace_kwargs(ns)))
    writer = None
    result = RecordResult(Path(bag))
    try:
        rec = ros.node
        try:
            writer = BagWriter(bag)
        except (FileExistsError, ValueError, OSError) as exc:
            raise AttitudeSilError(str(exc)) from None
        rec.start_episode(writer, across_episodes=True)
        say(f"recording {len(selected)} topic(s){where} to {bag}; Ctrl-C to stop")
        clients = {n: AsyncParameterClient(rec, _target(ns, n)) for n in GRAPH_NODES}
        scn = None
        ask_at, asked = 0.0, False  # when to ask the graph for its parameters (again)
        ends = _EpisodeEnds(per_step, selected)
        while True:
            try:  # a stop signal (Ctrl-C, SIGTERM, SIGHUP) ends the recording: the normal way to stop it
                ros.spin(0.05)
                for name in rec.register_discovered():
                    say(f"subscribed to {rec.resolved[name]}")
                if scn is None and time.monotonic() >= ask_at and _graph_ready(rec, ns, clients):
                    try:
                        values = _ask_graph(rec, ros.spin, ns, 5.0, say)
                    except RunError as exc:  # a node just started answers once it spins: ask again, keep recording
                        if not asked:
                            say(f"parameter snapshot: {exc}; asking again")
                        asked, ask_at = True, time.monotonic() + 1.0
                        continue
                    scn = graph_scenario(values, None, f"the graph{where}")
                    rec.set_scene(build_scene(values))  # the 3D view: lvlh and the body model from here on
                    writer.set_custom_data(PARAMETERS_KEY, scn.parameters_yaml(nodes=list(values)))
                    result.snapshot = True
                    say(f"parameter snapshot of {', '.join(_target(ns, n) for n in values)}")
            except KeyboardInterrupt:
                break
            if rec.error:
                raise RunError(f"{rec.error}; the bag is readable up to there")
            if per_step and scn is not None and scn.duration > 0 and ends.check(rec, scn, say) and episode:
                result.episode_done = True
                break
        result.counts = {rec.resolved[n]: c for n, c in rec.counts.items()}
    finally:
        try:
            if writer is not None:
                writer.close()
        finally:
            ros.close()
    return result


def _snapshot_values(text: str, where: str) -> dict[str, dict]:
    try:
        data = yaml12.load(text)
    except yaml.YAMLError as exc:
        raise BagError(f"{where}: the parameter snapshot is not valid YAML{yaml_problem(exc)}") from None
    if not isinstance(data, dict):
        raise BagError(f"{where}: the parameter snapshot is not a parameter mapping")
    out: dict[str, dict] = {}
    for key, section in data.items():
        node = section_node(str(key))
        if node in ALL_NODES and isinstance(section, dict):
            out.setdefault(node, {}).update(section.get("ros__parameters") or {})
    return out


def _installed_laws_only(values: dict[str, dict], where: str, notes: list[str]) -> str | None:
    """The snapshot's controller section without the parameters of laws not installed here (a note names them).

    The metrics run no law, so a bag that flew one not installed is read as well (its law named in a note and
    returned, the section's ``controller_type`` left to its default); else None.
    """
    kept, missing = drop_uninstalled(flatten_parameters(values["controller"]))
    if missing:
        notes.append(notice(where, missing))
    flown = kept.get("controller_type")
    if not isinstance(flown, str) or flown in registry.names():
        values["controller"] = kept
        return None
    notes.append(f"{where}: the bag flew controller_type {flown}, not installed here; its metrics need no law")
    values["controller"] = {k: v for k, v in kept.items() if k != "controller_type"}
    return flown


def bag_metrics(bag: str | Path, scenario: str | Path | None = None) -> tuple[dict, list[str]]:
    """The ``run --json`` metrics of the episode a bag holds, and notes on how they were found.

    Node parameters come from the bag's snapshot (``metadata.yaml`` custom
    data), else from ``scenario``; the ``scenario`` section from ``scenario``,
    else the bag, else the defaults (said in a note). ``wall_time_s`` and
    ``real_time_factor`` are null: a bag has no wall time.

    Raises
    ------
    AttitudeSilError
        An unreadable bag, no snapshot and no ``scenario``, no episode in the bag.
    """
    settings = scenario_settings(scenario)
    reader = open_bag(bag)
    custom = reader.custom_data
    notes: list[str] = []
    snapshot = custom.get(PARAMETERS_KEY)
    if not snapshot and scenario is None:
        raise BagError(f"{bag}: the bag holds no parameter snapshot (recorded by another tool, or the graph's "
                       "nodes did not answer); give --scenario FILE")
    if settings is None and custom.get(SCENARIO_KEY):
        settings = _scenario_section(custom[SCENARIO_KEY], str(bag))
    law = None
    try:
        if snapshot:
            values = _snapshot_values(snapshot, str(bag))
            law = None if "controller" in values else EXTERNAL  # a controller of the user's flew (run --external)
            if law is None:
                law = _installed_laws_only(values, str(bag), notes)
            scn = graph_scenario(values, settings, f"{bag} (parameter snapshot)")
        else:
            scn = load_scenario(scenario)
            notes.append(f"no parameter snapshot in {bag}: node parameters from {scenario}")
    except ScenarioError as exc:
        raise BagError(str(exc)) from None
    if settings is None:
        notes.append(f"{bag} has no scenario section (metrics settings): defaults used; give --scenario FILE")
    kept = {}
    for name in KEPT_TOPICS:
        full = reader.find_topic(name)
        kept[name] = [] if full is None else [(m.log_time_ns, m.data) for m in reader.iter_raw(topics=[full])]
    clock = reader.find_topic(CLOCK)
    if clock is not None:
        resets = sum(1 for m in reader.iter_raw(topics=[clock]) if m.log_time_ns == 0)
        if resets > 1:
            notes.append(f"{bag} holds {resets} episodes; the first message of each step counts")
    traj = trajectory_from_messages(kept)
    if traj.t.size < 2:
        raise BagError(f"{bag}: holds no episode (fewer than two steps on attitude, body_rate, setpoints, "
                       "command, wheel and disturbance topics)")
    duration = float(traj.t[-1] - traj.t[0])
    if duration + 0.5 * scn.dt < scn.duration:
        notes.append(f"{bag} holds {duration:g} s of a {scn.duration:g} s episode; metrics over what it holds")
    metrics = episode_report(scn, traj, law or scn.param("controller", "controller_type"), duration, 0.0)
    diagnostics = reader.find_topic(DIAGNOSTICS)
    metrics["faults"] = [] if diagnostics is None else \
        [line for m in reader.iter_raw(topics=[diagnostics]) for line in fault_lines(m.data)]
    metrics["wall_time_s"] = None
    metrics["real_time_factor"] = None
    metrics["bag"] = str(bag)
    return metrics, notes


def _scenario_section(text: str, where: str) -> dict | None:
    try:
        data = yaml12.load(text)
    except yaml.YAMLError as exc:
        raise BagError(f"{where}: the scenario section in metadata.yaml is not valid YAML{yaml_problem(exc)}") from None
    section = data.get(SCENARIO_NODE) if isinstance(data, dict) else None
    values = section.get("ros__parameters") if isinstance(section, dict) else None
    return values if isinstance(values, dict) else None
