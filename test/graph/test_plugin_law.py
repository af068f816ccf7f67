"""A control law from another package: examples/custom_law registered through the entry point.

The Makefile installs ``examples/custom_law`` (``pip install -e``) as a user
would install their own law. These tests prove the law is found through the
entry-point group alone (nothing in attitude_sil names it) and that it works
everywhere a built-in law does: its parameter table on the controller node,
the stepwise and compiled batch drivers (bit for bit), the graph (== batch to
1e-9, started on it and swapped to it), ``param set controller_type``, the
tuner (genome checked against its table), Monte Carlo and ``replay
--verify-controller``.
"""

import json
from importlib.metadata import entry_points

import numpy as np
import pytest
import yaml

from attitude_sil.core.control import registry
from attitude_sil.core.plant.quaternion import quat_error, quat_to_dcm
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.params import NODE_PARAMS, spec_for
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.errors import SpecError
from attitude_sil.tuning.evaluate import PENALTY
from conftest import CONFIG, ROOT

EXAMPLE = ROOT / "examples" / "custom_law"
LAW = "quat_pd"


def test_the_law_comes_from_the_entry_point_and_nothing_in_the_package_names_it():
    eps = {ep.name: ep for ep in entry_points(group=registry.ENTRY_POINT_GROUP)}
    assert eps[LAW].value == "quat_pd:LAW"
    law = registry.get(LAW)
    assert law.step.py_func.__module__ == "quat_pd"  # the example's module, not a copy in the package
    assert registry.plugin_problems() == []
    sources = list((ROOT / "attitude_sil").rglob("*.py"))
    assert len(sources) > 50, sources  # the package's modules, not an empty glob
    for path in sources:
        assert LAW not in path.read_text(), path  # adding the law touched no file of the package


def test_its_parameters_are_controller_parameters_with_their_table():
    kp = spec_for("controller", f"{LAW}.kp")
    assert kp.runtime and kp.lengths == (3,) and kp.min == 0.0 and "V per unit quaternion error" in kp.description
    assert LAW in spec_for("controller", "controller_type").choices
    assert LAW in spec_for("scenario", "schedule.controller_types").choices
    names = [s.name for s in NODE_PARAMS["controller"]]
    assert names.count(f"{LAW}.kd") == 1


def _pd_reference(tr, kp, kd, u_max):
    """The law as its docstring writes it, in numpy, on a recorded trajectory."""
    q_BN, q_RN, w, w_d = tr.q_BN[0], tr.q_RN[0], tr.omega_BN_B[0], tr.omega_RN_R[0]
    e = -quat_error(q_BN, q_RN)[:, :3]
    Q = np.swapaxes(quat_to_dcm(q_RN), -1, -2) @ quat_to_dcm(q_BN)
    nu = np.einsum("kji,kj->ki", Q, w_d)
    return np.clip(kp * e + kd * (nu - w), -u_max, u_max)


def test_batch_drivers_agree_bit_for_bit_and_run_the_documented_law():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    gains = {f"{LAW}.kp": np.array([[40.0, 50.0, 60.0]] * 3), f"{LAW}.kd": np.array([[30.0, 60.0, 90.0]] * 3)}
    kw = dict(duration=3.0, controller=LAW, controller_params=gains, schedule=[])
    fast = simulate(scn, 3, driver="compiled", **kw)
    slow = simulate(scn, 3, driver="stepwise", **kw)
    assert np.array_equal(fast.q_BN, slow.q_BN) and np.array_equal(fast.u_cmd, slow.u_cmd)
    u_max = scn.param("controller", "output_limit")
    expected = _pd_reference(fast, gains[f"{LAW}.kp"][0], gains[f"{LAW}.kd"][0], u_max)
    assert np.allclose(fast.u_cmd[0], expected, rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(fast.u_cmd[0, :, 0])) > 0.1  # it did command something


def test_swaps_to_and_from_it_in_both_drivers():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    sched = [(100, LAW), (200, "fuzzy_pid"), (250, LAW)]
    fast = simulate(scn, 2, duration=3.0, schedule=sched, driver="compiled")
    slow = simulate(scn, 2, duration=3.0, schedule=sched, driver="stepwise")
    assert np.array_equal(fast.u_cmd, slow.u_cmd)
    # bumpless: no law without a bumpless entry of its own jumps at its swap (the generic decaying offset)
    assert abs(fast.u_cmd[0, 100, 0] - fast.u_cmd[0, 99, 0]) <= 1e-9


def test_graph_equals_batch_started_on_it_and_swapped_to_it():
    from attitude_sil.graph.session import run_graph

    plain = load_scenario(CONFIG / "hst_roll_step.yaml").with_values(
        "scenario", **{"schedule.times": [], "schedule.controller_types": []})
    swapped = plain.with_values("scenario", **{"schedule.times": [1.5], "schedule.controller_types": [LAW]})
    for scn, controller in ((plain, LAW), (swapped, "pid")):
        graph = run_graph(scn, duration=3.0, controller=controller, progress=False, keep_trajectory=True).trajectory
        batch = simulate(scn, 1, duration=3.0, controller=controller)
        assert np.max(np.abs(graph.q_BN - batch.q_BN)) <= 1e-9
        assert np.max(np.abs(graph.omega_BN_B - batch.omega_BN_B)) <= 1e-9


def test_tune_spec_of_the_example_runs_and_its_genome_is_checked(tmp_path):
    from attitude_sil.tuning.optimize import run_tuning
    from attitude_sil.tuning.spec import load_spec

    spec = load_spec(EXAMPLE / "tune_hst_quat_pd.yaml")
    assert [g.param for g in spec.genome] == [f"{LAW}.kp", f"{LAW}.kd"]
    spec.output = tmp_path / "tune"
    spec.algorithm.update(pop_size=8, generations=3)
    result = run_tuning(spec)
    assert result.best_cost[0] < PENALTY  # a stable, scored design
    for gene in spec.genome:
        assert np.all((gene.low <= result.best_params[gene.param]) & (result.best_params[gene.param] <= gene.high))
    bad = yaml.safe_load((EXAMPLE / "tune_hst_quat_pd.yaml").read_text())
    bad["genome"][0]["param"] = f"{LAW}.ki"  # the law has no integral gain
    bad["scenarios"] = [str(CONFIG / "hst_roll_step.yaml")]
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(SpecError, match=f"{LAW}.ki.*not a controller parameter"):
        load_spec(path)


def test_montecarlo_spec_of_the_example_runs(cli, tmp_path):
    spec = yaml.safe_load((EXAMPLE / "mc_hst_quat_pd.yaml").read_text())
    # the worst run re-run through the graph into a bag: one (each costs a graph episode)
    spec.update(scenario=str(CONFIG / "hst_roll_step.yaml"), output=str(tmp_path / "mc"),
                worst={"metric": "settling_time_s", "count": 1})
    path = tmp_path / "mc.yaml"
    path.write_text(yaml.safe_dump(spec))
    res = cli("montecarlo", path, "--runs", "12")
    assert res.returncode == 0, res.stderr
    summary = json.loads((tmp_path / "mc" / "summary.json").read_text())
    assert summary["controller"] == LAW and summary["completed_runs"] == 12
    assert summary["metrics"]["time_constant_s"]["never"] == 0  # every dispersed run moved toward the step
    bags = sorted((tmp_path / "mc" / "bags").iterdir())
    assert len(bags) == 1 and (bags[0] / "metadata.yaml").is_file()


def test_replay_verifies_a_recorded_run_of_it(tmp_path):
    import subprocess
    import sys

    from attitude_sil.graph.session import run_graph

    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    bag = tmp_path / "qpd"
    run_graph(scn, duration=2.0, controller=LAW, record_dir=bag, progress=False)

    def verify(*extra):
        return subprocess.run([sys.executable, "-m", "attitude_sil.cli", "replay", str(bag), "--verify-controller",
                               *extra], cwd=ROOT, capture_output=True, text=True, timeout=120,
                              stdin=subprocess.DEVNULL)

    ok = verify()
    assert ok.returncode == 0 and ok.stdout.startswith("PASS"), ok.stdout + ok.stderr
    changed = yaml.safe_load((CONFIG / "hst_roll_step.yaml").read_text())
    changed["/**/controller"]["ros__parameters"][f"{LAW}.kd"] = [10.0, 10.0, 10.0]
    path = tmp_path / "changed.yaml"
    path.write_text(yaml.safe_dump(changed))
    bad = verify("--params", str(path))
    assert bad.returncode == 1 and bad.stdout.startswith("FAIL"), bad.stdout + bad.stderr
