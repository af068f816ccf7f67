"""The tuning loop: pymoo algorithms in ask/tell form, results on disk, resume.

Algorithms (``algorithm.name``), configured from pymoo to match the papers:

* ``ga`` — real-coded GA (SBX crossover, polynomial mutation, tournament of 2),
  paper 000's PID tuning.
* ``binary_ga`` — binary-coded GA: every gene ``bits`` bits (paper 001: 6 bits
  over [0.0001, 0.1]), two-point crossover with ``crossover`` probability,
  bit-flip mutation with per-bit probability ``mutation``, tournament of 2.
* ``pso`` — canonical PSO with fixed inertia ``w`` and ``c1``, ``c2`` (paper 002:
  100 particles, 100 iterations, 0.729, 1.55, 1.55; pymoo's adaptive variant
  and best-perturbation switched off).
* ``mixed_ga`` — mixed-variable GA with paper 004's operators (the Chipperfield
  GA toolbox it names): linear ranking (selective pressure 2) with roulette-wheel
  selection of whole individuals; single-point crossover on the integer genes
  (the 49 rules) and SBX on the real ones, each with probability ``crossover``
  (0.7); per-gene mutation with probability ``mutation`` (0.01): a random
  reset of an integer gene, polynomial mutation of a real one.
* ``nsga2`` — NSGA-II on (Ts, Ce): the trade-off front paper 001 probes with two beta.
* ``root_locus`` — :mod:`attitude_sil.tuning.rootlocus` (no population).

Every evaluated candidate is appended to ``<output>/evaluations.jsonl`` as
soon as its generation is scored, so Ctrl-C loses nothing finished.
``resume=True`` replays the algorithm from its seed, answering the
generations already on disk from that file instead of simulating them: pymoo's
algorithms are deterministic given the seed and the costs, so the resumed run
ends exactly where an uninterrupted one would.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

import numpy as np
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.algorithms.soo.nonconvex.ga import GA
from pymoo.algorithms.soo.nonconvex.pso import PSO
from pymoo.core.mixed import MixedVariableDuplicateElimination, MixedVariableGA, MixedVariableMating
from pymoo.core.mutation import Mutation
from pymoo.core.problem import Problem
from pymoo.core.selection import Selection
from pymoo.core.variable import Integer
from pymoo.core.variable import Real as RealVariable
from pymoo.operators.crossover.pntx import SinglePointCrossover, TwoPointCrossover
from pymoo.operators.crossover.sbx import SBX
from pymoo.operators.mutation.bitflip import BitflipMutation
from pymoo.operators.mutation.pm import PM
from pymoo.operators.repair.rounding import RoundingRepair
from pymoo.operators.sampling.rnd import BinaryRandomSampling

from .evaluate import PENALTY, Evaluation, Evaluator
from .results import TuningResult, write_best_yaml
from .rootlocus import tune_root_locus
from .spec import SpecError, TuningSpec, decode

__all__ = ["TuningResult", "check_output", "run_tuning", "build_algorithm", "write_best_yaml"]


class RankingRoulette(Selection):
    """Linear ranking (selective pressure ``sp``) and roulette-wheel sampling, as the GA toolbox of paper 004."""

    def __init__(self, sp: float = 2.0) -> None:
        super().__init__()
        self.sp = float(sp)

    def _do(self, _, pop, n_select, n_parents, random_state=None, **kwargs):
        f = pop.get("F")[:, 0]
        n = len(pop)
        rank = np.empty(n)
        rank[np.argsort(-f, kind="stable")] = np.arange(n)  # worst 0 ... best n-1
        fitness = 2.0 - self.sp + 2.0 * (self.sp - 1.0) * rank / max(n - 1, 1)
        return random_state.choice(n, size=(n_select, n_parents), p=fitness / fitness.sum())


class IntegerReset(Mutation):
    """Each integer gene reset to a uniform value of its range with probability ``prob_var``."""

    def _do(self, problem, X, random_state=None, **kwargs):
        X = np.array(X, dtype=float)
        prob = np.asarray(self.get_prob_var(problem, size=len(X)), dtype=float).reshape(-1, 1)
        hit = random_state.random(X.shape) < prob
        lo, hi = problem.xl.astype(float), problem.xu.astype(float)
        draws = np.floor(lo + random_state.random(X.shape) * (hi - lo + 1.0))
        X[hit] = draws[hit]
        return X


def build_algorithm(spec: TuningSpec):
    """(pymoo algorithm, pymoo problem, n_generations) for the spec."""
    a = spec.algorithm
    name = a["name"]
    n_obj = 2 if spec.cost["name"] == "ts_ce" else 1
    gens = int(a.get("generations", 40))
    pop = int(a.get("pop_size", 50))
    if name == "mixed_ga":
        variables = {}
        for g in spec.genome:
            for label in g.labels():
                key = f"{len(variables):03d}:{label}"
                variables[key] = (Integer(bounds=(int(g.low), int(g.high))) if g.kind == "int"
                                  else RealVariable(bounds=(g.low, g.high)))

        class Mixed(Problem):
            def __init__(self):
                super().__init__(vars=variables, n_obj=n_obj)

        xo, mut = float(a.get("crossover", 0.7)), float(a.get("mutation", 0.01))
        mating = MixedVariableMating(
            selection=RankingRoulette(), eliminate_duplicates=MixedVariableDuplicateElimination(),
            crossover={RealVariable: SBX(prob=xo), Integer: SinglePointCrossover(prob=xo)},
            mutation={RealVariable: PM(prob=1.0, prob_var=mut),
                      Integer: IntegerReset(prob=1.0, prob_var=mut, repair=RoundingRepair())})
        return MixedVariableGA(pop_size=pop, mating=mating), Mixed(), gens
    if name == "binary_ga":
        class Binary(Problem):
            def __init__(self):
                super().__init__(n_var=spec.n_var, n_obj=n_obj, xl=0, xu=1, vtype=bool)

        algo = GA(pop_size=pop, sampling=BinaryRandomSampling(),
                  crossover=TwoPointCrossover(prob=float(a.get("crossover", 0.7))),
                  mutation=BitflipMutation(prob=1.0, prob_var=float(a.get("mutation", 1e-5))),
                  eliminate_duplicates=True)
        return algo, Binary(), gens

    xl = np.concatenate([[g.low] * g.width for g in spec.genome])
    xu = np.concatenate([[g.high] * g.width for g in spec.genome])

    class Real(Problem):
        def __init__(self):
            super().__init__(n_var=spec.n_var, n_obj=n_obj, xl=xl, xu=xu)

    if name == "pso":
        algo = PSO(pop_size=pop, w=float(a.get("w", 0.729)), c1=float(a.get("c1", 1.55)), c2=float(a.get("c2", 1.55)),
                   adaptive=False, pertube_best=False)
        return algo, Real(), gens
    if name == "nsga2":
        return NSGA2(pop_size=pop), Real(), gens

    algo = GA(pop_size=pop, crossover=SBX(prob=float(a.get("crossover", 0.9)), eta=float(a.get("eta_c", 15))),
              mutation=PM(prob=float(a.get("mutation", 0.9)), eta=float(a.get("eta_m", 20))),
              eliminate_duplicates=True)
    return algo, Real(), gens


def _as_array(spec: TuningSpec, X) -> np.ndarray:
    """pymoo's X (array, or dicts for mixed variables) -> (P, n_var) floats in gene order."""
    if X.dtype == object:
        keys = sorted(X[0])
        return np.array([[float(row[k]) for k in keys] for row in X])
    return np.asarray(X, dtype=float)


def _load_cache(path: Path) -> dict[int, list[dict]]:
    cache: dict[int, list[dict]] = {}
    if not path.is_file():
        return cache
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            break  # a torn last line from a kill: everything before it is whole
        cache.setdefault(row["generation"], []).append(row)
    return cache


def _rows(spec: TuningSpec, gen: int, x: np.ndarray, ev: Evaluation) -> list[dict]:
    labels = spec.labels()
    rows = []
    for i in range(x.shape[0]):
        rows.append({
            "generation": gen,
            "index": i,
            "x": [float(v) for v in x[i]],
            "genome": {label: float(v) for label, v in zip(labels, ev.values[i], strict=True)},
            "cost": [float(v) for v in ev.F[i]],
            "terms": {k: (float(v[i]) if np.isfinite(v[i]) else None) for k, v in ev.terms.items()},
            "failure": ev.reasons[i],
        })
    return rows


def check_output(spec: TuningSpec, resume: bool) -> None:
    """Refuse an output folder the run cannot use, before anything starts.

    Raises
    ------
    SpecError
        ``resume`` finds nothing to continue, or a fresh run would
        mix its bags with an earlier run's.
    """
    out = spec.output
    if resume and spec.algorithm["name"] != "root_locus" and not (out / "evaluations.jsonl").is_file():
        raise SpecError(f"output {out}: nothing to resume (no evaluations.jsonl); run without --resume")
    bags = out / "bags"
    if not resume and bags.is_dir() and any(bags.iterdir()):
        raise SpecError(f"{bags}: results of an earlier run are there; use --resume or another output")


def run_tuning(spec: TuningSpec, *, resume: bool = False, evaluator: Callable[[np.ndarray], Evaluation] | None = None,
               progress: Callable[[dict], None] | None = None, should_stop: Callable[[], bool] | None = None,
               on_generation: Callable[[int, np.ndarray, float], None] | None = None) -> TuningResult:
    """Run the spec's algorithm to its last generation (or until ``should_stop``).

    Parameters
    ----------
    spec : TuningSpec
    resume : bool
        Continue a run whose ``evaluations.jsonl`` is in the output folder.
    evaluator : callable, optional
        Scores a (P, n_var) population; default: the batch engine over
        ``evaluation.workers`` processes.
    progress : callable(dict), optional
        Called after every generation with generation, best, median, evals/s.
    should_stop : callable() -> bool, optional
        Polled between generations (Ctrl-C).
    on_generation : callable(gen, best_x, best_cost), optional
        E.g. to record the generation's best through the graph.

    Raises
    ------
    SpecError
        A resume whose saved candidates do not match what the spec asks now.
    """
    if spec.algorithm["name"] == "root_locus":
        return tune_root_locus(spec, progress=progress)
    log, cache = _open_log(spec, resume)
    algo, problem, gens = build_algorithm(spec)
    algo.setup(problem, termination=("n_gen", gens), seed=spec.seed, verbose=False)
    own = evaluator is None
    ev_ctx = Evaluator(spec, int(spec.evaluation.get("workers", 1))) if own else None
    score = ev_ctx.__enter__() if own else evaluator
    best_x, best_f = None, np.array([math.inf])
    history = []
    n_eval = 0
    interrupted = False
    all_rows: list[dict] = []
    try:
        with open(log, "a") as fh:
            gen = 0
            while algo.has_next():
                if should_stop is not None and should_stop():
                    interrupted = True
                    break
                gen += 1
                pop = algo.ask()
                x = _as_array(spec, pop.get("X"))
                t0 = time.monotonic()
                cached = cache.get(gen)
                F, rows = _score_generation(spec, gen, x, cached, score, fh)
                n_eval += len(rows)
                all_rows.extend(rows)
                pop.set("F", F)
                algo.tell(infills=pop)
                valid = F[:, 0] < PENALTY
                i_best = int(np.argmin(F[:, 0]))
                if F[i_best, 0] < best_f[0]:
                    best_x, best_f = x[i_best].copy(), F[i_best].copy()
                stats = {"generation": gen, "generations": gens, "best": float(best_f[0]),
                         "generation_best": float(F[i_best, 0]),
                         "median": float(np.median(F[valid, 0])) if valid.any() else float("nan"),
                         "failed": int((~valid).sum()), "evaluations": n_eval,
                         "evals_per_s": len(rows) / max(time.monotonic() - t0, 1e-9), "cached": cached is not None}
                history.append(stats)
                if progress is not None:
                    progress(stats)
                if on_generation is not None and cached is None:
                    on_generation(gen, x[i_best], float(F[i_best, 0]))
    finally:
        if own:
            ev_ctx.__exit__(None, None, None)
    return _finish_run(spec, all_rows, history, best_x, best_f, n_eval, interrupted)


def _open_log(spec: TuningSpec, resume: bool) -> tuple[Path, dict[int, list[dict]]]:
    """Create the output folder; the evaluation log (removed unless resuming) and its generations on disk."""
    out = spec.output
    out.mkdir(parents=True, exist_ok=True)
    log = out / "evaluations.jsonl"
    if not resume and log.exists():
        log.unlink()
    cache = _load_cache(log) if resume else {}
    return log, cache


def _score_generation(spec: TuningSpec, gen: int, x: np.ndarray, cached: list[dict] | None,
                      score: Callable[[np.ndarray], Evaluation], fh: TextIO) -> tuple[np.ndarray, list[dict]]:
    """Costs and rows of a generation: from the log when resuming (it must match ``x``), else scored and logged."""
    if cached is not None:
        xc = np.array([r["x"] for r in cached])
        if xc.shape != x.shape or not np.allclose(xc, x, rtol=0, atol=1e-12):
            raise SpecError(f"{spec.path}: cannot resume: generation {gen} on disk differs from what "
                            "the spec and seed ask now")
        return np.array([r["cost"] for r in cached]), cached
    ev = score(x)
    rows = _rows(spec, gen, x, ev)
    fh.write("".join(json.dumps(r) + "\n" for r in rows))
    fh.flush()
    return ev.F, rows


def _finish_run(spec: TuningSpec, all_rows: list[dict], history: list[dict], best_x: np.ndarray | None,
            best_f: np.ndarray, n_eval: int, interrupted: bool) -> TuningResult:
    """Write the run's result files and return its result; SpecError if no generation was evaluated."""
    if best_x is None:
        raise SpecError(f"{spec.path}: no generation was evaluated")
    front = []
    if spec.cost["name"] == "ts_ce":
        front = _pareto([r for r in all_rows if not r["failure"]])
    _write_results(spec, all_rows, history, best_x, best_f, front)
    params, _ = decode(spec, best_x[None])
    return TuningResult(best_x=best_x, best_cost=best_f, best_params={k: v[0] for k, v in params.items()},
                        generations=history, evaluations=n_eval, front=front, interrupted=interrupted)


def _pareto(rows: list[dict]) -> list[dict]:
    """Non-dominated rows of a two-objective run, sorted by the first objective."""
    pts = np.array([r["cost"] for r in rows]) if rows else np.zeros((0, 2))
    keep = []
    for i, p in enumerate(pts):
        dominated = np.any(np.all(pts <= p, axis=1) & np.any(pts < p, axis=1))
        if not dominated:
            keep.append(i)
    front = sorted((rows[i] for i in keep), key=lambda r: r["cost"][0])
    unique, seen = [], set()
    for r in front:
        key = tuple(round(c, 12) for c in r["cost"])
        if key not in seen:
            seen.add(key)
            unique.append(r)
    return unique


def _write_results(spec, rows, history, best_x, best_f, front) -> None:

    out = spec.output
    (out / "evaluations.json").write_text(json.dumps(rows, indent=1))
    labels = spec.labels()
    term_keys = sorted({k for r in rows for k in r["terms"]})
    with open(out / "evaluations.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["generation", "index", *labels, *[f"cost_{i}" for i in range(len(best_f))], *term_keys,
                    "failure"])
        for r in rows:
            w.writerow([r["generation"], r["index"], *[r["genome"][k] for k in labels], *r["cost"],
                        *[r["terms"].get(k) for k in term_keys], r["failure"]])
    best = write_best_yaml(spec, best_x, out / "best.yaml")
    summary = {"name": spec.name, "spec": str(spec.path), "algorithm": spec.algorithm, "cost": spec.cost,
               "seed": spec.seed, "best_cost": [float(v) for v in best_f], "best_parameters": best,
               "generations": history, "pareto_front": [{"cost": r["cost"], "genome": r["genome"]} for r in front]}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
