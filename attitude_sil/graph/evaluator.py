"""Score tuning candidates through the live graph (``evaluation.mode: graph``).

Each candidate's controller parameters are set through the controller's
parameter service, ``plant/reset`` starts the episode, and the cost comes from
the episode's :class:`~attitude_sil.core.trajectory.Trajectory` through the
same :func:`attitude_sil.tuning.evaluate.score` the batch engine uses.
``replicas: N`` runs N namespaced copies of the graph in N processes, each
taking a share of the population.
"""

from __future__ import annotations

import atexit
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from attitude_sil.errors import SpecError
from attitude_sil.graph.session import GraphSession
from attitude_sil.tuning.evaluate import PENALTY, Evaluation, scenario_for, score
from attitude_sil.tuning.results import parameter_values
from attitude_sil.tuning.spec import TuningSpec, apply_overrides, decode, load_spec

__all__ = ["GraphEpisodes", "GraphEvaluator", "best_parameters"]


def best_parameters(spec: TuningSpec, x: np.ndarray) -> dict:
    """Controller parameters (ROS values) of one candidate's optimiser variables, (n_var,)."""
    params, _ = decode(spec, x[None])
    return parameter_values(params, 0)


class GraphEpisodes:
    """One graph (a :class:`GraphSession`) scoring candidates one after another."""

    def __init__(self, spec: TuningSpec, namespace: str | None, record: Path | None) -> None:
        if len(spec.scenarios) != 1 or len(spec.conditions) != 1:
            raise SpecError(f"{spec.path}: graph evaluation takes one scenario and one condition")
        self.spec = spec
        self.scn = scenario_for(spec, spec.scenarios[0], spec.conditions[0])
        self.session = GraphSession(self.scn, controller=spec.controller, namespace=namespace).__enter__()
        self.record = record

    def run(self, params: dict, record_dir: Path | None):
        """One episode with these controller parameters; returns the :class:`RunResult`."""
        return self.session.run_episode(controller_params=params, record_dir=record_dir, keep_trajectory=True)

    def score_rows(self, x: np.ndarray, tags: list[str]) -> Evaluation:
        """Costs of candidates ``x`` (P, n_var); ``tags`` name their bags."""
        spec = self.spec
        params, values = decode(spec, x)
        final_time = params.pop("final_time", None)
        n = x.shape[0]
        n_obj = 2 if spec.cost["name"] == "ts_ce" else 1
        F = np.zeros((n, n_obj))
        reasons = [""] * n
        rows_terms: list[dict] = []
        for i in range(n):
            record_dir = None if self.record is None else self.record / tags[i]
            tr = self.run(parameter_values(params, i), record_dir).trajectory
            terms: dict = {}
            f_i = np.zeros((1, n_obj))

            def fail(mask, why, i=i):
                if np.any(mask) and not reasons[i]:
                    reasons[i] = why

            score(spec, self.scn, tr, None if final_time is None else final_time[i:i + 1], f_i, terms, fail)
            F[i] = f_i[0]
            rows_terms.append(terms)
        for i, why in enumerate(reasons):
            if why:
                F[i] = PENALTY
        keys = sorted({k for t in rows_terms for k in t})
        terms = {k: np.array([float(np.asarray(t.get(k, np.nan)).ravel()[0]) for t in rows_terms]) for k in keys}
        return Evaluation(F=np.nan_to_num(F, nan=PENALTY, posinf=PENALTY), terms=terms, reasons=reasons,
                          values=values)

    def close(self) -> None:
        self.session.__exit__(None, None, None)


_WORKER: GraphEpisodes | None = None


def _init_worker(spec_path: str, overrides: dict, ids, record: str | None) -> None:
    global _WORKER
    spec = apply_overrides(load_spec(spec_path), overrides)
    idx = ids.get()
    _WORKER = GraphEpisodes(spec, f"replica{idx}", None if record is None else Path(record))
    atexit.register(_WORKER.close)


def _worker_score(x: np.ndarray, tags: list[str]) -> Evaluation:
    return _WORKER.score_rows(x, tags)


class GraphEvaluator:
    """Scores populations through the live graph, on ``replicas`` graphs in parallel."""

    def __init__(self, spec: TuningSpec, replicas: int = 1, record: Path | None = None,
                 overrides: dict | None = None) -> None:
        self.spec = spec
        self.replicas = max(1, int(replicas))
        self.record = record
        self.overrides = overrides or {}
        self.generation = 0
        self.episodes = 0

    def __enter__(self) -> GraphEvaluator:
        if self.replicas == 1:
            self.local = GraphEpisodes(self.spec, None, self.record)
            self.pool = None
        else:
            ctx = mp.get_context("spawn")
            ids = ctx.Queue()
            for i in range(self.replicas):
                ids.put(i)
            self.pool = ProcessPoolExecutor(self.replicas, mp_context=ctx, initializer=_init_worker,
                                            initargs=(str(self.spec.path), self.overrides, ids,
                                                      None if self.record is None else str(self.record)))
        return self

    def __exit__(self, *exc) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)
        else:
            self.local.close()

    def __call__(self, x: np.ndarray) -> Evaluation:
        self.generation += 1
        x = np.atleast_2d(x)
        tags = [f"g{self.generation:03d}_c{i:03d}" for i in range(x.shape[0])]
        self.episodes += x.shape[0]
        if self.pool is None:
            return self.local.score_rows(x, tags)
        idx = np.array_split(np.arange(x.shape[0]), self.replicas)
        return Evaluation.concat(list(self.pool.map(_worker_score, [x[i] for i in idx],
                                                    [[tags[j] for j in i] for i in idx])))
