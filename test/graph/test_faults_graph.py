"""A scenario's faults on the node graph: flown as the batch engine flies them, said on /diagnostics.

A wheel that seizes its drive half a second into HST's roll step: the graph's
episode equals the compiled driver's to 1e-9 (the same fault, the same
trajectory); the wheels node says the fault on ``/diagnostics`` once, at the
step it becomes active, which the bag keeps and the run, ``metrics`` and an
engine-written bag of the same episode all list alike.
"""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from attitude_sil.cli import main
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.engine_bag import record_episode
from attitude_sil.graph.session import run_graph
from attitude_sil.storage.reader import open_bag
from conftest import CONFIG

FAULT = "wheel2 stuck at 0.5"


def test_a_wheel_fault_flies_on_the_graph_as_in_the_engine_and_is_said_on_diagnostics(tmp_path, capfd):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels", faults=[FAULT])
    graph = run_graph(scn, duration=1.5, record_dir=tmp_path / "graph", keep_trajectory=True, progress=False)
    engine = simulate(scn, 1, duration=1.5, driver="compiled")
    nominal = simulate(load_scenario(CONFIG / "hst_roll_step.yaml"), 1, duration=1.5, driver="compiled")
    g = graph.trajectory
    for name in ("q_BN", "omega_BN_B", "wheel_speed"):
        assert np.max(np.abs(getattr(g, name) - getattr(engine, name))) <= 1e-9, name
    assert np.max(np.abs(engine.wheel_speed[0, -1] - nominal.wheel_speed[0, -1])) > 1e-3  # the fault acts
    assert graph.metrics["faults"] == [FAULT]

    bag = open_bag(tmp_path / "graph")
    said = list(bag.iter_decoded(["/diagnostics"]))
    assert len(said) == 1  # once, as it becomes active
    raw, msg = said[0]
    assert raw.log_time_ns == 500_000_000 and msg.header.stamp.sec == 0 and msg.header.stamp.nanosec == 500_000_000
    (status,) = msg.status
    assert status.level == ord(DiagnosticStatus.ERROR) and status.name == "wheels: wheel2"
    assert status.hardware_id == "wheel2" and status.message == f"fault: {FAULT}"
    assert {kv.key: kv.value for kv in status.values} == {"mode": "stuck", "at_s": "0.5", "for_s": "end"}

    capfd.readouterr()
    assert main(["metrics", str(tmp_path / "graph")]) == 0
    assert f"faults                   {FAULT}" in capfd.readouterr().out

    record_episode(scn, engine, tmp_path / "engine", duration=1.5)
    written = [(r.log_time_ns, _said(m)) for r, m in open_bag(tmp_path / "engine").iter_decoded(["/diagnostics"])]
    assert written == [(raw.log_time_ns, _said(msg))]  # what the wheels node published (CDR padding aside)


def _said(msg) -> tuple:
    """A DiagnosticArray's stamp and statuses, field by field."""
    return ((msg.header.stamp.sec, msg.header.stamp.nanosec),
            [(s.level, s.name, s.message, s.hardware_id, [(kv.key, kv.value) for kv in s.values])
             for s in msg.status])


def test_a_star_tracker_off_flies_on_the_graph_as_stepped_and_says_its_start_and_end(tmp_path):
    fault = "star_tracker off at 0.5 for 0.5"
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml").with_values("sensors", faults=[fault])
    graph = run_graph(scn, duration=1.5, record_dir=tmp_path / "bag", keep_trajectory=True, progress=False)
    stepped = simulate(scn, 1, duration=1.5)
    for name in ("q_BN", "q_BN_est", "attitude_sigma"):
        assert np.max(np.abs(getattr(graph.trajectory, name) - getattr(stepped, name))) <= 1e-9, name
    assert graph.metrics["faults"] == [fault]
    said = [(r.log_time_ns, [(s.level, s.name, s.message) for s in m.status])
            for r, m in open_bag(tmp_path / "bag").iter_decoded(["/diagnostics"])]
    assert said == [(500_000_000, [(ord(DiagnosticStatus.ERROR), "sensors: star_tracker", f"fault: {fault}")]),
                    (1_000_000_000, [(ord(DiagnosticStatus.OK), "sensors: star_tracker", f"fault ended: {fault}")])]
    reports = [m for _, m in open_bag(tmp_path / "bag").iter_decoded(["/star_tracker"])]
    blind = [m.header.stamp.nanosec * 1e-9 for m in reports if m.orientation_covariance[0] == -1.0]
    assert blind == pytest.approx([0.5 + 0.1 * j for j in range(5)])  # the exposures at 0.5 ... 0.9 s


def test_a_slow_star_tracker_flies_on_the_graph_as_stepped():
    # the estimator node takes each report step's message as the tracker published it, whatever its exposure:
    # here 0.3 s older than the latency from 0.5 s to 1 s, which the filter (max age 0.5 s) rolls back to
    fault = "star_tracker latency 0.3 at 0.5 for 0.5"
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml").with_values("sensors", faults=[fault]) \
        .with_values("estimator", **{"star_tracker.max_age_s": 0.5})
    graph = run_graph(scn, duration=1.5, keep_trajectory=True, progress=False)
    stepped = simulate(scn, 1, duration=1.5)
    nominal = simulate(load_scenario(CONFIG / "hst_roll_step_sensors.yaml"), 1, duration=1.5)
    for name in ("q_BN", "q_BN_est", "attitude_sigma"):
        assert np.max(np.abs(getattr(graph.trajectory, name) - getattr(stepped, name))) <= 1e-9, name
    assert np.max(np.abs(stepped.attitude_sigma - nominal.attitude_sigma)) > 1e-9  # the delay acts
    assert graph.metrics["faults"] == [fault]


def test_the_wheel_failure_preset_reallocates_on_the_graph_as_in_the_engine():
    scn = load_scenario(CONFIG / "hst_wheel_failure.yaml").with_values("wheels", reallocate_on_fault=True)
    graph = run_graph(scn, duration=3.0, keep_trajectory=True, progress=False)
    engine = simulate(scn, 1, duration=3.0, driver="compiled")
    for name in ("q_BN", "omega_BN_B", "wheel_speed"):
        assert np.max(np.abs(getattr(graph.trajectory, name) - getattr(engine, name))) <= 1e-9, name
    assert graph.metrics["faults"] == ["wheel1 lost at 2"]
    kept = simulate(scn.with_values("wheels", reallocate_on_fault=False), 1, duration=3.0, driver="compiled")
    assert np.max(np.abs(engine.q_BN - kept.q_BN)) > 1e-6  # the reallocation acted


def test_controller_output_faults_fly_on_the_graph_as_in_the_engine(tmp_path):
    faults = ["controller delay 0.2 at 0.3", "controller gain 1.5 at 0.6 for 0.5"]
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels", faults=faults)
    graph = run_graph(scn, duration=1.5, record_dir=tmp_path / "bag", keep_trajectory=True, progress=False)
    engine = simulate(scn, 1, duration=1.5, driver="compiled")
    for name in ("q_BN", "omega_BN_B", "wheel_speed"):
        assert np.max(np.abs(getattr(graph.trajectory, name) - getattr(engine, name))) <= 1e-9, name
    assert graph.metrics["faults"] == faults
    said = [(r.log_time_ns, [(s.name, s.message) for s in m.status])
            for r, m in open_bag(tmp_path / "bag").iter_decoded(["/diagnostics"])]
    assert said == [(300_000_000, [("wheels: controller", f"fault: {faults[0]}")]),
                    (600_000_000, [("wheels: controller", f"fault: {faults[1]}")]),
                    (1_100_000_000, [("wheels: controller", f"fault ended: {faults[1]}")])]


def test_the_fdir_isolates_on_the_graph_as_in_the_stepwise_driver_and_says_it(tmp_path):
    scn = load_scenario(CONFIG / "hst_wheel_failure.yaml").with_values(
        "wheels", reallocate_on_fault=True, **{"fdir.enabled": True})
    graph = run_graph(scn, duration=3.0, record_dir=tmp_path / "graph", keep_trajectory=True, progress=False)
    stepped = simulate(scn, 1, duration=3.0)
    for name in ("q_BN", "omega_BN_B", "wheel_speed"):
        assert np.max(np.abs(getattr(graph.trajectory, name) - getattr(stepped, name))) <= 1e-9, name
    k = int(np.argmax(stepped.fdir_isolated[0] > 0))
    assert stepped.fdir_isolated[0, -1] == 1 and 2.0 < stepped.t[k] < 3.0
    said = [(r.log_time_ns, _said(m)) for r, m in open_bag(tmp_path / "graph").iter_decoded(["/diagnostics"])]
    isolated = f"isolated wheel1 at {stepped.t[k]:g}; reallocated over the others"
    assert [s[1][1][0][:3] for s in said] == [
        (ord(DiagnosticStatus.ERROR), "wheels: wheel1", "fault: wheel1 lost at 2"),
        (ord(DiagnosticStatus.WARN), "wheels: fdir", isolated)]
    assert said[1][0] == int(round(stepped.t[k] * 1e9))
    record_episode(scn, stepped, tmp_path / "engine", duration=3.0)
    written = [(r.log_time_ns, _said(m)) for r, m in open_bag(tmp_path / "engine").iter_decoded(["/diagnostics"])]
    assert written == said


def test_gyro_faults_fly_on_the_graph_as_stepped_with_the_loop_on_the_estimate(tmp_path):
    faults = ["gyro.x stuck at 0.5", "gyro.y bias_jump 3600 at 0.3 for 0.5", "gyro.z spike 1 at 0.7"]
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml").with_values("sensors", faults=faults)
    graph = run_graph(scn, duration=1.5, record_dir=tmp_path / "bag", keep_trajectory=True, progress=False)
    stepped = simulate(scn, 1, duration=1.5)
    nominal = simulate(load_scenario(CONFIG / "hst_roll_step_sensors.yaml"), 1, duration=1.5)
    for name in ("q_BN", "q_BN_est", "attitude_sigma"):
        assert np.max(np.abs(getattr(graph.trajectory, name) - getattr(stepped, name))) <= 1e-9, name
    assert np.max(np.abs(stepped.q_BN - nominal.q_BN)) > 1e-7  # the faults reach the loop through the filter
    said = [(r.log_time_ns, [(s.name, s.message) for s in m.status])
            for r, m in open_bag(tmp_path / "bag").iter_decoded(["/diagnostics"])]
    assert said == [(300_000_000, [("sensors: gyro.y", f"fault: {faults[1]}")]),
                    (500_000_000, [("sensors: gyro.x", f"fault: {faults[0]}")]),
                    (700_000_000, [("sensors: gyro.z", f"fault: {faults[2]}")]),
                    (800_000_000, [("sensors: gyro.y", f"fault ended: {faults[1]}")])]
