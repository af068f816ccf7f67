"""Scenario files: ROS 2 parameter YAML validated against the node schema.

A scenario is a standard ``/**/node_name: ros__parameters: {...}`` file, so the
same file can be handed to ``ros2 run ... --params-file`` under any namespace.
Sections:

* one per node (``plant``, ``wheels``, ``disturbance``, ``guidance``,
  ``controller``), keyed ``/**/node`` (what the project writes), ``node``,
  ``/node`` or ``/ns/node`` (:func:`attitude_sil.core.sim.paramfile.section_node`:
  the namespace part is ignored, a scenario is one graph; two keys naming
  the same node are merged in file order);
* ``/**`` for names shared by every node that declares them (``control_period``);
* ``scenario`` for what only the runner reads (name, metrics settings).

Unknown sections and keys, wrong types and out-of-range values raise
:class:`ScenarioError` with one line naming the file, the key and the rule.
"""

from __future__ import annotations

import copy
import difflib
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from attitude_sil.core import yaml12
from attitude_sil.core.control.laws.bdot import detumble_gain
from attitude_sil.core.control.momentum import BDOT
from attitude_sil.core.environment.ephemeris import Ephemeris
from attitude_sil.core.faults import FAULT_NODES, OWNER, faults_of, parse_faults, wheel_failure_values
from attitude_sil.core.plant.rigid_body import inertia_matrix
from attitude_sil.core.plant.wheels import GEOMETRIES
from attitude_sil.core.sensing.models import SensorSuite
from attitude_sil.core.sim.paramfile import node_key, section_node
from attitude_sil.core.sim.params import GLOBAL_NODE, NODE_PARAMS, SCENARIO_NODE
from attitude_sil.errors import ScenarioError

__all__ = ["ScenarioError", "Scenario", "load_scenario", "scenario_from_dict", "with_parameter_file", "yaml_problem",
           "GRAPH_NODES", "SENSOR_NODES", "MAGNETIC_NODES", "ALL_NODES", "PRESETS", "default_config_dir",
           "derived_values", "effective_values", "flatten_parameters", "check_fault_lines"]

#: the preset scenarios of the five papers (``config/<name>.yaml``)
PRESETS = ("hst_roll_step", "hawaiisat_lvlh", "flexible_axis", "cubesat_1u", "pitch_axis")


def default_config_dir() -> Path:
    """The presets: the repository's ``config/`` (or the installed ``share/attitude_sil/config``)."""
    here = Path(__file__).resolve().parents[3] / "config"
    if here.is_dir():
        return here
    return Path(sys.prefix) / "share" / "attitude_sil" / "config"


#: nodes of the graph, in the order the runner starts them
GRAPH_NODES = ("plant", "wheels", "disturbance", "guidance", "controller")

#: the nodes of the sensing loop (docs/sensors.md), started after the others when a scenario runs them
#: (:attr:`Scenario.has_sensors`)
SENSOR_NODES = ("sensors", "estimator")

#: the magnetorquers (docs/orbit-and-field.md), started after the others when a scenario flies them
#: (:attr:`Scenario.has_magnetorquers`)
MAGNETIC_NODES = ("magnetorquers",)

#: every node a scenario configures
ALL_NODES = GRAPH_NODES + SENSOR_NODES + MAGNETIC_NODES


def _suggest(name: str, options) -> str:
    close = difflib.get_close_matches(name, list(options), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


@dataclass
class Scenario:
    """Validated parameter values of every node.

    Attributes
    ----------
    values : dict
        ``node -> name -> value`` for every declared parameter, defaults filled in.
    explicit : dict
        ``node -> name -> value`` of what the file set (after ``/**`` expansion);
        this is what is handed to the nodes as parameter overrides.
    source : str
        File path or a label, for messages.
    """

    values: dict[str, dict[str, Any]]
    explicit: dict[str, dict[str, Any]]
    source: str = "<scenario>"

    def param(self, node: str, name: str) -> Any:
        """Value of ``node``'s parameter ``name``."""
        return self.values[node][name]

    @property
    def name(self) -> str:
        return self.values[SCENARIO_NODE]["name"] or Path(self.source).stem

    @property
    def dt(self) -> float:
        return self.values["plant"]["control_period"]

    @property
    def duration(self) -> float:
        return self.values["plant"]["duration"]

    @property
    def feedback(self) -> str:
        """What the controller reads: ``truth`` or ``estimate`` (``scenario.feedback``)."""
        return self.values[SCENARIO_NODE]["feedback"]

    @property
    def has_sensors(self) -> bool:
        """Whether the sensors and the estimator run: ``scenario.sensors``, estimate feedback, or a section of
        either node in the file."""
        shared = {"control_period", "faults"}  # what a /** section gives every node (a fault list does not start it)
        return bool(self.values[SCENARIO_NODE]["sensors"] or self.feedback == "estimate"
                    or any(set(self.explicit.get(n, {})) - shared for n in SENSOR_NODES))

    @property
    def has_magnetorquers(self) -> bool:
        """Whether the magnetorquers fly: the controller commands a dipole (``momentum.mode``, ``bdot``
        among the laws it flies, first or scheduled, or the rods as its ``torque_actuator``)."""
        c = self.values["controller"]
        laws = {c["controller_type"], *self.values[SCENARIO_NODE]["schedule.controller_types"]}
        return c["momentum.mode"] != "none" or BDOT in laws or c["torque_actuator"] == "magnetorquers"

    @property
    def nodes(self) -> tuple[str, ...]:
        """The nodes this scenario's graph runs, in start order."""
        return (GRAPH_NODES + (SENSOR_NODES if self.has_sensors else ())
                + (MAGNETIC_NODES if self.has_magnetorquers else ()))

    def steps(self, duration: float | None = None) -> int:
        """Number of control steps K in the episode (states at k = 0..K)."""
        d = self.duration if duration is None else duration
        return int(round(d / self.dt))

    def with_values(self, node: str, **updates: Any) -> Scenario:
        """A copy with some of ``node``'s parameters replaced (validated).

        ``node="/**"`` sets a name on every graph node that declares it.
        Dotted names can be given with ``__`` (``pid__kp``) or through ``**{"pid.kp": ...}``.
        """
        new = copy.deepcopy(self)
        specs = {s.name: s for s in NODE_PARAMS[node]}
        for key, value in updates.items():
            name = key.replace("__", ".")
            if name not in specs:
                raise ScenarioError(f"{node} has no parameter {name!r}{_suggest(name, specs)}")
            try:
                v = specs[name].validate(value, node)
            except ValueError as exc:
                raise ScenarioError(str(exc)) from None
            targets = [n for n in ALL_NODES if any(sp.name == name for sp in NODE_PARAMS[n])] \
                if node == GLOBAL_NODE else [node]
            for target in targets:
                new.values[target][name] = copy.deepcopy(v)
                new.explicit.setdefault(target, {})[name] = copy.deepcopy(v)
        _check_consistency(new)
        return new

    def parameters_yaml(self, extra: dict[str, Any] | None = None, nodes=GRAPH_NODES) -> str:
        """The full parameter set of the graph's ``nodes`` (default: all) as a ROS 2 parameter YAML string.

        ``extra`` values override the nodes that declare them. Runs store this
        in their bag (``metadata.yaml`` custom data) so ``replay
        --verify-controller`` can configure a fresh controller as recorded; a
        node played from outside the package (``run --external``) is left out.
        """
        extra = extra or {}
        out = {}
        for node in nodes:
            values = effective_values(self, node)  # what the node runs with: its derived values too
            values.update({k: v for k, v in extra.items() if k in values})
            out[node_key(node)] = {"ros__parameters": values}
        return yaml.safe_dump(out, sort_keys=True)

    def scenario_yaml(self) -> str:
        """The ``scenario`` section (name, metrics settings) as parameter YAML: what a bag keeps for its metrics."""
        return yaml.safe_dump({SCENARIO_NODE: {"ros__parameters": dict(self.values[SCENARIO_NODE])}},
                              sort_keys=True)

    def params_file_dict(self) -> dict:
        """The explicit values as a ROS 2 parameter YAML mapping (``/**/node`` keys)."""
        return {
            node_key(node): {"ros__parameters": dict(vals)}
            for node, vals in self.explicit.items()
            if node in ALL_NODES and vals
        }


#: what a node takes from another node's parameters unless the scenario sets it: node -> name -> (node, name)
DERIVED = {"estimator": {"initial_attitude_rpy_deg": ("plant", "initial_attitude_rpy_deg"),
                         "star_tracker.rate_hz": ("sensors", "star_tracker.rate_hz"),
                         "star_tracker.latency_s": ("sensors", "star_tracker.latency_s")},
           **{node: {"command_timing": ("wheels", "command_timing"), "command_rate": ("wheels", "command_rate")}
              for node in ("plant", "guidance")}}
DERIVED["disturbance"] = {"environment.magnetic_field.model": ("plant", "environment.magnetic_field.model")}


#: derived values a node must not set otherwise than their source (the estimator's may differ: they are beliefs)
SHARED_VALUES = ("command_timing", "command_rate", "environment.magnetic_field.model")


def derived_values(scn: Scenario, node: str) -> dict[str, Any]:
    """The values ``node`` takes from another node's unless the scenario sets them (:data:`DERIVED`): the
    estimator starts from the plant's initial attitude and expects the sensors' star tracker schedule; the
    plant and the guidance order ``/clock`` for the controller timing the wheels hold commands for."""
    mine = scn.explicit.get(node, {})
    out = {name: copy.deepcopy(scn.values[src][src_name]) for name, (src, src_name) in DERIVED.get(node, {}).items()
           if name not in mine}
    if node in ("plant", "controller"):  # the magnetorquers fly: the plant takes their torque, the controller
        out["magnetorquers"] = scn.has_magnetorquers  # commands them
    if node == "controller" and scn.values[node]["bdot.gain"] == 0.0 and scn.has_magnetorquers:
        out["bdot.gain"] = detumble_gain_star(scn)
    return out


def detumble_gain_star(scn: Scenario) -> float:
    """Avanzini and Giulietti's B-dot gain k* (:func:`~attitude_sil.core.control.laws.bdot.detumble_gain`)
    for the plant's orbit and inertia: n from the orbit's energy at t = 0, xi_m the angle between the orbit's
    normal and the Earth's axis (the geomagnetic equator taken as the equator: the dipole's tilt, 9.2 deg in
    IGRF-14 for 2026, turns with the Earth), J_min the smallest principal inertia."""
    p = scn.values["plant"]
    now = Ephemeris(p, scn.dt).at(0)
    r, v, mu = np.linalg.norm(now.r_N), np.linalg.norm(now.v_N), float(p["orbit.mu"])
    a = 1.0 / (2.0 / r - v * v / mu)  # vis-viva
    normal = np.cross(now.r_N, now.v_N)
    xi_m = float(np.arccos(min(abs(normal[2]) / np.linalg.norm(normal), 1.0)))
    j_min = float(np.min(np.linalg.eigvalsh(inertia_matrix(p["inertia"]))))
    return detumble_gain(float(np.sqrt(mu / a**3)), xi_m, j_min)


def effective_values(scn: Scenario, node: str) -> dict[str, Any]:
    """``node``'s values as it runs: the scenario's, with :func:`derived_values` laid over them."""
    return {**scn.values[node], **derived_values(scn, node)}


#: the nodes that fly the orbit (the plant publishes it, the guidance and the disturbances read it): one orbit
ORBIT_NODES = ("plant", "guidance", "disturbance")


def _check_one_orbit(scn: Scenario) -> None:
    """Every ``orbit.*`` value the same in the nodes that fly the orbit."""
    names = sorted({n for node in ORBIT_NODES for n in scn.values[node] if n.startswith("orbit.")})
    for name in names:
        values = {node: scn.values[node][name] for node in ORBIT_NODES if name in scn.values[node]}
        if len({repr(v) for v in values.values()}) > 1:
            listing = ", ".join(f"{node}={v!r}" for node, v in values.items())
            raise ScenarioError(f"{scn.source}: {name} differs between nodes ({listing}); set it under /** (the "
                                "plant, the guidance and the disturbances fly one orbit)")


def _check_torque_actuator(scn: Scenario) -> None:
    """The rods make a torque law's demand only on a spacecraft without wheels, and only that: one actuator
    per torque, none left without one."""
    c, actuator = scn.values["controller"], scn.values["wheels"]["actuator"]
    rods = c["torque_actuator"] == "magnetorquers"
    if rods and actuator != "none":
        raise ScenarioError(f"{scn.source}: controller.torque_actuator magnetorquers sends the torque demand to "
                            f"the rods, but wheels.actuator is {actuator}: set wheels actuator none")
    if actuator == "none" and not rods:
        raise ScenarioError(f"{scn.source}: wheels.actuator none makes no torque: set controller torque_actuator "
                            "magnetorquers (the rods make the law's demand)")
    if rods and c["momentum.mode"] != "none":
        raise ScenarioError(f"{scn.source}: controller.momentum.mode {c['momentum.mode']} dumps wheel momentum, "
                            "and torque_actuator magnetorquers flies no wheels: set momentum.mode none")
    if rods and c["command"] != "torque" and c["controller_type"] != "geometric":
        raise ScenarioError(f"{scn.source}: controller.torque_actuator magnetorquers makes a torque demand: set "
                            "controller command torque")


def check_fault_lines(scn: Scenario, lines) -> list:
    """The faults of ``lines`` as this scenario would fly them (its targets, its length): the parsed faults.

    Raises
    ------
    ScenarioError
        One line for the first that cannot fly.
    """
    w = scn.values["wheels"]
    n_wheels = GEOMETRIES[w["geometry"]]().shape[1] if w["actuator"] == "reaction_wheels" else None
    return parse_faults(lines, scn.duration, n_wheels, scn.has_sensors, scn.has_magnetorquers)


def _check_faults(scn: Scenario) -> None:
    """The ``faults`` list flies in this run: targets it has, times within it, one wheel fault at most."""
    w = scn.values["wheels"]
    try:
        for node in FAULT_NODES:  # each node's list (one list under /**, or a section's own)
            for fault in check_fault_lines(scn, scn.values[node]["faults"]):
                owner = OWNER[fault.kind]  # set on a node alone, a fault must reach the node that flies it
                if owner in FAULT_NODES and str(fault) not in map(str, faults_of(scn.values[owner], owner)):
                    raise ScenarioError(f"fault '{fault}' is set on the {node} but flown by the {owner} node: set "
                                        f"it under /** or /**/{owner}")
        wheel_failure_values(w)
    except ScenarioError as exc:
        raise ScenarioError(f"{scn.source}: {exc}") from None


def _check_consistency(scn: Scenario) -> None:
    periods = {n: scn.values[n]["control_period"] for n in ALL_NODES}
    if len(set(periods.values())) > 1:
        listing = ", ".join(f"{n}={p}" for n, p in periods.items())
        raise ScenarioError(f"{scn.source}: control_period differs between nodes ({listing}); set it under /**")
    for node, values in DERIVED.items():  # a value a node must share with another is set there, or set the same
        for name, (src, src_name) in values.items():
            mine, theirs = effective_values(scn, node)[name], scn.values[src][src_name]
            if name in SHARED_VALUES and mine != theirs:
                raise ScenarioError(f"{scn.source}: {node}.{name} {mine} differs from {src}.{src_name} {theirs}; "
                                    f"set it under {src} (the {node} follows)")
    _check_one_orbit(scn)
    _check_torque_actuator(scn)
    _check_faults(scn)
    if scn.has_magnetorquers and scn.values["plant"]["environment.magnetic_field.model"] == "none":
        c = scn.values["controller"]
        why = f"controller.momentum.mode {c['momentum.mode']}" if c["momentum.mode"] != "none" else \
            "controller.torque_actuator magnetorquers" if c["torque_actuator"] == "magnetorquers" else "bdot"
        raise ScenarioError(f"{scn.source}: {why} drives the magnetorquers, which need a field: set plant "
                            "environment.magnetic_field.model (dipole or igrf)")
    dt = scn.dt
    k = scn.duration / dt
    if abs(k - round(k)) > 1e-6:
        raise ScenarioError(f"{scn.source}: plant.duration {scn.duration} s is not a whole number of control periods")
    sched = scn.values[SCENARIO_NODE]
    times, kinds = sched["schedule.times"], sched["schedule.controller_types"]
    if len(times) != len(kinds):
        raise ScenarioError(f"{scn.source}: scenario.schedule.times has {len(times)} entries but "
                            f"schedule.controller_types has {len(kinds)}")
    if any(b <= a for a, b in zip(times[:-1], times[1:], strict=True)):
        raise ScenarioError(f"{scn.source}: scenario.schedule.times must increase, got {times}")
    dt_ns = dt * 1e9
    if abs(dt_ns - round(dt_ns)) > 1e-3:
        raise ScenarioError(f"{scn.source}: control_period {dt} s is not a whole number of nanoseconds")
    if scn.has_sensors:
        try:
            SensorSuite(scn.values["sensors"], dt)  # the tracker's period and latency in whole steps, the outages
        except ScenarioError as exc:
            raise ScenarioError(f"{scn.source}: {exc}") from None
        for name in ("star_tracker.rate_hz", "star_tracker.latency_s"):
            mine, theirs = scn.values["estimator"][name], scn.values["sensors"][name]
            if name in scn.explicit.get("estimator", {}) and mine != theirs:
                raise ScenarioError(f"{scn.source}: estimator.{name} = {mine:g} but the sensors' is {theirs:g}: the "
                                    "filter would wait for reports that do not come (leave it unset to follow them)")


def scenario_from_dict(data: Any, source: str = "<dict>", check: bool = True) -> Scenario:
    """Validate a parsed parameter mapping into a :class:`Scenario`.

    ``check=False`` skips the cross-node rules (one node's own view).
    """
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: expected a mapping of node names to ros__parameters")
    known_nodes = set(NODE_PARAMS)
    values = {node: {s.name: copy.deepcopy(s.default) for s in specs}
              for node, specs in NODE_PARAMS.items() if node != GLOBAL_NODE}
    explicit: dict[str, dict[str, Any]] = {}
    sections: dict[str, dict] = {}
    for raw_node, section in data.items():
        node = section_node(str(raw_node))
        if node not in known_nodes:
            raise ScenarioError(f"{source}: unknown section {raw_node!r}{_suggest(node, known_nodes)}")
        if not isinstance(section, dict) or set(section) != {"ros__parameters"}:
            raise ScenarioError(f"{source}: section {raw_node!r} must hold exactly one key, ros__parameters")
        params = section["ros__parameters"]
        if params is None:
            params = {}
        if not isinstance(params, dict):
            raise ScenarioError(f"{source}: {raw_node}.ros__parameters must be a mapping")
        sections.setdefault(node, {}).update(flatten_parameters(params))
    # wildcard first, node sections override it
    order = [GLOBAL_NODE] + [n for n in sections if n != GLOBAL_NODE]
    for node in order:
        if node not in sections:
            continue
        specs = {s.name: s for s in NODE_PARAMS[node]}
        for name, value in sections[node].items():
            if name not in specs:
                raise ScenarioError(f"{source}: unknown key {node}.{name}{_suggest(name, specs)}")
            try:
                v = specs[name].validate(value, node)
            except ValueError as exc:
                raise ScenarioError(f"{source}: {exc}") from None
            targets = [n for n in ALL_NODES if any(s.name == name for s in NODE_PARAMS[n])] \
                if node == GLOBAL_NODE else [node]
            for target in targets:
                values[target][name] = copy.deepcopy(v)
                explicit.setdefault(target, {})[name] = copy.deepcopy(v)
    scn = Scenario(values=values, explicit=explicit, source=source)
    if check:
        _check_consistency(scn)
    return scn


def flatten_parameters(params: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{'pid': {'kp': [..]}}`` -> ``{'pid.kp': [..]}`` as ROS does for nested YAML."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten_parameters(value, name + "."))
        else:
            out[name] = value
    return out


#: one line for a YAML error (kept under this name for the modules that import it from here)
yaml_problem = yaml12.problem


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file.

    Raises
    ------
    ScenarioError
        Missing file, YAML syntax error, unknown key, wrong type or value.
    """
    data = yaml12.read(path, "scenario file", ScenarioError)
    return scenario_from_dict(data, source=str(Path(path)))


def with_parameter_file(scn: Scenario, path: str | Path) -> Scenario:
    """``scn`` with a ROS 2 parameter file (e.g. a tuner's ``best.yaml``) laid over it, validated.

    Raises
    ------
    ScenarioError
        Missing, empty or malformed file, unknown node or key, wrong value; the message names the file.
    """
    p = Path(path)
    data = yaml12.read(p, "parameter file", ScenarioError)
    if data is None:
        raise ScenarioError(f"{p}: empty parameter file (expected node: ros__parameters: ...)")
    if not isinstance(data, dict):
        raise ScenarioError(f"{p}: a parameter file maps node names to ros__parameters, got a {type(data).__name__}")
    for raw_node, section in data.items():
        node = section_node(str(raw_node))
        if node not in NODE_PARAMS:
            raise ScenarioError(f"{p}: unknown node {raw_node!r}{_suggest(node, NODE_PARAMS)}")
        if not isinstance(section, dict) or set(section) != {"ros__parameters"} \
                or not isinstance(section["ros__parameters"] or {}, dict):
            raise ScenarioError(f"{p}: {raw_node}: expected 'ros__parameters:' with a mapping of values")
        try:
            scn = scn.with_values(node, **flatten_parameters(section["ros__parameters"] or {}))
        except ScenarioError as exc:
            raise ScenarioError(f"{p}: {exc}") from None
    return scn
