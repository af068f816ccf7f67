"""The tuner: every algorithm improves on its start, penalties, resume, export, batch == graph."""

import json

import numpy as np
import pytest
import yaml

from attitude_sil.core.analysis.metrics import scenario_metrics
from attitude_sil.core.sim.engine import simulate
from attitude_sil.graph.evaluator import GraphEvaluator
from attitude_sil.tuning.evaluate import PENALTY, evaluate
from attitude_sil.tuning.optimize import run_tuning
from attitude_sil.tuning.spec import SpecError, load_spec
from conftest import CONFIG


def small(name, tmp_path, pop, gens, duration=None, **algo):
    spec = load_spec(CONFIG / name)
    spec.output = tmp_path / spec.name
    spec.algorithm.update(pop_size=pop, generations=gens, **algo)
    spec.evaluation["workers"] = 1
    if duration is not None:
        spec.scenarios = [s.with_values("plant", duration=duration) for s in spec.scenarios]
    return spec


@pytest.mark.parametrize("name,pop,gens,duration", [
    ("tune_hst_pid_ga.yaml", 12, 6, None),
    ("tune_hawaiisat_geometric_ga.yaml", 12, 4, 300.0),
    ("tune_flexible_pid_pso.yaml", 10, 5, 40.0),
    ("tune_pitch_flc_ga.yaml", 12, 6, None),
])
def test_each_algorithm_improves_on_its_starting_population(name, pop, gens, duration, tmp_path):
    spec = small(name, tmp_path, pop, gens, duration)
    result = run_tuning(spec)
    first = result.generations[0]["generation_best"]
    assert result.best_cost[0] < first  # better than the best of the random start
    assert result.best_cost[0] < PENALTY
    rows = json.loads((spec.output / "evaluations.json").read_text())
    assert len(rows) >= pop * gens - pop  # pymoo may skip duplicates
    assert {"generation", "genome", "cost", "terms", "failure"} <= set(rows[0])


def test_nsga2_front_improves_and_is_non_dominated(tmp_path):
    spec = small("tune_hawaiisat_pareto.yaml", tmp_path, 10, 4, 300.0)
    result = run_tuning(spec)
    front = np.array([r["cost"] for r in result.front])
    assert len(front) >= 2
    for p in front:  # nothing on the front dominates another point of it
        assert not np.any(np.all(front <= p, axis=1) & np.any(front < p, axis=1))
    rows = json.loads((spec.output / "evaluations.json").read_text())
    gen1 = np.array([r["cost"] for r in rows if r["generation"] == 1 and not r["failure"]])
    assert len(gen1) > 0, "no valid start point to compare the front with"
    # every valid start point is dominated by (or on) the final front
    for p in gen1:
        assert np.any(np.all(front <= p + 1e-12, axis=1))


def test_root_locus_meets_the_targets_on_the_linear_model(tmp_path):
    spec = load_spec(CONFIG / "tune_hst_pid_rootlocus.yaml")
    spec.output = tmp_path / "rl"
    run_tuning(spec)
    summary = json.loads((spec.output / "summary.json").read_text())
    assert summary["linear_step_info"]["Overshoot"] < 2.0
    assert summary["linear_step_info"]["SettlingTime"] < 6.0
    # the design is placed on the linear model; the HST wheels as rated (0.8 N m) saturate on the nonlinear
    # step, which can only slow it: 2.08 s here (1.47 s on the unlimited variant, docs/fidelity.md)
    assert 1.5 - 0.1 < summary["nonlinear"]["time_constant_s"] < 3.0
    assert (spec.output / "root_locus.png").stat().st_size > 10_000


def test_death_penalty_equal_gains_and_divergence_get_reasons_not_crashes():
    spec = load_spec(CONFIG / "tune_hawaiisat_geometric_ga.yaml")
    spec.scenarios = [s.with_values("plant", duration=60.0) for s in spec.scenarios]
    ones = np.ones(6)
    x = np.stack([
        np.concatenate([np.ones(6 * 3), np.ones(6 * 3)]),  # K = L = 0.1 I: equal k_i, and too strong
        np.concatenate([ones, np.zeros(6), [0, 1, 0, 0, 0, 0], np.zeros(18)]),  # k = (0.1, 1e-4, 0.016): death
        np.concatenate([[0, 0, 0, 1, 1, 0], [0, 0, 0, 0, 1, 1], [0, 0, 0, 1, 0, 1], np.tile([1, 1, 1, 0, 0, 0], 3)]),
    ])
    ev = evaluate(spec, x)
    assert ev.reasons[0].startswith("equal k_i")
    assert ev.reasons[1].startswith("death penalty")
    assert ev.F[0, 0] == PENALTY and ev.F[1, 0] == PENALTY
    assert ev.reasons[2] == "" or ev.reasons[2] == "never settled"  # a gentle design: no rule broken
    spec_pid = load_spec(CONFIG / "tune_hst_pid_ga.yaml")
    bad = evaluate(spec_pid, np.array([[np.nan, 0.0, 1.0, 1.0], [50.0, 0.1, 100.0, 1.4]]))
    assert bad.reasons[0] != "" and bad.F[0, 0] == PENALTY
    assert bad.reasons[1] == "" and bad.F[1, 0] < 1.0


def test_resume_gives_the_uninterrupted_result(tmp_path):
    whole = small("tune_hst_pid_ga.yaml", tmp_path / "a", 10, 5)
    full = run_tuning(whole)
    part = small("tune_hst_pid_ga.yaml", tmp_path / "b", 10, 5)
    calls = {"n": 0}

    def stop_after_two():
        calls["n"] += 1
        return calls["n"] > 2

    first = run_tuning(part, should_stop=stop_after_two)
    assert first.interrupted and len(first.generations) == 2
    resumed = run_tuning(part, resume=True)
    assert [g["cached"] for g in resumed.generations] == [True, True, False, False, False]
    assert np.array_equal(resumed.best_x, full.best_x)
    a = json.loads((whole.output / "evaluations.json").read_text())
    b = json.loads((part.output / "evaluations.json").read_text())
    assert [r["x"] for r in a] == [r["x"] for r in b]
    # a changed spec cannot resume a run it did not make
    other = small("tune_hst_pid_ga.yaml", tmp_path / "b", 10, 5)
    other.seed = 7
    with pytest.raises(SpecError, match="cannot resume"):
        run_tuning(other, resume=True)


def test_exported_yaml_reproduces_the_reported_cost(tmp_path):
    spec = small("tune_hst_pid_ga.yaml", tmp_path, 10, 3)
    run_tuning(spec)
    summary = json.loads((spec.output / "summary.json").read_text())
    best = yaml.safe_load((spec.output / "best.yaml").read_text())["/**/controller"]["ros__parameters"]
    scn = spec.scenarios[0].with_values("controller", **{k: v for k, v in best.items()})
    tr = simulate(scn, 1, controller=best["controller_type"], schedule=[])
    m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_c_B, scn.values["scenario"])
    assert m["cost_J"][0] == pytest.approx(summary["best_cost"][0], rel=1e-12)


def test_batch_and_graph_give_the_same_cost(tmp_path):
    spec = load_spec(CONFIG / "tune_hst_pid_ga.yaml")
    spec.scenarios = [s.with_values("plant", duration=5.0) for s in spec.scenarios]
    x = np.array([[48.894, 0.071, 106.046, 1.427], [113.554, 0.006, 260.942, 14.626], [80.0, 0.5, 150.0, 3.0]])
    batch = evaluate(spec, x)
    with GraphEvaluator(spec, replicas=1, record=tmp_path / "bags") as graph:
        live = graph(x)
    assert np.allclose(live.F, batch.F, rtol=1e-9, atol=1e-12)
    assert sorted(p.name for p in (tmp_path / "bags").iterdir()) == ["g001_c000", "g001_c001", "g001_c002"]


def test_same_seed_same_result(tmp_path):
    a = run_tuning(small("tune_flexible_pid_pso.yaml", tmp_path / "a", 6, 3, 20.0))
    b = run_tuning(small("tune_flexible_pid_pso.yaml", tmp_path / "b", 6, 3, 20.0))
    assert np.array_equal(a.best_x, b.best_x)


def test_robustness_over_inertia_errors_and_flexible_cases():
    from attitude_sil.core.sim.scenario import load_scenario
    from attitude_sil.tuning.robustness import robustness

    rows = robustness(load_scenario(CONFIG / "hawaiisat_lvlh.yaml"))
    assert [r["case"] for r in rows][0] == "J -12.5 %" and len(rows) == 11
    ts = [r["settling_time_s"] for r in rows]
    ce = [r["control_effort_Nms"] for r in rows]
    assert np.all(np.diff(ce) > 0)  # a heavier body costs more effort (paper 001 Fig. 6)
    assert ts[-1] > ts[5] > ts[0]  # and settles later
    flex = robustness(load_scenario(CONFIG / "flexible_axis.yaml"))
    assert [r["case"] for r in flex] == ["nominal", "case1", "case2", "case3", "case4"]
    assert len({round(r["mse"], 9) for r in flex}) == 5


def test_tuner_node_publishes_progress():
    import time

    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.executors import SingleThreadedExecutor

    from attitude_sil.graph.tuner_node import TunerNode

    got = []
    ctx = rclpy.Context()
    rclpy.init(args=[], context=ctx)
    tuner = TunerNode(context=ctx)
    listener = rclpy.create_node("progress_listener", context=ctx)
    listener.create_subscription(DiagnosticStatus, "/tuner/progress", got.append, 10)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(listener)
    try:
        deadline = time.monotonic() + 20
        while tuner.pub.get_subscription_count() < 1:  # discovery, by condition
            assert time.monotonic() < deadline
            executor.spin_once(timeout_sec=0.05)
        tuner.publish({"generation": 3, "generations": 40, "best": 0.5, "median": 1.25, "failed": 2,
                       "evals_per_s": 400.0})
        while not got:
            assert time.monotonic() < deadline
            executor.spin_once(timeout_sec=0.05)
    finally:
        listener.destroy_node()
        tuner.destroy_node()
        rclpy.try_shutdown(context=ctx)
    values = {kv.key: kv.value for kv in got[0].values}
    assert got[0].name == "tuner" and got[0].message == "generation 3/40"
    assert values["best"] == "0.5" and values["median"] == "1.25" and values["failed"] == "2"


def test_a_population_scores_the_same_whole_in_slices_and_over_workers(tmp_path, monkeypatch):
    # noise makes every candidate's result depend on its seed: the seeds must follow the candidate,
    # not its position in a slice or a worker's share
    from attitude_sil.tuning import evaluate as ev

    spec = small("tune_hst_pid_ga.yaml", tmp_path, 9, 1, duration=2.0)
    spec.scenarios = [s.with_values("disturbance", models=["noise"], **{"noise.power": [5e-2, 5e-2, 5e-2]})
                      for s in spec.scenarios]
    x = np.random.default_rng(5).uniform([10, 0, 50, 1], [100, 1, 200, 10], (9, 4))
    whole = evaluate(spec, x)
    monkeypatch.setattr(ev, "EPISODES_PER_SLICE", 4)
    sliced = evaluate(spec, x)
    with ev.Evaluator(spec, workers=2) as workers:
        split = workers(x)
    assert np.array_equal(whole.F, sliced.F) and np.array_equal(whole.F, split.F)
    # and the noise matters: the same design under other seeds scores differently
    shifted = evaluate(spec, x, first=100)
    assert not np.array_equal(whole.F, shifted.F)
