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
import yaml

from attitude_sil.core import yaml12
from attitude_sil.core.params import NODE_PARAMS
from attitude_sil.core.scenario import Scenario, load_scenario
from attitude_sil.errors import ScenarioError, SpecError

__all__ = ["SpecError", "Gene", "TuningSpec", "load_spec", "apply_overrides", "decode", "ALGORITHMS", "COSTS"]

ALGORITHMS = ("ga", "binary_ga", "pso", "mixed_ga", "nsga2", "root_locus")
COSTS = ("paper000_j", "paper001_fitness", "mse", "paper004_objective", "ts_ce")
_TOP = {"name", "description", "scenarios", "conditions", "controller", "genome", "cost", "algorithm", "seed",
        "evaluation", "output", "record"}


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
    if param == "final_time":  # paper 004: the final time t_f is searched too
        try:
            low, high = float(raw["low"]), float(raw["high"])
        except (TypeError, ValueError):
            raise _fail(path, f"{where}: low and high must be numbers") from None
        if not 0 < low < high:
            raise _fail(path, f"{where}: need 0 < low < high for final_time")
        return Gene(param, low, high, str(raw.get("kind", "real")))
    spec = _controller_spec(param)
    if spec is None:
        names = [s.name for s in NODE_PARAMS["controller"]]
        close = difflib.get_close_matches(param, names, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise _fail(path, f"{where}.param {param!r} is not a controller parameter{hint}")
    if not spec.kind.endswith("array"):
        raise _fail(path, f"{where}.param {param!r} is not an array parameter")
    try:
        low, high = float(raw["low"]), float(raw["high"])
    except (TypeError, ValueError):
        raise _fail(path, f"{where}: low and high must be numbers") from None
    if not (np.isfinite(low) and np.isfinite(high)):
        raise _fail(path, f"{where}: low and high must be finite, got {low} and {high}")
    if not low < high:
        raise _fail(path, f"{where}: low {low} must be below high {high}")
    kind = str(raw.get("kind", "real"))
    if kind not in ("real", "int", "bits"):
        raise _fail(path, f"{where}.kind must be real, int or bits, got {kind!r}")
    index = raw.get("index")
    count = int(raw.get("count", 1))
    bits = int(raw.get("bits", 6))
    if count < 1 or bits < 1 or bits > 30:
        raise _fail(path, f"{where}: count >= 1 and 1 <= bits <= 30")
    if index is not None and (not isinstance(index, int) or index < 0):
        raise _fail(path, f"{where}.index must be a non-negative integer")
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
    if not p.is_file():
        raise SpecError(f"{p}: no such tuning spec")
    try:
        data = yaml12.load(p.read_text())
    except yaml.YAMLError:
        raise SpecError(f"{p}: not valid YAML") from None
    if not isinstance(data, dict):
        raise _fail(p, "expected a mapping")
    unknown = set(data) - _TOP
    if unknown:
        key = sorted(unknown)[0]
        close = difflib.get_close_matches(key, _TOP, n=1)
        raise _fail(p, f"unknown key {key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    for key in ("scenarios", "controller", "genome", "cost", "algorithm"):
        if key not in data:
            raise _fail(p, f"missing key {key!r}")
    scen_files = data["scenarios"] if isinstance(data["scenarios"], list) else [data["scenarios"]]
    scenarios = []
    for f in scen_files:
        sp = (p.parent / str(f)).resolve() if not Path(str(f)).is_absolute() else Path(str(f))
        try:
            scenarios.append(load_scenario(sp))
        except ScenarioError as exc:
            raise SpecError(str(exc)) from None
    controller = str(data["controller"])
    if controller not in ("pid", "fuzzy_pid", "ga_flc", "geometric"):
        raise _fail(p, f"controller must be pid, fuzzy_pid, ga_flc or geometric, got {controller!r}")
    if not isinstance(data["genome"], list) or not data["genome"]:
        raise _fail(p, "genome must be a non-empty list")
    genome = [_gene(p, i, g, controller) for i, g in enumerate(data["genome"])]
    cost = dict(data["cost"]) if isinstance(data["cost"], dict) else {"name": data["cost"]}
    if cost.get("name") not in COSTS:
        raise _fail(p, f"cost.name must be one of {', '.join(COSTS)}, got {cost.get('name')!r}")
    algorithm = dict(data["algorithm"]) if isinstance(data["algorithm"], dict) else {"name": data["algorithm"]}
    if algorithm.get("name") not in ALGORITHMS:
        raise _fail(p, f"algorithm.name must be one of {', '.join(ALGORITHMS)}, got {algorithm.get('name')!r}")
    if algorithm["name"] == "binary_ga" and any(g.kind != "bits" for g in genome):
        raise _fail(p, "binary_ga needs every gene of kind bits")
    if algorithm["name"] == "nsga2" and cost["name"] != "ts_ce":
        raise _fail(p, "nsga2 needs the two-objective cost ts_ce")
    conditions = data.get("conditions") or [{}]
    if not isinstance(conditions, list) or not all(isinstance(c, dict) for c in conditions):
        raise _fail(p, "conditions must be a list of mappings node.param: value")
    for c in conditions:
        for key, value in c.items():
            node, _, name = str(key).partition(".")
            try:
                scenarios[0].with_values(node, **{name: value})
            except (ScenarioError, KeyError) as exc:
                raise _fail(p, f"condition {key}: {exc}") from None
    evaluation = dict(data.get("evaluation") or {})
    evaluation.setdefault("mode", "batch")
    if evaluation["mode"] not in ("batch", "graph"):
        raise _fail(p, f"evaluation.mode must be batch or graph, got {evaluation['mode']!r}")
    seed = data.get("seed", 1)
    if not isinstance(seed, int) or seed < 0:
        raise _fail(p, f"seed must be a non-negative integer, got {seed!r}")
    name = str(data.get("name") or p.stem)
    out = Path(str(data.get("output") or f"results/{name}"))
    return TuningSpec(path=p, name=name, scenarios=scenarios, conditions=conditions, controller=controller,
                      genome=genome, cost=cost, algorithm=algorithm, seed=seed, evaluation=evaluation, output=out,
                      record=dict(data.get("record") or {}), description=str(data.get("description", "")))


def decode(spec: TuningSpec, x: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Optimiser variables (P, n_var) -> per-episode controller parameters and gene values.

    Returns
    -------
    params : dict ``param -> (P, length)`` arrays starting from the scenario's values
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
        if section == "seed" and not name:
            spec.seed = int(value)
        elif section == "output" and not name:
            spec.output = Path(str(value))
        elif section in ("algorithm", "cost", "evaluation", "record") and name:
            getattr(spec, section)[name] = value
        else:
            raise SpecError(f"--set {key}: only seed, output, algorithm.*, cost.*, evaluation.*, record.* can be set")
    for key, least in (("generations", 1), ("pop_size", 2)):
        value = spec.algorithm.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < least):
            raise SpecError(f"algorithm.{key} must be an integer >= {least}, got {value!r}")
    for key, least in (("workers", 1), ("replicas", 1)):
        value = spec.evaluation.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < least):
            raise SpecError(f"evaluation.{key} must be an integer >= {least}, got {value!r}")
    return spec
