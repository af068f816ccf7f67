"""Monte Carlo campaigns: one scenario and one controller design over dispersed runs.

A campaign spec is a YAML document (``config/mc_*.yaml``)::

    name: mc_hst_roll_step
    scenario: hst_roll_step.yaml          # relative to the spec
    params: null                          # optional parameter file laid over it (e.g. a tuner's best.yaml)
    controller: pid                       # optional controller_type (default: the scenario's)
    set: {disturbance.models: [noise]}    # optional scenario values, node.param: value
    runs: 1000
    seed: 42
    chunk: 100                            # runs per chunk shipped to a worker
    dispersions: {...}                    # see attitude_sil.tuning.dispersions
    requirements:                         # pass rates in summary.json
      settling_time_s: {max: 20}
      overshoot_pct: {max: 5}
    worst: {metric: settling_time_s, count: 3}   # bags of the worst runs, re-run through the graph
    plot: {runs: 100, stride: 10}         # the dispersed responses drawn: first runs, every n-th step
    output: results/mc_hst_roll_step

Runs are cut into chunks of ``chunk`` runs; each chunk is one call of
:func:`run_chunk` on an :class:`~attitude_sil.tuning.executor.Executor` (this
process, local worker processes or a Dask cluster). A run's dispersions and
noise seeds depend only on the spec's seed and the run's index, so the results
are the same bit for bit whichever back-end ran which chunk. Every finished
chunk is appended to ``chunks.jsonl`` in the output folder: an interrupted
campaign keeps what finished and ``resume`` runs only the rest.
"""

from __future__ import annotations

import csv
import difflib
import hashlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from attitude_sil.core import yaml12
from attitude_sil.core.analysis.pointing import POINTING_COLUMNS
from attitude_sil.core.control import registry
from attitude_sil.core.faults import wheel_failure_values
from attitude_sil.core.plant.fdir import fdir_report
from attitude_sil.core.sim.build import check_episode
from attitude_sil.core.sim.engine import simulate_summary
from attitude_sil.core.sim.params import NODE_PARAMS
from attitude_sil.core.sim.scenario import Scenario, load_scenario, with_parameter_file
from attitude_sil.core.trajectory import EpisodeSummary
from attitude_sil.errors import ScenarioError, SpecError

from .dispersions import FAULTS_KEY, check_dispersions, episode_values, run_scenario, value_columns
from .executor import Executor
from .spec import output_path

__all__ = ["MonteCarloSpec", "load_mc_spec", "run_chunk", "run_campaign", "CampaignResult", "METRIC_KEYS",
           "worst_runs", "summarize_campaign"]

_TOP = {"name", "description", "scenario", "params", "controller", "set", "runs", "seed", "chunk", "dispersions",
        "requirements", "worst", "plot", "output"}
#: per-run columns besides the scenario's metrics
EXTRA_KEYS = ("finite", "peak_command", "peak_wheel_speed_rad_s")
#: metrics a requirement may name
METRIC_KEYS = ("time_constant_s", "rise_time_s", "settling_time_s", "overshoot_pct", "steady_state_error_rad",
               "control_effort_Nms", "cost_J", "iae", "ise", "itae", "mse", "max_abs_error_rad", "fitness_f",
               "final_error_rad", "peak_command", "peak_wheel_speed_rad_s", *POINTING_COLUMNS)
MAX_RUNS = 10_000_000


@dataclass
class MonteCarloSpec:
    """A validated campaign spec; see the module docstring."""

    path: Path
    name: str
    scenario: Scenario
    controller: str | None
    runs: int
    seed: int
    chunk: int
    dispersions: dict
    requirements: dict[str, dict[str, float]]
    worst: dict[str, Any]
    plot: dict[str, int]
    output: Path
    description: str = ""
    text_hash: str = ""
    extra: dict = field(default_factory=dict)

    def chunks(self) -> list[tuple[int, int]]:
        """``[(lo, hi), ...]``: the runs of each chunk."""
        return [(lo, min(lo + self.chunk, self.runs)) for lo in range(0, self.runs, self.chunk)]


def _fail(p: Path, msg: str) -> SpecError:
    return SpecError(f"{p}: {msg}")


def _int(p: Path, key: str, value: Any, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise _fail(p, f"{key} must be an integer in {low}..{high}, got {value!r}")
    return value


def load_mc_spec(path: str | Path, runs: int | None = None, overrides: dict | None = None) -> MonteCarloSpec:
    """Read and validate a Monte Carlo spec; ``runs`` overrides its ``runs``.

    ``overrides`` (``--set KEY=VALUE``, ``--output``) replace spec entries
    before the spec is checked: ``KEY`` is a top-level key (``output``,
    ``seed``, ``controller``, ...), a dotted path into one
    (``requirements.settling_time_s.max``, ``dispersions.inertia_pct.scale``),
    or ``set.`` and a scenario key (``set.disturbance.noise.power``). They
    count in the spec's identity, which ``--resume`` checks.

    Raises
    ------
    SpecError
        Missing file, bad YAML, unknown key, bad dispersion or requirement; one line naming the file and key.
    """
    p = Path(path)
    data = yaml12.read(p, "Monte Carlo spec", SpecError)
    text = p.read_bytes() + json.dumps(sorted((overrides or {}).items()), default=str).encode()
    if not isinstance(data, dict):
        raise _fail(p, "expected a mapping of name, scenario, runs, seed, dispersions, requirements, ...")
    for key, value in (overrides or {}).items():
        _override(data, key, value)
    unknown = set(map(str, data)) - _TOP
    if unknown:
        key = sorted(unknown)[0]
        close = difflib.get_close_matches(key, _TOP, n=1)
        raise _fail(p, f"unknown key {key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    scn = _spec_scenario(p, data)
    controller = data.get("controller")
    if controller is not None and controller not in registry.names():
        raise _fail(p, f"controller must be one of {', '.join(registry.names())}, got {controller!r}")
    try:
        check_episode(scn, controller)
    except ScenarioError as exc:
        raise _fail(p, f"scenario: {exc}") from None
    n_runs = _int(p, "runs", data.get("runs", 100), 1, MAX_RUNS)
    if runs is not None:
        if isinstance(runs, bool) or not isinstance(runs, int) or not 1 <= runs <= MAX_RUNS:
            raise SpecError(f"--runs must be an integer in 1..{MAX_RUNS}, got {runs!r}")
        n_runs = runs
    seed = _int(p, "seed", data.get("seed", 1), 0, 2**32 - 1)
    chunk = _int(p, "chunk", data.get("chunk", 100), 1, 100_000)
    dispersions = check_dispersions(str(p), data.get("dispersions"), scn)
    requirements = _requirements(p, data.get("requirements"), scn)
    worst = _worst(p, data.get("worst"), requirements)
    plot = _plot(p, data.get("plot"))
    name = data.get("name") or p.stem
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise _fail(p, f"name and description must be strings, got {name!r} and {description!r}")
    out = output_path(str(p), data.get("output") or f"results/{name}")  # the tuning spec's check, same messages
    return MonteCarloSpec(path=p, name=name, scenario=scn, controller=controller, runs=n_runs, seed=seed, chunk=chunk,
                          dispersions=dispersions, requirements=requirements, worst=worst, plot=plot, output=out,
                          description=description, text_hash=hashlib.sha256(text).hexdigest())


def _spec_scenario(p: Path, data: dict) -> Scenario:
    """The spec's ``scenario`` file, with its ``params`` file laid over it and its ``set`` values."""
    if "scenario" not in data:
        raise _fail(p, "missing key 'scenario'")
    f = data["scenario"]
    if not isinstance(f, str) or not f:
        raise _fail(p, f"scenario must be a file name, got {f!r}")
    try:
        scn = load_scenario(p.parent / f if not Path(f).is_absolute() else Path(f))
        if data.get("params") is not None:
            if not isinstance(data["params"], str):
                raise _fail(p, f"params must be a parameter file name, got {data['params']!r}")
            pf = data["params"]
            scn = with_parameter_file(scn, p.parent / pf if not Path(pf).is_absolute() else Path(pf))
    except ScenarioError as exc:
        raise _fail(p, f"scenario: {exc}") from None
    overrides = data.get("set") or {}
    if not isinstance(overrides, dict):
        raise _fail(p, "set must be a mapping node.param: value")
    for key, value in overrides.items():
        node, _, name = str(key).partition(".")
        if node not in NODE_PARAMS or not name:
            raise _fail(p, f"set {key}: expected node.param with a node of {', '.join(NODE_PARAMS)}")
        try:
            scn = scn.with_values(node, **{name: value})
        except ScenarioError as exc:
            raise _fail(p, f"set {key}: {exc}") from None
    return scn


def _worst(p: Path, raw: Any, requirements: dict[str, dict[str, float]]) -> dict[str, Any]:
    """The spec's ``worst`` section: how many worst runs to record, ranked by which metric."""
    worst = raw or {}
    if not isinstance(worst, dict) or set(worst) - {"metric", "count"}:
        raise _fail(p, f"worst must be a mapping of metric, count, got {worst!r}")
    worst = {"count": _int(p, "worst.count", worst.get("count", 3), 0, 100),
             "metric": worst.get("metric", next(iter(requirements), None))}
    if worst["metric"] is not None and worst["metric"] not in METRIC_KEYS:
        raise _fail(p, f"worst.metric must be one of {', '.join(METRIC_KEYS)}, got {worst['metric']!r}")
    if worst["metric"] is None and worst["count"]:
        raise _fail(p, "worst.metric is needed when there are no requirements")
    return worst


def _plot(p: Path, raw: Any) -> dict[str, int]:
    """The spec's ``plot`` section: how many runs to draw and the step stride."""
    plot = raw or {}
    if not isinstance(plot, dict) or set(plot) - {"runs", "stride"}:
        raise _fail(p, f"plot must be a mapping of runs, stride, got {plot!r}")
    return {"runs": _int(p, "plot.runs", plot.get("runs", 100), 0, 1000),
            "stride": _int(p, "plot.stride", plot.get("stride", 10), 1, 10_000)}


def _requirements(p: Path, raw: Any, scn: Scenario) -> dict[str, dict[str, float]]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise _fail(p, f"requirements must be a mapping metric: {{max: x}} or {{min: x}}, got {raw!r}")
    out = {}
    for metric, rule in raw.items():
        if metric not in METRIC_KEYS:
            close = difflib.get_close_matches(str(metric), METRIC_KEYS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise _fail(p, f"requirements: unknown metric {metric!r}{hint}; known: {', '.join(METRIC_KEYS)}")
        if not isinstance(rule, dict) or not rule or set(rule) - {"min", "max"} or not all(
                not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) for v in rule.values()):
            raise _fail(p, f"requirements.{metric} must be {{max: number}} and/or {{min: number}}, got {rule!r}")
        out[str(metric)] = {k: float(v) for k, v in rule.items()}
    return out


def run_chunk(spec: MonteCarloSpec, lo: int, hi: int, threads: int | None = None) -> dict[str, np.ndarray]:
    """Runs ``lo..hi-1`` of the campaign in the batch engine (what a worker does with one chunk).

    Returns
    -------
    dict of (hi - lo,) arrays
        ``run``, the dispersed values (:func:`~attitude_sil.tuning.dispersions.value_columns`), the
        scenario's metrics and :data:`EXTRA_KEYS`.
    """
    runs = np.arange(lo, hi)
    values = episode_values(spec.scenario, spec.dispersions, spec.seed, runs)
    seeds = spec.scenario.param("disturbance", "noise.seed") + runs
    if FAULTS_KEY in values:  # each run its own faults list: one run at a time, each its own scenario
        s = _summaries([simulate_summary(run_scenario(spec.scenario, values, r), 1, controller=spec.controller,
                                         threads=threads, warn_nonfinite=False,
                                         episode_values={"disturbance.noise.seed": seeds[r:r + 1]})
                        for r in range(hi - lo)])
    else:
        s = simulate_summary(spec.scenario, hi - lo, controller=spec.controller, threads=threads,
                             warn_nonfinite=False, episode_values={"disturbance.noise.seed": seeds, **values})
    out: dict[str, np.ndarray] = {"run": runs}
    out.update(value_columns(values))
    out.update({k: np.asarray(v, dtype=float) for k, v in s.metrics.items()})
    out["finite"] = np.asarray(s.finite, dtype=bool)
    out["peak_command"] = np.asarray(s.peak_command, dtype=float)
    if s.peak_wheel_speed is not None:
        out["peak_wheel_speed_rad_s"] = np.asarray(s.peak_wheel_speed, dtype=float)
    return out


def _summaries(parts: list) -> EpisodeSummary:
    """One :class:`EpisodeSummary` of the runs of ``parts`` (each of one run), in order."""
    peaks = [p.peak_wheel_speed for p in parts]
    return EpisodeSummary(metrics={k: np.concatenate([p.metrics[k] for p in parts]) for k in parts[0].metrics},
                          finite=np.concatenate([p.finite for p in parts]),
                          peak_command=np.concatenate([p.peak_command for p in parts]),
                          peak_wheel_speed=None if peaks[0] is None else np.concatenate(peaks))


@dataclass
class CampaignResult:
    """A campaign's runs (complete or not), its summary and how long it took."""

    table: dict[str, np.ndarray]
    summary: dict
    interrupted: bool
    wall_time_s: float


def _jsonable(a: np.ndarray) -> list:
    if a.dtype.kind in "US":
        return a.tolist()
    if a.dtype.kind == "b":
        return [bool(x) for x in a]
    if a.dtype.kind in "iu":
        return [int(x) for x in a]
    return [float(x) for x in a]  # NaN and inf as JSON's NaN / Infinity (Python reads them back exactly)


def _header(spec: MonteCarloSpec) -> dict:
    return {"spec_sha256": spec.text_hash, "runs": spec.runs, "seed": spec.seed, "chunk": spec.chunk}


def _override(data: dict, key: str, value) -> None:
    """One ``--set KEY=VALUE`` into the spec's mapping (:func:`load_mc_spec`)."""
    top, _, rest = key.partition(".")
    if top not in _TOP:
        close = difflib.get_close_matches(top, _TOP, n=1)
        raise SpecError(f"--set {key}: unknown key {top!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    if not rest:
        data[top] = value
        return
    if top == "set":  # scenario keys hold dots themselves: node.param
        path = ["set", rest]
    else:
        path = [top, *rest.split(".")]
    node = data
    for part in path[:-1]:
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        if not isinstance(child, dict):
            raise SpecError(f"--set {key}: {part!r} is not a mapping in the spec")
        node = child
    node[path[-1]] = value


def check_campaign_output(spec: MonteCarloSpec, resume: bool) -> None:
    """Refuse an output folder the campaign cannot use, before anything runs.

    Raises
    ------
    SpecError
        ``resume`` with nothing to continue or a different spec; a fresh run over an earlier campaign.
    """
    log = spec.output / "chunks.jsonl"
    if resume:
        if not log.is_file():
            raise SpecError(f"output {spec.output}: nothing to resume (no chunks.jsonl); run without --resume")
        first = log.read_text().partition("\n")[0]
        try:
            header = json.loads(first)
        except ValueError:
            raise SpecError(f"{log}: not a campaign log (first line is not JSON)") from None
        if header != _header(spec):
            raise SpecError(f"{log}: written by a different spec, run count, seed or chunk size; run without "
                            "--resume into another output")
    elif log.exists():
        raise SpecError(f"{spec.output}: results of an earlier campaign are there; --resume continues them, "
                        "--output DIR writes elsewhere")


def _load_chunks(log: Path) -> dict[int, dict[str, np.ndarray]]:
    done: dict[int, dict[str, np.ndarray]] = {}
    lines = log.read_text().splitlines()[1:]
    for line in lines:
        try:
            rec = json.loads(line)
        except ValueError:
            break  # a line cut short by a kill: that chunk runs again
        done[int(rec["lo"])] = {k: np.asarray(v) for k, v in rec["columns"].items()}
    return done


def run_campaign(spec: MonteCarloSpec, executor: Executor, *, resume: bool = False,
                 progress: Callable[[int, int, float], None] | None = None,
                 should_stop: Callable[[], bool] | None = None) -> CampaignResult:
    """Run the campaign's chunks on ``executor``; write the table and summary into ``spec.output``.

    Parameters
    ----------
    spec : MonteCarloSpec
    executor : Executor
    resume : bool
        Run only the chunks ``chunks.jsonl`` does not hold yet.
    progress : callable(done_runs, total_runs, wall_s), optional
        Called after every finished chunk.
    should_stop : callable() -> bool, optional
        Polled after every finished chunk (Ctrl-C): what finished is kept.
    """
    check_campaign_output(spec, resume)
    out = spec.output
    out.mkdir(parents=True, exist_ok=True)
    log = out / "chunks.jsonl"
    done = _load_chunks(log) if resume else {}
    if not resume:
        log.write_text(json.dumps(_header(spec)) + "\n")
    todo = [(lo, hi) for lo, hi in spec.chunks() if lo not in done]
    t0 = time.monotonic()
    n_done = n_before = sum(len(c["run"]) for c in done.values())
    if progress is not None:
        progress(n_done, spec.runs, 0.0)
    calls = [(spec, lo, hi, executor.threads) for lo, hi in todo]
    with log.open("a") as fh:
        for i, cols in executor.as_completed(run_chunk, calls, should_stop):
            lo = todo[i][0]
            done[lo] = cols
            fh.write(json.dumps({"lo": lo, "columns": {k: _jsonable(np.asarray(v)) for k, v in cols.items()}}) + "\n")
            fh.flush()
            n_done += len(cols["run"])
            if progress is not None:
                progress(n_done, spec.runs, time.monotonic() - t0)
    wall = time.monotonic() - t0
    interrupted = n_done < spec.runs
    table = {k: np.concatenate([done[lo][k] for lo in sorted(done)]) for k in done[min(done)]} if done else {}
    summary = summarize_campaign(spec, table, interrupted)
    ran = n_done - n_before
    summary.update(wall_time_s=wall, episodes_per_s=(ran / wall if wall > 0 else None), executor=executor.name,
                   workers=executor.workers)
    write_table(out, table)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return CampaignResult(table=table, summary=summary, interrupted=interrupted, wall_time_s=wall)


def _passes(table: dict[str, np.ndarray], metric: str, rule: dict) -> np.ndarray:
    v = table[metric].astype(float)
    ok = np.isfinite(v) & table["finite"].astype(bool)
    if "max" in rule:
        ok &= v <= rule["max"]
    if "min" in rule:
        ok &= v >= rule["min"]
    return ok


def summarize_campaign(spec: MonteCarloSpec, table: dict[str, np.ndarray], interrupted: bool) -> dict:
    """``summary.json``: percentiles (50/90/99) of every metric over its finite values, pass rates, worst runs."""
    n = len(table.get("run", []))
    summary: dict[str, Any] = {"name": spec.name, "spec": str(spec.path), "scenario": spec.scenario.name,
                               "controller": spec.controller or spec.scenario.param("controller", "controller_type"),
                               "runs": spec.runs, "completed_runs": n, "seed": spec.seed,
                               "interrupted": interrupted, "metrics": {}, "requirements": {}}
    if not n:
        return summary
    for key in [k for k in METRIC_KEYS if k in table]:
        v = table[key].astype(float)
        fin = v[np.isfinite(v)]
        stats = {"never": int(n - fin.size)}
        if fin.size:
            p50, p90, p99 = np.percentile(fin, [50, 90, 99])
            stats.update(p50=float(p50), p90=float(p90), p99=float(p99), mean=float(fin.mean()),
                         min=float(fin.min()), max=float(fin.max()))
        summary["metrics"][key] = stats
    all_ok = np.ones(n, dtype=bool)
    for metric, rule in spec.requirements.items():
        if metric not in table:
            summary["requirements"][metric] = {**rule, "pass_rate": None, "note": "not a metric of this scenario"}
            continue
        ok = _passes(table, metric, rule)
        all_ok &= ok
        summary["requirements"][metric] = {**rule, "pass_rate": float(ok.mean()), "failed_runs": int((~ok).sum())}
    summary["pass_rate"] = float(all_ok.mean())
    diverged = ~table["finite"].astype(bool)
    summary["diverged_runs"] = int(diverged.sum())
    if diverged.any():  # the law that flew them: the campaign's (a scheduled swap is in the scenario)
        summary["diverged_under"] = summary["controller"]
        summary["diverged_run_ids"] = [int(r) for r in table["run"][diverged][:20]]
    summary["worst"] = [{"run": int(table["run"][i]), spec.worst["metric"]: float(table[spec.worst["metric"]][i])}
                        for i in worst_runs(spec, table)] if spec.worst["metric"] in table else []
    if "fdir_wheel" in table:  # the wheels' FDIR flew: its detections against the failures the runs flew
        w = {**spec.scenario.values["wheels"], **wheel_failure_values(spec.scenario.values["wheels"])}
        failure = [table.get(f"wheels.failure.{k}", np.full(n, w[f"failure.{k}"])) for k in ("wheel", "time", "mode")]
        summary["fdir"] = fdir_report(*failure, table["fdir_wheel"], table["fdir_time_s"], spec.scenario.duration)
    return summary


def worst_runs(spec: MonteCarloSpec, table: dict[str, np.ndarray]) -> list[int]:
    """Rows of the ``worst.count`` worst runs: most requirements failed, then the worst ``worst.metric``.

    A metric the run never reached (NaN) or a diverged run counts as worst; larger is worse unless the
    metric's requirement is a ``min``.
    """
    metric, count = spec.worst["metric"], spec.worst["count"]
    if not count or metric not in table or not len(table["run"]):
        return []
    fails = np.zeros(len(table["run"]))
    for m, rule in spec.requirements.items():
        if m in table:
            fails += ~_passes(table, m, rule)
    v = table[metric].astype(float)
    sign = -1.0 if "min" in spec.requirements.get(metric, {}) and "max" not in spec.requirements[metric] else 1.0
    badness = np.where(np.isfinite(v) & table["finite"].astype(bool), sign * v, np.inf)
    order = np.lexsort((table["run"], -badness, -fails))  # stable: ties by run index
    return [int(i) for i in order[:count]]


def write_table(out: Path, table: dict[str, np.ndarray]) -> None:
    """``runs.csv`` and ``runs.json``: one row per run (dispersed values and metrics)."""
    keys = list(table)
    rows = [{k: _jsonable(table[k][i:i + 1])[0] for k in keys} for i in range(len(table.get("run", [])))]
    (out / "runs.json").write_text(json.dumps(rows) + "\n")
    with (out / "runs.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})


def run_of(spec: MonteCarloSpec, run: int) -> Scenario:
    """Run ``run``'s scenario: the dispersed values set, the noise seed that run had; for the node graph."""
    values = episode_values(spec.scenario, spec.dispersions, spec.seed, [run])
    scn = run_scenario(spec.scenario, values, 0)
    if "disturbance.noise.seed" not in values:
        scn = scn.with_values("disturbance", **{"noise.seed": spec.scenario.param("disturbance", "noise.seed") + run})
    return scn
