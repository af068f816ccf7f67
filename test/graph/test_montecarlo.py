"""Monte Carlo dispersions in the batch engine, the graph and a campaign.

The core extensions (per-episode motor constants, wheel failures, sensor noise)
must give the same numbers in the compiled and the stepwise driver and in the
node graph; a run's dispersions must depend on its index only; a campaign
stopped part-way and resumed must equal one run straight through; a robust
cost is the mean (or worst) of its candidate's dispersed runs.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from attitude_sil.core.sim.build import build_wheels
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.session import run_graph
from attitude_sil.tuning.dispersions import check_dispersions, episode_values, run_scenario
from attitude_sil.tuning.evaluate import evaluate
from attitude_sil.tuning.executor import InProcess, LocalProcesses
from attitude_sil.tuning.montecarlo import load_mc_spec, run_campaign, worst_runs
from attitude_sil.tuning.spec import load_spec
from conftest import CONFIG, ROOT

ALL = {"inertia_pct": {"dist": "normal", "scale": [5, 5, 5]}, "initial_attitude_deg": {"scale": 0.05},
       "initial_rate_deg_s": {"dist": "uniform", "scale": 0.002}, "setpoint_deg": {"scale": [0.1, 0, 0]},
       "motor_constant_pct": {"scale": 5}, "wheel_failure": {"probability": 1.0, "time": [0.5, 2.5]},
       "sensor_noise": {"attitude_std_deg": 0.002, "rate_std_deg_s": 0.001}}


@pytest.fixture(scope="module")
def hst():
    return load_scenario(CONFIG / "hst_roll_step.yaml").with_values("plant", duration=3.0)


def test_dispersed_runs_agree_in_both_drivers_and_depend_on_their_index_only(hst):
    disp = check_dispersions("t", ALL, hst)
    values = episode_values(hst, disp, 5, np.arange(6))
    assert set(values["wheels.failure.mode"]) == {"lost", "stuck"}  # both failure modes are exercised
    a = simulate(hst, 6, driver="compiled", episode_values=values)
    b = simulate(hst, 6, driver="stepwise", episode_values=values)
    for name in ("q_BN", "omega_BN_B", "u_cmd", "tau_c_B", "wheel_speed", "wheel_effort", "wheel_angle"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    nominal = simulate(hst, 1, driver="compiled")
    assert not np.array_equal(a.q_BN[:1], nominal.q_BN)  # the dispersions did something
    part = episode_values(hst, disp, 5, [3, 4])
    for key, col in part.items():
        assert np.array_equal(col, values[key][3:5]), key
    alone = simulate(hst, 2, driver="compiled", episode_values=part)
    assert np.array_equal(alone.q_BN, a.q_BN[3:5])  # a run's numbers do not depend on its batch


def test_lost_wheel_coasts_and_stuck_wheel_holds_its_voltage(hst):
    scn = hst.with_values("wheels", **{"failure.wheel": 2, "failure.time": 1.0, "failure.mode": "lost"})
    w = build_wheels(scn, 1)
    cmd = np.array([[5.0, -3.0, 2.0]])
    for _ in range(100):
        w.advance(cmd)
    speed = w.x[0, 1, 2]
    out = w.advance(cmd)  # step 100 = t 1.0 s: the wheel is lost
    assert w.x[0, 1, 1] == 0.0 and out.velocity[0, 1] == speed
    assert w.x[0, 1, 2] == pytest.approx(speed * np.exp(-1e-4 * 0.01 / 0.84), rel=1e-12)
    stuck = build_wheels(scn.with_values("wheels", **{"failure.mode": "stuck"}), 1)
    healthy = build_wheels(hst, 1)
    for k in range(150):
        c = 0.1 * cmd * (1 + 0.01 * k)  # a ramp inside the drive limit: a held voltage differs from the ramp's
        stuck.advance(c)
        healthy.advance(c)
    held = stuck.e_hold[0]
    assert 0.0 < abs(held) < scn.param("wheels", "motor.v_max")
    assert not np.array_equal(stuck.x[0, 1], healthy.x[0, 1])
    assert np.array_equal(stuck.x[0, 0], healthy.x[0, 0])  # the other wheels are untouched


def test_a_dispersed_run_through_the_node_graph_matches_the_batch_engine(hst, tmp_path):
    disp = check_dispersions("t", ALL, hst)
    values = episode_values(hst, disp, 5, [0, 1, 2])
    row = int(np.argmax(values["wheels.failure.mode"] == "stuck"))
    scn = run_scenario(hst, values, row)
    batch = simulate(hst, 3, episode_values=values)
    graph = run_graph(scn, progress=False, keep_trajectory=True)
    np.testing.assert_allclose(graph.trajectory.q_BN[0], batch.q_BN[row], rtol=0, atol=1e-9)
    np.testing.assert_allclose(graph.trajectory.u_cmd[0], batch.u_cmd[row], rtol=0, atol=1e-9)


def _spec(tmp_path, runs=24, chunk=5, extra=""):
    text = (CONFIG / "mc_hst_roll_step.yaml").read_text().replace("scenario: ", f"scenario: {CONFIG}/")
    text = text.replace("output: results/mc_hst_roll_step", f"output: {tmp_path}/out").replace(
        "chunk: 100", f"chunk: {chunk}").replace("disturbance.models: [noise]", "disturbance.models: [noise]\n"
                                                  "  plant.duration: 4.0") + extra
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "mc.yaml"
    path.write_text(text)
    return load_mc_spec(path, runs=runs)


def test_a_campaign_stopped_and_resumed_equals_one_run_straight_through(tmp_path):
    whole = _spec(tmp_path / "a")
    with InProcess() as ex:
        ref = run_campaign(whole, ex)
    assert not ref.interrupted and len(ref.table["run"]) == 24
    summary = json.loads((whole.output / "summary.json").read_text())
    assert summary["completed_runs"] == 24 and 0.0 <= summary["pass_rate"] <= 1.0
    assert set(summary["metrics"]["time_constant_s"]) >= {"p50", "p90", "p99"}
    assert summary["metrics"]["settling_time_s"]["never"] == 24  # 4 s runs do not settle: NaN, counted
    assert (whole.output / "runs.csv").read_text().count("\n") == 25
    part = _spec(tmp_path / "b")
    calls = []
    with LocalProcesses(2) as ex:  # another back-end, stopped after two chunks
        first = run_campaign(part, ex, should_stop=lambda: len(calls) >= 2,
                             progress=lambda done, total, wall: calls.append(done) if done else None)
    assert first.interrupted and 0 < len(first.table["run"]) < 24
    with InProcess() as ex:
        rest = run_campaign(part, ex, resume=True)
    assert not rest.interrupted
    for key, col in ref.table.items():
        assert np.array_equal(col, rest.table[key], equal_nan=col.dtype.kind == "f"), key
    rows = worst_runs(whole, ref.table)
    assert len(rows) == 3 and all(np.isnan(ref.table["settling_time_s"][r]) or ref.table["settling_time_s"][r]
                                  >= np.nanmedian(ref.table["settling_time_s"]) for r in rows)


def test_robust_cost_is_the_mean_or_worst_of_the_candidates_dispersed_runs(tmp_path):
    text = (CONFIG / "tune_hst_pid_ga.yaml").read_text().replace("scenarios: [", f"scenarios: [{CONFIG}/")
    text += "\nrobust: {runs: 3, statistic: mean, seed: 4, dispersions: {inertia_pct: {scale: [10, 10, 10]}}}\n"
    (tmp_path / "t.yaml").write_text(text)
    spec = load_spec(tmp_path / "t.yaml")
    x = np.array([[48.894, 0.071, 106.046, 1.427], [120.0, 0.01, 150.0, 3.0], [30.0, 0.2, 80.0, 2.0]])
    whole = evaluate(spec, x)
    split = [evaluate(spec, x[:1], 0), evaluate(spec, x[1:], 1)]
    assert np.array_equal(whole.F, np.concatenate([s.F for s in split]))
    scn = spec.scenarios[0]
    values = episode_values(scn, spec.robust["dispersions"], 4, np.arange(3))
    plain = spec.__class__(**{**spec.__dict__, "robust": {}})
    singles = []
    for j in range(3):  # run j of every candidate is the plant of dispersed run j
        s = plain.__class__(**{**plain.__dict__, "scenarios": [run_scenario(scn, values, j)]})
        singles.append(evaluate(s, x).F[:, 0])
    np.testing.assert_array_equal(whole.F[:, 0], np.mean(np.stack(singles, axis=1), axis=1))
    worst = spec.__class__(**{**spec.__dict__, "robust": {**spec.robust, "statistic": "max"}})
    np.testing.assert_array_equal(evaluate(worst, x).F[:, 0], np.max(np.stack(singles, axis=1), axis=1))


def test_set_and_output_override_the_spec_and_count_in_its_identity(cli, tmp_path):
    spec = CONFIG / "mc_hst_roll_step.yaml"
    out = tmp_path / "camp"
    base = ["montecarlo", str(spec), "--runs", "4", "--in-process", "--no-bags", "--quiet", "--output", str(out),
            "--set", "set.plant.duration=1.0"]
    first = cli(*base, "--set", "seed=5", "--set", "requirements.settling_time_s.max=0.5")
    assert first.returncode == 0, first.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 5 and summary["completed_runs"] == 4
    assert (out / "runs.csv").is_file() and not (ROOT / "results" / "camp").exists()
    # the same output again: refused, and --resume with another --set is another campaign: refused too
    again = cli(*base, "--set", "seed=5")
    assert again.returncode == 2 and "--output DIR writes elsewhere" in again.stderr
    other = cli(*base, "--set", "seed=6", "--resume")
    assert other.returncode == 2 and "written by a different spec" in other.stderr
    for bad, needle in (("bogus=1", "unknown key 'bogus'"), ("seed", "KEY=VALUE"), ("runs.x=1", "not a mapping")):
        res = cli("montecarlo", str(spec), "--set", bad)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and needle in res.stderr, res.stderr
