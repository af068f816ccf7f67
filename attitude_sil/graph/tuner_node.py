"""``tuner`` node: runs a tuning spec and publishes its progress.

:class:`TunerNode` publishes ``tuner/progress`` (diagnostic_msgs/DiagnosticStatus:
generation, best and median cost, evaluations per second) after every
generation. :func:`tune` is the run itself, shared by the ``tuner_node``
console script and ``attitude-sil tune``:

* ``evaluation.mode: batch`` (default) scores whole populations in the batch
  engine (:mod:`attitude_sil.tuning`); the best candidate of every generation
  whose genome changed is written straight from the engine's trajectory as the
  bag the graph would record (:mod:`attitude_sil.graph.engine_bag`; the
  flexible plant's are re-run through the graph), and the final best is re-run
  through the graph and recorded, a true SIL record (``<output>/bags/``);
* ``evaluation.mode: graph`` runs every candidate through the live graph
  (:mod:`attitude_sil.graph.evaluator`); every episode is recorded.

The node lives in the graph layer (not ``nodes/``) because it drives whole
graphs: it starts a :class:`~attitude_sil.graph.session.GraphSession` to record.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from attitude_sil.core.sim.engine import simulate
from attitude_sil.errors import AttitudeSilError, SpecError
from attitude_sil.graph.engine_bag import record_episode
from attitude_sil.graph.evaluator import GraphEpisodes, GraphEvaluator, best_parameters
from attitude_sil.ros.environment import localhost_environment
from attitude_sil.tuning.evaluate import Evaluator, scalar_groups, scenario_for, scenario_with
from attitude_sil.tuning.executor import DaskCluster
from attitude_sil.tuning.optimize import check_output, run_tuning
from attitude_sil.tuning.results import TuningResult
from attitude_sil.tuning.spec import TuningSpec, apply_overrides, decode, load_spec

__all__ = ["TunerNode", "TuneOutcome", "tune", "main"]


class TunerNode(Node):
    """The ``tuner`` node: parameters ``spec``, ``resume``, ``record``; publishes ``~/progress``."""

    def __init__(self, **kwargs) -> None:
        super().__init__("tuner", **kwargs)
        self.declare_parameter("spec", "", ParameterDescriptor(
            description="tuning spec YAML (config/tune_*.yaml) that main() runs", read_only=True))
        self.declare_parameter("resume", False, ParameterDescriptor(
            description="continue the run saved in the spec's output folder", read_only=True))
        self.declare_parameter("record", True, ParameterDescriptor(
            description="record each generation's best and the final best through the graph", read_only=True))
        self.pub = self.create_publisher(DiagnosticStatus, "~/progress", 10)

    def publish(self, stats: dict) -> None:
        """Publish one generation's statistics (``generation``, ``generations``, ``best``, ...)."""
        msg = DiagnosticStatus(level=DiagnosticStatus.OK, name="tuner",
                               message=f"generation {stats['generation']}/{stats['generations']}",
                               values=[KeyValue(key=k, value=str(v)) for k, v in stats.items()])
        self.pub.publish(msg)


@dataclass
class TuneOutcome:
    """What :func:`tune` did: the optimiser's result, the spec as run, the wall time."""

    result: TuningResult
    spec: TuningSpec
    wall_time_s: float


def _record_from_engine(spec: TuningSpec, x: np.ndarray, path: Path) -> bool:
    """Write a generation's best straight from the batch engine (graph/engine_bag.py); False where it cannot."""
    if len(spec.scenarios) != 1 or len(spec.conditions) != 1:
        raise SpecError(f"{spec.path}: recording takes one scenario and one condition")
    scn = scenario_for(spec, spec.scenarios[0], spec.conditions[0])
    if scn.param("plant", "model") == "flexible_axis":
        return False  # the flexible mode is not in the trajectory: the graph records it
    params, _ = decode(spec, x[None])
    params.pop("final_time", None)
    ((fixed, _),) = scalar_groups(params, 1)  # a scalar gene is the scenario's value, as in evaluation
    scn = scenario_with(scn, fixed)
    params = {k: v for k, v in params.items() if k not in fixed}
    tr = simulate(scn, 1, controller_params=params, controller=spec.controller, schedule=[])
    record_episode(scn, tr, path, controller_params=best_parameters(spec, x), controller=spec.controller)
    return True


def tune(spec_path: str | Path | TuningSpec, *, resume: bool = False, overrides: dict | None = None,
         record: bool = True, on_progress: Callable[[dict], None] | None = None,
         should_stop: Callable[[], bool] | None = None, scheduler: str | None = None) -> TuneOutcome:
    """Run a tuning spec to its end (or until ``should_stop``), recording bests through the graph.

    ``spec_path`` is a spec file, or a spec already loaded (``overrides`` are then applied again, which
    is harmless, and handed to graph evaluation). ``scheduler`` (a Dask scheduler address) evaluates
    the populations of a batch-mode spec on that cluster: the same result as a local run.

    Raises
    ------
    SpecError
        Bad spec, bad override, or results of an earlier run in the way without ``resume``.
    RunError
        A recording episode failed.
    """
    spec = spec_path if isinstance(spec_path, TuningSpec) else load_spec(spec_path)
    spec = apply_overrides(spec, overrides or {})
    bags = spec.output / "bags"
    mode = spec.evaluation.get("mode", "batch")
    recorder: GraphEpisodes | None = None
    last_recorded: list[np.ndarray | None] = [None]

    def record_best(gen: int, x: np.ndarray, cost: float) -> None:
        nonlocal recorder
        if not record or mode != "batch" or not spec.record.get("best_per_generation", True):
            return
        if last_recorded[0] is not None and np.array_equal(last_recorded[0], x):
            return
        path = bags / f"best_g{gen:03d}"
        if not _record_from_engine(spec, x, path):
            if recorder is None:
                recorder = GraphEpisodes(spec, None, bags)
            recorder.run(best_parameters(spec, x), path)
        last_recorded[0] = x.copy()

    evaluator = None
    cluster = None
    t0 = time.monotonic()
    try:
        check_output(spec, resume)
        if mode == "graph":
            if scheduler:
                raise SpecError(f"{spec.path}: a Dask scheduler evaluates batch mode only (evaluation.mode is graph)")
            evaluator = GraphEvaluator(spec, int(spec.evaluation.get("replicas", 1)), bags if record else None,
                                       overrides).__enter__()
        elif scheduler:
            evaluator = Evaluator(spec, executor=DaskCluster(scheduler)).__enter__()
            cluster = evaluator.executor
        result = run_tuning(spec, resume=resume, evaluator=evaluator, progress=on_progress,
                            should_stop=should_stop, on_generation=record_best)
        if record and mode == "batch" and not result.interrupted and spec.algorithm["name"] != "root_locus":
            final = bags / "best_final"
            if not final.exists():
                if recorder is None:
                    recorder = GraphEpisodes(spec, None, bags)
                recorder.run(best_parameters(spec, result.best_x), final)
    finally:
        if evaluator is not None:
            evaluator.__exit__(None, None, None)
        if cluster is not None:
            cluster.close()
        if recorder is not None:
            recorder.close()
    return TuneOutcome(result=result, spec=spec, wall_time_s=time.monotonic() - t0)


def main(args: list[str] | None = None) -> int:
    """Console script ``tuner_node``: ``tuner_node --ros-args -p spec:=config/tune_hst_pid_ga.yaml``.

    Runs the spec, publishing progress on ``tuner/progress`` and logging each
    generation; Ctrl-C stops after the current generation (``-p resume:=true``
    continues). Bad input logs one line and exits 2.
    """
    localhost_environment()
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = TunerNode()
        spec = node.get_parameter("spec").value
        if not spec:
            raise SpecError("no spec given: tuner_node --ros-args -p spec:=config/tune_hst_pid_ga.yaml")

        def progress(stats: dict) -> None:
            node.publish(stats)
            node.get_logger().info(f"generation {stats['generation']}/{stats['generations']}: "
                                   f"best {stats['best']:.6g}, {stats['evals_per_s']:.0f} evaluations/s")

        outcome = tune(spec, resume=node.get_parameter("resume").value, record=node.get_parameter("record").value,
                       on_progress=progress, should_stop=lambda: not rclpy.ok())
        node.get_logger().info(f"best cost {outcome.result.best_cost.tolist()} in {outcome.wall_time_s:.1f} s; "
                               f"results in {outcome.spec.output}")
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 130
    except AttitudeSilError as exc:
        print(f"tuner_node: error: {exc}", file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    raise SystemExit(main())
