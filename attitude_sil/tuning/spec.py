"""Tuning specs: which scenario, controller, genome, cost, algorithm, seed and output.

A spec is a YAML document (one per paper under ``config/``)::

    name: tune_hst_pid_ga
    scenarios: [hst_roll_step.yaml]      # relative to the spec; costs are summed
    conditions: [{}]                      # optional: overrides per condition, costs summed
    controller: pid
    genome:
      - {param: pid.kp, low: 1.0, high: 200.0}           # a gene broadcast to all three axes
      - {param: geometric.k, index: 0, low: 1e-4, high: 0.1, kind: bits, bits: 6}
      - {param: ga_flc.rules, count: 49, low: 1, high: 7, kind: int}
    cost: {name: paper000_j}
    algorithm: {name: ga, pop_size: 50, generations: 40}
    seed: 1
    evaluation: {mode: batch, workers: 2}
    output: results/tune_hst_pid_ga

Genes: ``kind`` is ``real`` (default), ``int`` or ``bits`` (a binary-coded real
with ``bits`` bits over [low, high], paper 001). A gene sets a whole parameter
(broadcast to every axis), one element (``index``), or ``count`` consecutive
elements from ``index``. A condition is a mapping ``node.param: value`` applied to
every scenario, e.g. ``{plant.initial_attitude_rpy_deg: [0, 30, 0]}``.
Every mistake is a :class:`SpecError` with one line naming the file and key.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from attitude_sil.core import yaml12
from attitude_sil.core.control import registry
from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.sim.params import NODE_PARAMS
from attitude_sil.core.sim.scenario import Scenario, load_scenario
from attitude_sil.errors import ScenarioError, SpecError

from .dispersions import check_dispersions

__all__ = ["SpecError", "SECTIONS", "Gene", "TuningSpec", "load_spec", "apply_overrides", "decode", "ALGORITHMS",
           "COSTS", "output_path", "untunable", "is_scalar"]

ALGORITHMS = ("ga", "binary_ga", "pso", "mixed_ga", "nsga2", "root_locus")
COSTS = ("paper000_j", "paper001_fitness", "mse", "paper004_objective", "ts_ce", "momentum")
_TOP = {"name", "description", "scenarios", "conditions", "controller", "genome", "cost", "algorithm", "seed",
        "evaluation", "output", "record", "robust"}


def _real(low: float | None = None, high: float | None = None, low_open: bool = False):
    def check(v: Any) -> str:
        rule = "a finite number" + (f" {'>' if low_open else '>='} {low:g}" if low is not None else "") + (
            f" and <= {high:g}" if high is not None else "")
        ok = (not isinstance(v, bool) and isinstance(v, (int, float)) and np.isfinite(v)
              and (low is None or v > low or (not low_open and v == low)) and (high is None or v <= high))
        return "" if ok else f"must be {rule}, got {v!r}"
    return check


def _integer(low: int, high: int):
    def check(v: Any) -> str:
        ok = not isinstance(v, bool) and isinstance(v, int) and low <= v <= high
        return "" if ok else f"must be an integer in {low}..{high}, got {v!r}"
    return check


def _choice(options: tuple[str, ...]):
    def check(v: Any) -> str:
        return "" if isinstance(v, str) and v in options else f"must be one of {', '.join(options)}, got {v!r}"
    return check


def _boolean(v: Any) -> str:
    return "" if isinstance(v, bool) else f"must be true or false, got {v!r}"


#: what each section of a spec may hold, and the rule of each value (unknown keys are refused)
SECTIONS: dict[str, dict[str, Any]] = {
    "cost": {"name": _choice(COSTS), "beta": _real(0.0), "limit": _real(0.0, low_open=True),
             "w_ts": _real(0.0), "w_itae": _real(0.0),
             "w1": _real(0.0), "w2": _real(0.0), "w3": _real(0.0), "k1": _real(0.0), "k2": _real(0.0),
             "K": _real(0.0), "theta_max_deg": _real(0.0, 180.0, low_open=True), "w_dipole": _real(0.0)},
    "algorithm": {"name": _choice(ALGORITHMS), "pop_size": _integer(2, 100_000), "generations": _integer(1, 10**9),
                  "crossover": _real(0.0, 1.0), "mutation": _real(0.0, 1.0), "eta_c": _real(0.0, low_open=True),
                  "eta_m": _real(0.0, low_open=True), "w": _real(0.0), "c1": _real(0.0), "c2": _real(0.0),
                  "restarts": _integer(1, 1000), "maxiter": _integer(1, 10**7),
                  "settling_time_max": _real(0.0, low_open=True), "n": _real(0.0, low_open=True),
                  "ti": _real(0.0, low_open=True)},
    "evaluation": {"mode": _choice(("batch", "graph")), "workers": _integer(1, 256), "replicas": _integer(1, 64)},
    "record": {"best_per_generation": _boolean},
}
_SEED = _integer(0, 2**32 - 1)  # numpy and pymoo seeds


def _section(where: str, section: str, raw: Any) -> dict[str, Any]:
    """A section checked against :data:`SECTIONS`; ``where`` starts the message (the file, or ``--set k=v``)."""
    if raw is None and section in ("evaluation", "record"):
        raw = {}
    if isinstance(raw, str) and section in ("cost", "algorithm"):
        raw = {"name": raw}  # cost: paper000_j
    if not isinstance(raw, dict):
        raise SpecError(f"{where}: {section} must be a mapping, got {type(raw).__name__} {raw!r}")
    rules = SECTIONS[section]
    for key, value in raw.items():
        if key not in rules:
            close = difflib.get_close_matches(str(key), list(rules), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise SpecError(f"{where}: unknown key {section}.{key}{hint}; known: {', '.join(rules)}")
        broken = rules[key](value)
        if broken:
            raise SpecError(f"{where}: {section}.{key} {broken}")
    if section in ("cost", "algorithm") and "name" not in raw:
        raise SpecError(f"{where}: {section}.name is missing")
    return dict(raw)


def _check_combination(where: str, genome: list, cost: dict, algorithm: dict) -> None:
    if algorithm["name"] == "binary_ga" and any(g.kind != "bits" for g in genome):
        raise SpecError(f"{where}: binary_ga needs every gene of kind bits")
    if algorithm["name"] == "nsga2" and cost["name"] != "ts_ce":
        raise SpecError(f"{where}: nsga2 needs the two-objective cost ts_ce")


def output_path(where: str, value: Any) -> Path:
    """A spec's ``output`` folder (tuning and Monte Carlo alike), refused in one line where it cannot be one."""
    if not isinstance(value, str) or not value.strip():
        raise SpecError(f"{where}: output must be a folder name, got {value!r}")
    out = Path(value)
    existing = next((p for p in (out, *out.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise SpecError(f"{where}: output {out}: {existing} is a file, not a folder")
    return out


@dataclass(frozen=True)
class Gene:
    """One searched variable (or ``count`` of them) mapped onto a controller parameter."""

    param: str
    low: float
    high: float
    kind: str = "real"
    index: int | None = None
    count: int = 1
    bits: int = 6

    @property
    def width(self) -> int:
        """Number of optimiser variables this gene contributes."""
        return self.count * (self.bits if self.kind == "bits" else 1)

    def labels(self) -> list[str]:
        if self.index is None and self.count == 1:
            return [self.param]
        start = self.index or 0
        return [f"{self.param}[{start + i}]" for i in range(self.count)]


@dataclass
class TuningSpec:
    """A validated tuning spec; see the module docstring."""

    path: Path
    name: str
    scenarios: list[Scenario]
    conditions: list[dict[str, Any]]
    controller: str
    genome: list[Gene]
    cost: dict[str, Any]
    algorithm: dict[str, Any]
    seed: int
    evaluation: dict[str, Any]
    output: Path
    record: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    #: robust-design cost: {runs, statistic, seed, dispersions}, or empty
    robust: dict[str, Any] = field(default_factory=dict)

    @property
    def n_var(self) -> int:
        return sum(g.width for g in self.genome)

    def labels(self) -> list[str]:
        return [label for g in self.genome for label in g.labels()]


def _fail(path: Path, msg: str) -> SpecError:
    return SpecError(f"{path}: {msg}")


def _controller_spec(name: str):
    for s in NODE_PARAMS["controller"]:
        if s.name == name:
            return s
    return None


def untunable(spec: ParamSpec) -> str:
    """Why controller parameter ``spec`` cannot be a gene, in a few words; empty if it can.

    A gene is a number the optimiser moves between ``low`` and ``high``, set
    on the controller before each episode (in graph mode through its
    parameter service, as the final best re-run through the graph is): so
    the parameter must be a number or a list of numbers, and settable while
    the controller runs.
    """
    if spec.kind == "bool":
        return "it is a switch (true or false), not a number"
    if spec.kind in ("string", "string_array"):
        listed = f" ({', '.join(spec.choices)})" if spec.choices else ""
        return f"it is a choice of names{listed}, not a number"
    if not spec.runtime:
        return ("it is fixed once the controller runs (not runtime), and the tuner sets genes on a running "
                "controller (graph mode, the best's re-run through the graph)")
    return ""


def _gene(path: Path, i: int, raw: Any, controller: str) -> Gene:
    where = f"genome[{i}]"
    if not isinstance(raw, dict):
        raise _fail(path, f"{where} must be a mapping with param, low, high")
    unknown = set(raw) - {"param", "low", "high", "kind", "index", "count", "bits"}
    if unknown:
        raise _fail(path, f"{where} has unknown key {sorted(unknown)[0]!r}")
    for key in ("param", "low", "high"):
        if key not in raw:
            raise _fail(path, f"{where} needs {key}")
    param = str(raw["param"])
    kind = raw.get("kind", "real")
    if kind not in ("real", "int", "bits"):
        raise _fail(path, f"{where}.kind must be real, int or bits, got {kind!r}")
    for key, low_limit, high_limit in (("count", 1, 1_000_000), ("bits", 1, 30), ("index", 0, 1_000_000)):
        value = raw.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                  or not low_limit <= value <= high_limit):
            raise _fail(path, f"{where}.{key} must be an integer in {low_limit}..{high_limit}, got {value!r}")
    if param == "final_time":  # paper 004: the final time t_f is searched too
        low, high = raw["low"], raw["high"]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in (low, high)) \
                or not 0 < low < high:
            raise _fail(path, f"{where}: final_time needs finite numbers 0 < low < high, got {low!r} and {high!r}")
        if kind != "real" or raw.get("count", 1) != 1 or raw.get("index") is not None:
            raise _fail(path, f"{where}: final_time is one real gene (no kind, count or index)")
        return Gene(param, float(low), float(high))
    spec = _controller_spec(param)
    if spec is None:
        names = [s.name for s in NODE_PARAMS["controller"]]
        close = difflib.get_close_matches(param, names, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise _fail(path, f"{where}.param {param!r} is not a controller parameter{hint}")
    why = untunable(spec)
    if why:
        raise _fail(path, f"{where}.param {param!r} cannot be a gene: {why}")
    scalar = not spec.kind.endswith("array")
    if spec.kind.startswith("integer") and kind != "int":
        raise _fail(path, f"{where}.param {param!r} is an integer parameter: its gene needs kind int, got {kind}")
    if scalar and (raw.get("index") is not None or raw.get("count", 1) != 1):
        raise _fail(path, f"{where}.param {param!r} is one number, not a list: a gene on it takes no index or count")
    low, high = raw["low"], raw["high"]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (low, high)):
        raise _fail(path, f"{where}: low and high must be numbers, got {low!r} and {high!r}")
    low, high = float(low), float(high)
    if not (np.isfinite(low) and np.isfinite(high)):
        raise _fail(path, f"{where}: low and high must be finite, got {low} and {high}")
    if not low < high:
        raise _fail(path, f"{where}: low {low} must be below high {high}")
    index = raw.get("index")
    count = raw.get("count", 1)
    bits = raw.get("bits", 6)
    length = spec.lengths[0] if spec.lengths else None
    if length is not None and (index or 0) + count > length:
        raise _fail(path, f"{where}: elements {index or 0}..{(index or 0) + count - 1} exceed {param}'s {length}")
    if count > 1 and index is None:
        index = 0
    # the search range must lie inside what the parameter itself accepts, so every candidate
    # (and the best.yaml written from it) is a design the controller node takes
    if spec.min is not None and (low < spec.min or (spec.min_exclusive and low <= spec.min)):
        rel = ">" if spec.min_exclusive else ">="
        raise _fail(path, f"{where}: low {low} is outside {param}'s range ({rel} {spec.min:g})")
    if spec.max is not None and high > spec.max:
        raise _fail(path, f"{where}: high {high} is outside {param}'s range (<= {spec.max:g})")
    return Gene(param, low, high, kind, index, count, bits)


def load_spec(path: str | Path) -> TuningSpec:
    """Read and validate a tuning spec.

    Raises
    ------
    SpecError
        Missing file, bad YAML, unknown key, bad gene, unknown algorithm or cost.
    """
    p = Path(path)
    data = yaml12.read(p, "tuning spec", SpecError)
    if not isinstance(data, dict):
        raise _fail(p, "expected a mapping of name, scenarios, controller, genome, cost, algorithm, ...")
    unknown = set(data) - _TOP
    if unknown:
        key = str(sorted(map(str, unknown))[0])
        close = difflib.get_close_matches(key, _TOP, n=1)
        raise _fail(p, f"unknown key {key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    for key in ("scenarios", "controller", "genome", "cost", "algorithm"):
        if key not in data:
            raise _fail(p, f"missing key {key!r}")
    scen_files = data["scenarios"] if isinstance(data["scenarios"], list) else [data["scenarios"]]
    if not scen_files or not all(isinstance(f, str) and f for f in scen_files):
        raise _fail(p, f"scenarios must be a file name or a non-empty list of them, got {data['scenarios']!r}")
    scenarios = []
    for f in scen_files:
        sp = (p.parent / f).resolve() if not Path(f).is_absolute() else Path(f)
        try:
            scenarios.append(load_scenario(sp))
        except ScenarioError as exc:
            raise _fail(p, f"scenarios: {exc}") from None
    controller = data["controller"]
    if controller not in registry.names():
        raise _fail(p, f"controller must be one of {', '.join(registry.names())}, got {controller!r}")
    if not isinstance(data["genome"], list) or not data["genome"]:
        raise _fail(p, "genome must be a non-empty list")
    genome = [_gene(p, i, g, controller) for i, g in enumerate(data["genome"])]
    cost = _section(str(p), "cost", data["cost"])
    algorithm = _section(str(p), "algorithm", data["algorithm"])
    _check_combination(str(p), genome, cost, algorithm)
    if cost["name"] == "momentum" and not all(s.has_magnetorquers for s in scenarios):
        raise _fail(p, "cost momentum judges the wheel momentum the magnetorquers dump: every scenario must fly "
                    "them (controller momentum.mode cross_product)")
    conditions = data.get("conditions") or [{}]
    if not isinstance(conditions, list) or not all(isinstance(c, dict) for c in conditions):
        raise _fail(p, "conditions must be a list of mappings node.param: value")
    for c in conditions:
        for key, value in c.items():
            node, _, name = str(key).partition(".")
            if node not in NODE_PARAMS or not name:
                raise _fail(p, f"condition {key}: expected node.param with a node of {', '.join(NODE_PARAMS)}")
            try:
                scenarios[0].with_values(node, **{name: value})
            except ScenarioError as exc:
                raise _fail(p, f"condition {key}: {exc}") from None
    evaluation = _section(str(p), "evaluation", data.get("evaluation"))
    evaluation.setdefault("mode", "batch")
    record = _section(str(p), "record", data.get("record"))
    seed = data.get("seed", 1)
    if _SEED(seed):
        raise _fail(p, f"seed {_SEED(seed)}")
    name = data.get("name") or p.stem
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise _fail(p, f"name and description must be strings, got {name!r} and {description!r}")
    out = output_path(str(p), data.get("output") or f"results/{name}")
    robust = _robust(p, data.get("robust"), scenarios)
    if robust and evaluation["mode"] != "batch":
        raise _fail(p, "robust needs evaluation.mode batch")
    return TuningSpec(path=p, name=name, scenarios=scenarios, conditions=conditions, controller=controller,
                      genome=genome, cost=cost, algorithm=algorithm, seed=seed, evaluation=evaluation, output=out,
                      record=record, description=description, robust=robust)


def _robust(p: Path, raw: Any, scenarios: list[Scenario]) -> dict[str, Any]:
    """The ``robust`` section: ``{runs: 8, statistic: mean|max, seed: 1, dispersions: {...}}``."""
    if raw is None:
        return {}
    if not isinstance(raw, dict) or set(raw) - {"runs", "statistic", "seed", "dispersions"}:
        raise _fail(p, f"robust must be a mapping of runs, statistic, seed, dispersions, got {raw!r}")
    runs = raw.get("runs", 8)
    if isinstance(runs, bool) or not isinstance(runs, int) or not 1 <= runs <= 1000:
        raise _fail(p, f"robust.runs must be an integer in 1..1000, got {runs!r}")
    statistic = raw.get("statistic", "mean")
    if statistic not in ("mean", "max"):
        raise _fail(p, f"robust.statistic must be mean or max, got {statistic!r}")
    seed = raw.get("seed", 1)
    if _SEED(seed):
        raise _fail(p, f"robust.seed {_SEED(seed)}")
    dispersions = {}
    for scn in scenarios:
        dispersions = check_dispersions(f"{p}: robust", raw.get("dispersions"), scn)
        if "faults" in dispersions:
            raise _fail(p, "robust.dispersions.faults: fault dispersions are for Monte Carlo campaigns (a "
                           "tuning's robust runs share one scenario per candidate)")
    return {"runs": runs, "statistic": statistic, "seed": seed, "dispersions": dispersions}


def is_scalar(param: str) -> bool:
    """Whether gene parameter ``param`` is one number (``geometric.torque_limit``), not a list (``pid.kp``):
    its decoded values are then one per candidate, ``(P,)``."""
    spec = _controller_spec(param)
    return spec is not None and not spec.kind.endswith("array")


def decode(spec: TuningSpec, x: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Optimiser variables (P, n_var) -> per-episode controller parameters and gene values.

    Returns
    -------
    params : dict ``param -> (P, length)`` arrays starting from the scenario's values, ``(P,)`` for a
        scalar parameter (:func:`is_scalar`) and for ``final_time`` ``(P, 1)``
    values : (P, n_genes_flat) decoded gene values (reals, ints, binary decoded), for the results table
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    n = x.shape[0]
    base = spec.scenarios[0].values["controller"]
    params: dict[str, np.ndarray] = {}
    values = []
    col = 0
    for g in spec.genome:
        if g.kind == "bits":
            raw = np.round(x[:, col:col + g.width]).astype(np.int64).reshape(n, g.count, g.bits)
            ints = raw @ (1 << np.arange(g.bits - 1, -1, -1))
            vals = g.low + ints * (g.high - g.low) / ((1 << g.bits) - 1)
        elif g.kind == "int":
            vals = np.clip(np.round(x[:, col:col + g.count]), g.low, g.high)
        else:
            vals = np.clip(x[:, col:col + g.count], g.low, g.high)
        col += g.width
        values.append(vals)
        if is_scalar(g.param):
            params[g.param] = vals[:, 0].copy()
            continue
        if g.param not in params:
            start = base.get(g.param, [0.0])
            params[g.param] = np.tile(np.asarray(start, dtype=float), (n, 1))
        arr = params[g.param]
        if g.index is None:
            arr[:] = vals[:, :1]
        else:
            arr[:, g.index:g.index + g.count] = vals
    return params, np.concatenate(values, axis=1)


def apply_overrides(spec: TuningSpec, overrides: dict[str, Any]) -> TuningSpec:
    """``--set section.key=value`` on a loaded spec (seed, output, algorithm.*, cost.*, evaluation.*, record.*).

    Raises
    ------
    SpecError
        A key outside those sections.
    """
    for key, value in overrides.items():
        section, _, name = key.partition(".")
        where = f"--set {key}={value}" if not isinstance(value, str) else f"--set {key}={value!r}"
        if section == "seed" and not name:
            if _SEED(value):
                raise SpecError(f"{where}: seed {_SEED(value)}")
            spec.seed = value
        elif section == "output" and not name:
            number = value is not None and isinstance(value, (int, float))
            spec.output = output_path(where, str(value) if number else value)
        elif section in SECTIONS and name:
            setattr(spec, section, _section(where, section, {**getattr(spec, section), name: value}))
        else:
            raise SpecError(f"--set {key}: only seed, output, algorithm.*, cost.*, evaluation.*, record.* can be set")
    _check_combination("--set", spec.genome, spec.cost, spec.algorithm)
    return spec
