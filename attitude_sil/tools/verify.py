"""``attitude-sil replay BAG --verify-controller``: controller regression against a recording.

A fresh ``controller`` node, configured as recorded, is fed the recorded
``attitude``, ``body_rate``, ``attitude_setpoint`` and ``rate_setpoint`` of
each step in turn; its command for the step (``voltage_cmd`` or
``torque_cmd``) is compared with the recorded one. The configuration comes
from the parameter snapshot the runner stores in the bag's ``metadata.yaml``
(or from ``--params FILE``), and recorded ``/parameter_events`` of the
controller (gain changes, swaps) are applied before the step they precede,
so a run with a live swap verifies too. Where the bag holds ``dipole_cmd``
(the magnetorquers flew), the controller's magnetic channel is fed the
recorded ``wheel_momentum`` and ``magnetic_field`` (the ``magnetometer``
with estimate feedback) after each step's command, and its dipole is compared
too. This is how a user checks that a
controller change did not alter behaviour on a library of recorded episodes.

A bag outlives the environment it was recorded in: its snapshot holds the
parameters of every law that was installed then. Parameters of a law that
is not installed now are left out, with one notice naming the law(s)
(:func:`recorded_parameters`); only a law that flew (the snapshot's
``controller_type``, or a recorded swap) has to be installed, and a bag
that flew one that is not is refused in one line naming it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy
import yaml
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python

from attitude_sil.core import yaml12
from attitude_sil.core.sim.paramfile import sections_for
from attitude_sil.core.sim.params import GLOBAL_NODE, SCENARIO_NODE, spec_for
from attitude_sil.core.sim.scenario import flatten_parameters, load_scenario, scenario_from_dict, yaml_problem
from attitude_sil.errors import AttitudeSilError, BagError, ScenarioError
from attitude_sil.nodes.controller_node import ControllerNode
from attitude_sil.ros.contract import (
    COMMAND_TOPICS,
    CONTROLLER_INPUTS,
    DIPOLE_CMD,
    DUMPING_INPUTS,
    FEEDBACK_REMAP,
    RECORDED_TOPICS,
    STEP_TOPICS,
    message_class,
)
from attitude_sil.ros.convert import stamp_to_ns, vector_to_array
from attitude_sil.ros.environment import localhost_environment
from attitude_sil.ros.parameters import typed_parameter
from attitude_sil.ros.qos import LOCKSTEP_QOS
from attitude_sil.storage.reader import BagReader, open_bag
from attitude_sil.storage.writer import PARAMETERS_KEY, SCENARIO_KEY
from attitude_sil.tools.snapshot import check_installed, drop_uninstalled, notice

__all__ = ["VerifyResult", "verify_controller", "controller_parameters", "recorded_parameters"]

INPUTS = CONTROLLER_INPUTS
COMMANDS = COMMAND_TOPICS


@dataclass
class VerifyResult:
    """Outcome of a verification.

    Attributes
    ----------
    steps : int
        Steps compared.
    max_deviation : float
        Largest |new - recorded| over steps and axes (V or N m).
    worst_time_s : float
        Sim time of that step.
    worst_axis : int
    tolerance : float
    swaps : int
        Recorded parameter changes applied.
    dipole_steps : int
        Steps whose dipole was compared (0: the bag has no ``dipole_cmd``).
    dipole_deviation : float
        Largest |new - recorded| of the dipole, A m^2.
    """

    steps: int
    max_deviation: float
    worst_time_s: float
    worst_axis: int
    tolerance: float
    swaps: int
    dipole_steps: int = 0
    dipole_deviation: float = 0.0

    @property
    def passed(self) -> bool:
        return self.max_deviation <= self.tolerance and self.dipole_deviation <= self.tolerance


def controller_parameters(bag_path: str | Path, params_file: str | Path | None = None) -> dict:
    """The controller's parameters at the start of the recorded run (:func:`recorded_parameters`'s values)."""
    return recorded_parameters(bag_path, params_file)[0]


def recorded_parameters(bag_path: str | Path, params_file: str | Path | None = None) -> tuple[dict, list[str]]:
    """The controller's parameters at the start of the recorded run, and the laws whose parameters were left out.

    From ``params_file`` (a scenario or parameter YAML) if given, else from the
    snapshot in the bag's metadata.yaml. The snapshot holds the parameters of
    every law installed when the bag was recorded; those of a law not
    installed now are left out and the law named in the second item (the
    caller says so in one line). The law the snapshot flew must be installed.

    Raises
    ------
    BagError
        No snapshot or no controller section in it, a snapshot that is not
        valid YAML or breaks the schema, a flown law that is not installed,
        or a bad ``params_file``.
    """
    if params_file is not None:
        try:
            return load_scenario(params_file).values["controller"], []
        except ScenarioError as exc:
            raise BagError(str(exc)) from None
    path = Path(bag_path)
    meta = (path if path.is_dir() else path.parent) / "metadata.yaml"
    snapshot = None
    if meta.is_file():
        try:
            info = yaml12.load_file(meta)
        except yaml.YAMLError as exc:
            raise BagError(f"{meta}: not valid YAML{yaml_problem(exc)}") from None
        info = info.get("rosbag2_bagfile_information") if isinstance(info, dict) else None
        custom = (info.get("custom_data") if isinstance(info, dict) else None) or {}
        snapshot = custom.get(PARAMETERS_KEY) if isinstance(custom, dict) else None
    if not snapshot:
        raise BagError(f"{path}: the bag holds no parameter snapshot (recorded by another tool, or the run "
                       "was killed before its metadata was written); give --params FILE")
    try:
        data = yaml12.load(str(snapshot))
    except yaml.YAMLError as exc:
        raise BagError(f"{meta}: the parameter snapshot is not valid YAML{yaml_problem(exc)}") from None
    # "/**/controller" (this version) or "controller" (bags recorded before it)
    sections = dict(sections_for(data, "/controller")) if isinstance(data, dict) else {}
    sections.pop(GLOBAL_NODE, None)
    if not sections:
        raise BagError(f"{meta}: the parameter snapshot has no controller section (a controller outside "
                       "attitude_sil flew this bag, run --external controller, or another tool recorded it); "
                       "give --params FILE to check one of the package's laws against it")
    dropped: set[str] = set()
    for key, section in sections.items():
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if isinstance(params, dict):  # anything else is the schema's to refuse, below
            params = flatten_parameters(params)
            check_installed(params.get("controller_type"), str(path))
            kept, laws = drop_uninstalled(params)
            sections[key] = {**section, "ros__parameters": kept}
            dropped.update(laws)
    try:
        values = scenario_from_dict(sections, source=f"{meta}", check=False).values["controller"]
    except ScenarioError as exc:
        raise BagError(f"the parameter snapshot: {exc}") from None
    return values, sorted(dropped)


def _param_changes(reader: BagReader, where: str) -> tuple[list[tuple[int, dict]], list[str]]:
    """Recorded changes of the controller's parameters as (stamp ns, {name: value}), and the laws whose
    parameters were left out (not installed); a swap to a law that is not installed is a BagError naming
    ``where`` (the bag)."""
    out = []
    dropped: set[str] = set()
    topic = reader.find_topic("parameter_events")
    if topic is None:
        return out, []
    for raw, msg in reader.iter_decoded(topics=[topic]):
        if not msg.node.rstrip("/").endswith("controller"):
            continue
        changes = {p.name: parameter_value_to_python(p.value) for p in msg.changed_parameters}
        check_installed(changes.get("controller_type"), where,
                        f" (a swap recorded at t={raw.log_time_ns * 1e-9:.3f} s)")
        changes, laws = drop_uninstalled(changes)
        dropped.update(laws)
        if changes:
            out.append((raw.log_time_ns, changes))
    return out, sorted(dropped)


def _feedback(reader: BagReader) -> str:
    """What the recorded controller read: the ``scenario.feedback`` of the bag's scenario section (``truth`` if
    the bag has none)."""
    try:
        section = yaml12.load(str(reader.custom_data[SCENARIO_KEY]))
        return str(section[SCENARIO_NODE]["ros__parameters"].get("feedback", "truth"))
    except (yaml.YAMLError, KeyError, TypeError, AttributeError):
        return "truth"


def _bag_topics(reader: BagReader, feedback: str = "truth") -> tuple[dict[str, str], list[str]]:
    """The bag's controller input topics (short name -> full name: with ``feedback`` ``estimate`` the
    estimator's outputs, as the run remapped them) and command topics; BagError if missing."""
    names = {}
    for short in INPUTS:
        full = reader.find_topic(FEEDBACK_REMAP.get(short, short) if feedback == "estimate" else short)
        if full is None:
            raise BagError(f"{reader.paths[0]}: no {short} topic: cannot feed a controller")
        names[short] = full
    cmd_topics = [t for t in (reader.find_topic(c) for c in COMMANDS) if t is not None]
    if not cmd_topics:
        raise BagError(f"{reader.paths[0]}: no voltage_cmd or torque_cmd topic to compare with")
    return names, cmd_topics


def _dipole_steps(reader: BagReader, feedback: str) -> tuple[dict[int, dict[str, bytes]], dict[int, np.ndarray]]:
    """The recorded magnetic inputs (raw, by stamp) and dipoles (by stamp) where the bag holds ``dipole_cmd``,
    else two empty mappings; BagError if an input the dipole was made from is missing."""
    dipole = reader.find_topic(DIPOLE_CMD)
    if dipole is None:
        return {}, {}
    names = {}
    for short in DUMPING_INPUTS:
        full = reader.find_topic(FEEDBACK_REMAP.get(short, short) if feedback == "estimate" else short)
        if full is None:
            raise BagError(f"{reader.paths[0]}: dipole_cmd is recorded but not {short}: cannot feed the "
                           "controller's magnetic channel")
        names[full] = short
    inputs: dict[int, dict[str, bytes]] = {}
    for msg in reader.iter_raw(topics=list(names)):
        inputs.setdefault(msg.log_time_ns, {})[names[msg.topic]] = msg.data
    recorded = {raw.log_time_ns: vector_to_array(msg) for raw, msg in reader.iter_decoded(topics=[dipole])}
    return {t: v for t, v in inputs.items() if len(v) == len(DUMPING_INPUTS) and t in recorded}, recorded


def _recorded_steps(reader: BagReader, names: dict[str, str], cmd_topics: list[str]
                    ) -> tuple[dict[int, dict[str, bytes]], dict[int, tuple[str, np.ndarray]], list[int]]:
    """The recorded inputs (raw) and commands by stamp, and the stamps of the steps that have all of them."""
    inputs: dict[int, dict[str, bytes]] = {}
    for msg in reader.iter_raw(topics=list(names.values())):
        inputs.setdefault(msg.log_time_ns, {})[msg.topic.split("/")[-1]] = msg.data
    recorded: dict[int, tuple[str, np.ndarray]] = {}
    for raw, msg in reader.iter_decoded(topics=cmd_topics):
        recorded[raw.log_time_ns] = (raw.topic.split("/")[-1], vector_to_array(msg))
    stamps = sorted(t for t, v in inputs.items() if len(v) == len(INPUTS) and t in recorded)
    if not stamps:
        raise BagError(f"{reader.paths[0]}: no step has all controller inputs and a recorded command")
    return inputs, recorded, stamps


def _apply_changes(ctrl: ControllerNode, pending: list[tuple[int, dict]], t: int) -> int:
    """Apply (and drop from ``pending``) the recorded parameter changes stamped before step ``t``; how many."""
    applied = 0
    while pending and pending[0][0] < t:
        _, change = pending.pop(0)
        results = ctrl.set_parameters([Parameter(k, value=v) for k, v in change.items()])
        if not all(r.successful for r in results):
            raise BagError(f"the recorded change {change} is refused now: "
                           f"{'; '.join(r.reason for r in results if not r.successful)}")
        applied += 1
    return applied


def _deviation(got: tuple[str, np.ndarray], recorded: tuple[str, np.ndarray]) -> tuple[float, int]:
    """Largest |new - recorded| of one step's command and its axis; inf if the command kinds differ."""
    kind, vec = got
    rec_kind, rec_vec = recorded
    if kind != rec_kind:
        return math.inf, 0
    d = np.abs(vec - rec_vec)
    axis = int(np.argmax(d))
    return float(d[axis]), axis


def _spin_until(executor, done: Callable[[], bool], timeout: float, why: str) -> None:
    """Spin until ``done()``; BagError ``why`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            raise BagError(why)
        executor.spin_once(timeout_sec=0.05)


def _feed(feeder: Node, magnetic: bool, got: dict, got_dipole: dict) -> dict:
    """The feeder's publishers of the controller's inputs (and, with ``magnetic``, of its magnetic channel's),
    by name; its subscriptions put each command in ``got`` (stamp -> (topic, value)) and each dipole in
    ``got_dipole`` (stamp -> value)."""
    fed = INPUTS + (DUMPING_INPUTS if magnetic else ())
    pubs = {n: feeder.create_publisher(message_class(RECORDED_TOPICS[n]), n, LOCKSTEP_QOS) for n in fed}
    for c in COMMANDS:
        feeder.create_subscription(
            message_class(STEP_TOPICS[c]), c,
            lambda m, c=c: got.__setitem__(stamp_to_ns(m.header.stamp), (c, vector_to_array(m))), LOCKSTEP_QOS)
    if magnetic:
        feeder.create_subscription(message_class(RECORDED_TOPICS[DIPOLE_CMD]), DIPOLE_CMD,
                                   lambda m: got_dipole.__setitem__(stamp_to_ns(m.header.stamp), vector_to_array(m)),
                                   LOCKSTEP_QOS)
    return pubs


def verify_controller(bag_path: str | Path, params_file: str | Path | None = None, tolerance: float = 1e-9,
                      timeout: float = 10.0, say: Callable[[str], None] | None = None) -> VerifyResult:
    """Feed the recorded plant topics to a fresh controller node and compare its commands.

    ``say`` gets the one notice line when the bag holds parameters of laws
    that are not installed (left out: the bag did not fly them).

    Raises
    ------
    BagError
        Unreadable bag, missing topics, or a controller that does not answer.
    AttitudeSilError
        A tolerance that is not a finite number >= 0.
    """
    if not (math.isfinite(tolerance) and tolerance >= 0.0):
        raise AttitudeSilError(f"--tolerance must be a finite number >= 0, got {tolerance}")
    if params_file is not None:
        controller_parameters(bag_path, params_file)  # a bad --params is refused before the bag is read
    reader = open_bag(bag_path)
    names, cmd_topics = _bag_topics(reader, _feedback(reader))
    values, dropped = recorded_parameters(bag_path, params_file)
    changes, dropped_later = _param_changes(reader, str(bag_path))
    dropped = sorted(set(dropped) | set(dropped_later))
    if dropped and say is not None:
        say(notice(str(bag_path), dropped))
    inputs, recorded, stamps = _recorded_steps(reader, names, cmd_topics)
    magnetic, dipoles = _dipole_steps(reader, _feedback(reader))

    localhost_environment()
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    got: dict[int, tuple[str, np.ndarray]] = {}
    executor = ctrl = feeder = None
    try:
        if magnetic:  # the magnetorquers flew: the controller commands them
            values = {**values, "magnetorquers": True}
        overrides = [typed_parameter(spec_for("controller", k), v) for k, v in values.items() if v != []]
        ctrl = ControllerNode(context=context, parameter_overrides=overrides)
        feeder = Node("verify_feeder", context=context)
        got_dipole: dict[int, np.ndarray] = {}
        pubs = _feed(feeder, bool(magnetic), got, got_dipole)
        executor = EventsExecutor(context=context)
        executor.add_node(ctrl)
        executor.add_node(feeder)
        deadline = time.monotonic() + timeout
        while any(p.get_subscription_count() < 1 for p in pubs.values()) or \
                any(s.get_publisher_count() < 1 for s in feeder.subscriptions
                    if s.topic_name.endswith(("voltage_cmd", "torque_cmd", DIPOLE_CMD))):
            if time.monotonic() > deadline:
                raise BagError("the controller node did not connect")
            executor.spin_once(timeout_sec=0.02)
        pending = list(changes)
        applied = 0
        worst, dipole_worst = (0.0, 0.0, 0), 0.0
        for t in stamps:
            applied += _apply_changes(ctrl, pending, t)
            for n in INPUTS:
                pubs[n].publish(inputs[t][n])
            _spin_until(executor, lambda t=t: t in got, timeout,
                        f"the controller gave no command for t={t * 1e-9:.6f} s")
            dev, axis = _deviation(got[t], recorded[t])
            if dev > worst[0]:
                worst = (dev, t * 1e-9, axis)
            if t in magnetic:  # the step's magnetic inputs come after its command, as in the graph
                for n in DUMPING_INPUTS:
                    pubs[n].publish(magnetic[t][n])
                _spin_until(executor, lambda t=t: t in got_dipole, timeout, f"no dipole_cmd for t={t * 1e-9:.6f} s")
                dipole_worst = max(dipole_worst, float(np.max(np.abs(got_dipole[t] - dipoles[t]))))
        return VerifyResult(len(stamps), worst[0], worst[1], worst[2], tolerance, applied,
                            sum(t in magnetic for t in stamps), dipole_worst)
    finally:
        # destroy explicitly: a context shut down with live nodes leaves them in the graph
        for name in ("executor", "ctrl", "feeder"):
            obj = locals().get(name)
            if obj is not None:
                obj.shutdown() if name == "executor" else obj.destroy_node()
        rclpy.try_shutdown(context=context)
