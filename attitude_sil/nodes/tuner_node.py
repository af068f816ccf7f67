"""``tuner`` node and ``attitude-sil tune``: run a tuning spec, in batch or through the graph.

* The ``tuner`` node publishes the progress of the run on ``tuner/progress``
  (diagnostic_msgs/DiagnosticStatus: generation, best and median cost,
  evaluations per second) after every generation.
* ``evaluation.mode: batch`` (default) scores whole populations in the batch
  engine (:mod:`attitude_sil.tuning`); the best candidate of every generation
  whose genome changed, and the final best, are re-run through the graph and
  recorded (``<output>/bags/``).
* ``evaluation.mode: graph`` runs every candidate through the live graph: the
  controller's parameters are set through its parameter service, ``plant/reset``
  starts the episode, and the cost comes from the topics received; every
  episode is recorded. ``evaluation.replicas: N`` runs N namespaced copies of
  the graph in N processes, each taking a share of the population.
"""

from __future__ import annotations

import atexit
import json
import math
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from attitude_sil.tuning.evaluate import PENALTY, Evaluation, scenario_for, score
from attitude_sil.tuning.optimize import parameter_values
from attitude_sil.tuning.spec import SpecError, TuningSpec, decode, load_spec

__all__ = ["GraphEvaluator", "TunerNode", "tune_command"]


@dataclass
class _GraphTrajectory:
    """The arrays :func:`attitude_sil.tuning.evaluate.score` needs, from one graph episode."""

    t: np.ndarray
    q_BN: np.ndarray
    q_RN: np.ndarray
    omega_BN_B: np.ndarray
    tau_c_B: np.ndarray
    u_cmd: np.ndarray
    wheel_speed: None = None


def _as_batch(traj: dict) -> _GraphTrajectory:
    n = min(len(traj["attitude"]), len(traj["attitude_setpoint"]), len(traj["wheel_torque"]), len(traj["body_rate"]),
            len(traj.get("command", [])))
    return _GraphTrajectory(t=traj["attitude_t"][:n] * 1e-9, q_BN=traj["attitude"][None, :n],
                            q_RN=traj["attitude_setpoint"][None, :n], omega_BN_B=traj["body_rate"][None, :n],
                            tau_c_B=traj["wheel_torque"][None, :n], u_cmd=traj["command"][None, :n])


def _best_params(spec: TuningSpec, x: np.ndarray) -> dict:
    """Controller parameters (ROS values) of one candidate's optimiser variables."""
    params, _ = decode(spec, x[None])
    return parameter_values(params, 0)


class _Episodes:
    """One graph (GraphSession) scoring candidates one after another."""

    def __init__(self, spec: TuningSpec, namespace: str | None, record: Path | None) -> None:
        from attitude_sil.runner import GraphSession

        if len(spec.scenarios) != 1 or len(spec.conditions) != 1:
            raise SpecError(f"{spec.path}: graph evaluation takes one scenario and one condition")
        self.spec = spec
        self.scn = scenario_for(spec, spec.scenarios[0], spec.conditions[0])
        self.session = GraphSession(self.scn, controller=spec.controller, namespace=namespace).__enter__()
        self.record = record

    def score_rows(self, x: np.ndarray, tags: list[str]) -> Evaluation:
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
            result = self.session.run_episode(controller_params=parameter_values(params, i), record_dir=record_dir)
            tr = _as_batch(result.trajectory)
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


_WORKER: _Episodes | None = None


def _init_worker(spec_path: str, overrides: dict, ids, record: str | None) -> None:
    global _WORKER
    spec = _apply_overrides(load_spec(spec_path), overrides)
    idx = ids.get()
    _WORKER = _Episodes(spec, f"replica{idx}", None if record is None else Path(record))
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
            self.local = _Episodes(self.spec, None, self.record)
            self.pool = None
        else:
            import multiprocessing as mp

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


def _apply_overrides(spec: TuningSpec, overrides: dict) -> TuningSpec:
    """``--set section.key=value`` on a loaded spec (algorithm, cost, evaluation, record, seed)."""
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
    return spec


class TunerNode:
    """The ``tuner`` node: publishes ``tuner/progress`` (diagnostic_msgs/DiagnosticStatus)."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticStatus
        from rclpy.node import Node

        from attitude_sil.runner import localhost_environment

        localhost_environment()
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.node = Node("tuner", context=self.context)
        self.pub = self.node.create_publisher(DiagnosticStatus, "~/progress", 10)
        self._msg = DiagnosticStatus

    def publish(self, stats: dict) -> None:
        from diagnostic_msgs.msg import KeyValue

        msg = self._msg(level=self._msg.OK, name="tuner",
                        message=f"generation {stats['generation']}/{stats['generations']}",
                        values=[KeyValue(key=k, value=str(v)) for k, v in stats.items()])
        self.pub.publish(msg)

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _bar(stats: dict, width: int = 24) -> str:
    done = stats["generation"] / max(stats["generations"], 1)
    fill = int(round(done * width))
    median = stats["median"]
    med = "n/a" if not math.isfinite(median) else f"{median:.4g}"
    return (f"gen {stats['generation']:>3}/{stats['generations']} [{'#' * fill}{'.' * (width - fill)}] "
            f"best {stats['best']:.5g}  median {med}  failed {stats['failed']}  "
            f"{stats['evals_per_s']:.0f} evals/s" + ("  (from the saved run)" if stats.get("cached") else ""))


def tune_command(spec_path: str, *, resume: bool = False, overrides: dict | None = None, quiet: bool = False,
                 record: bool = True) -> dict:
    """Body of ``attitude-sil tune``; returns the summary printed at the end.

    Raises
    ------
    SpecError
        Bad spec or resume mismatch.
    """
    from attitude_sil.tuning.optimize import run_tuning

    spec = _apply_overrides(load_spec(spec_path), overrides or {})
    stop = {"flag": False}

    def on_sigint(signum, frame):
        if stop["flag"]:
            raise KeyboardInterrupt
        stop["flag"] = True
        print("\nstopping after this generation (Ctrl-C again to stop now)", file=sys.stderr)

    old = signal.signal(signal.SIGINT, on_sigint)
    tuner = TunerNode()
    bags = spec.output / "bags"
    mode = spec.evaluation.get("mode", "batch")
    recorder = None
    last_recorded = [None]

    def progress(stats):
        tuner.publish(stats)
        if not quiet:
            print(_bar(stats), file=sys.stderr, flush=True)

    def record_best(gen, x, cost):
        nonlocal recorder
        if not record or mode != "batch" or not spec.record.get("best_per_generation", True):
            return
        if last_recorded[0] is not None and np.array_equal(last_recorded[0], x):
            return
        if recorder is None:
            recorder = _Episodes(spec, None, bags)
        recorder.session.run_episode(controller_params=_best_params(spec, x), record_dir=bags / f"best_g{gen:03d}")
        last_recorded[0] = x.copy()

    evaluator = None
    if mode == "graph":
        evaluator = GraphEvaluator(spec, int(spec.evaluation.get("replicas", 1)), bags if record else None,
                                   overrides).__enter__()
    t0 = time.monotonic()
    try:
        if not resume and bags.exists() and any(bags.iterdir()):
            raise SpecError(f"{bags}: results of an earlier run are there; use --resume or another output")
        result = run_tuning(spec, resume=resume, evaluator=evaluator, progress=progress,
                            should_stop=lambda: stop["flag"], on_generation=record_best)
        if record and mode == "batch" and not result.interrupted and spec.algorithm["name"] != "root_locus":
            if recorder is None:
                recorder = _Episodes(spec, None, bags)
            final = bags / "best_final"
            if not final.exists():
                recorder.session.run_episode(controller_params=_best_params(spec, result.best_x), record_dir=final)
    finally:
        signal.signal(signal.SIGINT, old)
        if evaluator is not None:
            evaluator.__exit__(None, None, None)
        if recorder is not None:
            recorder.close()
        tuner.close()
    summary = json.loads((spec.output / "summary.json").read_text()) if (spec.output / "summary.json").exists() \
        else {}
    summary["wall_time_s"] = time.monotonic() - t0
    summary["interrupted"] = result.interrupted
    summary["evaluations"] = result.evaluations
    summary["output"] = str(spec.output)
    return summary
