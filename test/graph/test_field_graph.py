"""The geomagnetic field at the spacecraft on ``magnetic_field``, and the orbit on ``orbit``, in the graph.

The plant publishes both with each step's state. With an IGRF field on a
propagated orbit, the graph's field in B equals the engine's to 1e-9
relative; the orbit topic carries the propagator's position and velocity.
"""

from __future__ import annotations

import numpy as np
import pytest
import rclpy
import yaml
from rclpy.parameter import Parameter

from attitude_sil.cli import main
from attitude_sil.core.analysis.metrics import episode_report
from attitude_sil.core.sim.build import build_dipole_command, build_environment
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.errors import ScenarioError
from attitude_sil.graph.session import GraphSession, run_graph
from attitude_sil.nodes.controller_node import ControllerNode
from attitude_sil.storage.reader import open_bag
from attitude_sil.tools.verify import verify_controller
from conftest import CONFIG, start_python, stop_processes

ORBIT = {"orbit.model": "keplerian_j2", "orbit.semi_major_axis": 6.91e6, "orbit.eccentricity": 0.001,
         "orbit.inclination_deg": 51.6, "orbit.raan_deg": 120.0, "orbit.arg_perigee_deg": 0.0,
         "orbit.true_anomaly_deg": 0.0, "orbit.epoch": "2026-03-20T12:00:00Z"}


def _with_field(preset: str):
    """The preset on the orbit above, with the IGRF field."""
    scn = load_scenario(CONFIG / preset).with_values("/**", **ORBIT)
    return scn.with_values("plant", **{"environment.magnetic_field.model": "igrf"})


def _fly(scn, duration: float, **graph_options):
    """``scn`` through the graph (its trajectory kept) and through the engine: (graph run, engine trajectory)."""
    graph = run_graph(scn, duration=duration, keep_trajectory=True, progress=False, **graph_options)
    return graph, simulate(scn, 1, duration=duration)


def _assert_same(graph_tr, engine_tr, names, steps: int) -> None:
    """Each array of ``names``: ``steps`` steps (width 4 for a quaternion, else 3) in both trajectories, the graph's
    within 1e-9 of the largest engine value."""
    for name in names:
        a, b = getattr(graph_tr, name)[0], getattr(engine_tr, name)[0]
        assert a.shape == b.shape == (steps, 4 if name.startswith("q_") else 3), name
        assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(b)), name


def test_the_graph_publishes_the_field_and_the_orbit_as_the_engine_computes_them(tmp_path):
    scn = _with_field("hst_roll_step.yaml")
    graph, engine = _fly(scn, 1.0, record_dir=tmp_path / "bag")
    b_graph, b_engine = graph.trajectory.magnetic_field_B[0], engine.magnetic_field_B[0]
    assert b_graph.shape == b_engine.shape == (101, 3)
    assert np.max(np.linalg.norm(b_graph - b_engine, axis=1) / np.linalg.norm(b_engine, axis=1)) < 1e-9
    assert 1e-5 < np.linalg.norm(b_engine[0]) < 7e-5  # tesla: tens of microtesla in low Earth orbit
    # the orbit topic: the propagator's state, in the inertial frame
    orbit = build_environment(scn)[0]
    bag = open_bag(tmp_path / "bag")
    msgs = [m for _, m in bag.iter_decoded("/orbit")]
    assert len(msgs) == 101 and msgs[0].header.frame_id == "inertial"
    last = msgs[-1]
    r = np.array([last.pose.pose.position.x, last.pose.pose.position.y, last.pose.pose.position.z])
    v = np.array([last.twist.twist.linear.x, last.twist.twist.linear.y, last.twist.twist.linear.z])
    assert np.allclose(r, orbit.at(1_000_000_000).r_N, rtol=0, atol=1e-6)
    assert np.allclose(v, orbit.at(1_000_000_000).v_N, rtol=0, atol=1e-9)
    assert bag.topics["/magnetic_field"].count == 101


def test_the_magnetometer_reads_the_field_as_the_engine_does(tmp_path):
    # the sensing loop with a field: the sensors node samples the plant's magnetic_field; its readings, their
    # declared covariance and the engine's are the same numbers
    scn = _with_field("hst_roll_step_sensors.yaml")
    graph, engine = _fly(scn, 1.0, record_dir=tmp_path / "bag")
    m_graph, m_engine = graph.trajectory.magnetometer_B[0], engine.magnetometer_B[0]
    assert m_graph.shape == m_engine.shape == (101, 3)
    assert np.max(np.abs(m_graph - m_engine)) < 1e-9 * np.max(np.abs(m_engine))
    noise = m_engine - engine.magnetic_field_B[0]
    assert 10e-9 < np.std(noise) < 100e-9  # the preset's default: 50 nT per axis
    first = next(m for _, m in open_bag(tmp_path / "bag").iter_decoded("/magnetometer"))
    assert first.header.frame_id == "body"
    assert np.allclose(np.reshape(first.magnetic_field_covariance, (3, 3)), np.eye(3) * (50e-9) ** 2, rtol=1e-12)


def _dumping(preset: str):
    """The preset with the IGRF field and the cross-product law at a gain that acts within seconds."""
    return _with_field(preset).with_values("controller", **{"momentum.mode": "cross_product", "momentum.gain": 0.05})


def test_the_magnetorquers_and_the_dumping_law_fly_in_the_graph_as_in_the_stepwise_driver(tmp_path):
    scn = _dumping("hst_roll_step.yaml")
    graph, engine = _fly(scn, 1.0, record_dir=tmp_path / "bag")
    _assert_same(graph.trajectory, engine, ["q_BN", "omega_BN_B", "h_wheels_B", "dipole_cmd_B", "magnetic_torque_B"],
                 101)
    # it acted: the rods' torque is the law's dipole crossed with the field, and not nothing
    assert np.max(np.abs(engine.magnetic_torque_B)) > 1e-4
    no_dump = simulate(scn.with_values("controller", **{"momentum.mode": "none"}), 1, duration=1.0)
    assert np.max(np.abs(no_dump.h_wheels_B - engine.h_wheels_B)) > 1e-6
    bag = open_bag(tmp_path / "bag")
    assert bag.topics["/dipole_cmd"].count == bag.topics["/magnetic_torque"].count == 101
    assert "/**/magnetorquers" in bag.custom_data["attitude_sil.parameters"]
    # replay --verify-controller checks the magnetic channel too: the same law passes, another gain fails on
    # the dipole alone (the attitude law's commands do not change)
    same = verify_controller(tmp_path / "bag")
    assert same.passed and same.dipole_steps == 101 and same.dipole_deviation == 0.0, same
    other = tmp_path / "gain.yaml"
    other.write_text("/**/controller:\n  ros__parameters:\n    momentum.gain: 0.1\n")
    changed = verify_controller(tmp_path / "bag", params_file=other)
    assert not changed.passed and changed.max_deviation == 0.0 and changed.dipole_deviation > 1.0, changed


def test_with_estimate_feedback_the_dumping_law_reads_the_magnetometer(tmp_path):
    scn = _dumping("hst_roll_step_sensors.yaml").with_values("scenario", feedback="estimate")
    graph, engine = _fly(scn, 0.5)
    _assert_same(graph.trajectory, engine, ["dipole_cmd_B"], 51)
    m_engine = engine.dipole_cmd_B[0]
    # the magnetometer's, not the truth's: the law on the true field commands another dipole
    law = build_dipole_command(scn).dumping
    truth = law.dipole(engine.h_wheels_B[0], engine.magnetic_field_B[0])
    read = law.dipole(engine.h_wheels_B[0], engine.magnetometer_B[0])
    np.testing.assert_array_equal(m_engine, read)
    assert np.max(np.abs(truth - m_engine)) > 0.0


def test_bdot_detumbles_in_the_graph_as_in_the_stepwise_driver():
    # the cube on B-dot at k* (the runner fills the gain in): trajectories and the run's figures the same
    scn = load_scenario(CONFIG / "cubesat_1u_detumble.yaml")
    graph, engine = _fly(scn, 3.0)
    _assert_same(graph.trajectory, engine, ["omega_BN_B", "dipole_cmd_B", "magnetic_torque_B", "h_wheels_B"], 31)
    assert np.max(np.abs(engine.dipole_cmd_B)) > 0.01  # A m^2: it acts
    assert np.array_equal(engine.u_cmd, np.zeros_like(engine.u_cmd))  # the wheels idle
    figures = ("detumble_time_s", "wheel_momentum_peak_Nms", "wheel_momentum_final_Nms", "dipole_effort_Am2s")
    report = episode_report(scn, engine, "bdot", 3.0, 1.0)
    assert report["detumble_time_s"] is None and report["dipole_effort_Am2s"] > 0.0
    for key in figures:  # the graph's running figures against the engine trajectory's
        expected = None if report[key] is None else pytest.approx(report[key], rel=1e-9, abs=1e-15)
        assert graph.metrics[key] == expected, key


def test_the_residual_dipole_is_a_disturbance_in_the_field_in_graph_and_engine():
    scn = _with_field("hst_roll_step.yaml").with_values(
        "disturbance", models=["residual_dipole"], **{"residual_dipole.moment": [2.0, -1.0, 3.0]})
    graph, engine = _fly(scn, 1.0)
    tau, b = engine.tau_ext_B[0], engine.magnetic_field_B[0]
    np.testing.assert_array_equal(tau, np.cross([2.0, -1.0, 3.0], b))  # m_res x B, the plant's field
    _assert_same(graph.trajectory, engine, ["tau_ext_B"], 101)
    # per episode (what Monte Carlo disperses): each episode its own moment
    both = simulate(scn, 2, duration=0.1, episode_values={"disturbance.residual_dipole.moment": [[1, 0, 0], [0, 0, 5]]})
    np.testing.assert_array_equal(both.tau_ext_B[1], np.cross([0.0, 0.0, 5.0], both.magnetic_field_B[1]))
    with pytest.raises(ScenarioError, match="residual_dipole needs the geomagnetic field"):
        simulate(scn.with_values("plant", **{"environment.magnetic_field.model": "none"}), 1, duration=0.1)


def test_a_swap_to_bdot_where_the_magnetorquers_do_not_fly_is_refused():
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = ControllerNode(context=context)  # the defaults: no magnetorquers
        (refused,) = node.set_parameters([Parameter("controller_type", value="bdot")])
        assert not refused.successful and "does not fly" in refused.reason
        (taken,) = node.set_parameters([Parameter("controller_type", value="ga_flc")])
        assert taken.successful and node.param("controller_type") == "ga_flc"
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_second_episode_of_the_same_graph_flies_the_first_again():
    # B-dot's previous field direction and the controller's half-gathered momentum inputs start afresh at each
    # episode: two episodes of one graph (the tuner's and Monte Carlo's graph mode) give the same trajectory
    scn = load_scenario(CONFIG / "cubesat_1u_detumble.yaml")
    with GraphSession(scn, duration=1.0) as graph:
        first, second = (graph.run_episode(keep_trajectory=True).trajectory for _ in range(2))
    for name in ("omega_BN_B", "dipole_cmd_B", "magnetic_torque_B"):
        a, b = getattr(first, name), getattr(second, name)
        assert a.shape == b.shape == (1, 11, 3), name
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert np.max(np.abs(first.dipole_cmd_B)) > 0.01


def test_hawaiisat_on_its_rods_flies_in_the_graph_as_in_the_stepwise_driver(tmp_path):
    # the geometric law's torque demand made by the rods (torque_actuator magnetorquers), no wheels: the
    # demand on torque_cmd, the dipole, the rods' torque and the attitude the same; Ce counts the rods' torque
    scn = load_scenario(CONFIG / "hawaiisat_lvlh_magnetic.yaml")
    graph, engine = _fly(scn, 1.0, record_dir=tmp_path / "bag")
    _assert_same(graph.trajectory, engine, ["q_BN", "omega_BN_B", "u_cmd", "dipole_cmd_B", "magnetic_torque_B"], 51)
    assert np.max(np.abs(engine.magnetic_torque_B)) > 1e-4  # N m: the rods act
    assert not np.any(engine.tau_c_B) and not np.any(engine.h_wheels_B)  # nothing else does
    report = episode_report(scn, engine, "geometric", 1.0, 1.0)
    assert report["control_effort_Nms"] > 1e-4
    assert graph.metrics["control_effort_Nms"] == pytest.approx(report["control_effort_Nms"], rel=1e-9)
    verified = verify_controller(tmp_path / "bag")  # the demand and its dipole
    assert verified.passed and verified.steps == verified.dipole_steps == 51, verified


def test_record_takes_the_magnetorquers_parameters_into_its_snapshot(tmp_path, capfd):
    # a hand-started graph with its rods (as the launch file starts it: magnetorquers true on the plant and the
    # controller): record asks the magnetorquers node too, so the bag keeps HST's 3,600 A m^2 bars
    preset = CONFIG / "hst_momentum_dump.yaml"
    over = tmp_path / "over.yaml"
    over.write_text("/**/plant:\n  ros__parameters:\n    duration: 2.0\n    magnetorquers: true\n"
                    "/**/controller:\n  ros__parameters:\n    magnetorquers: true\n")
    names = ("plant", "wheels", "disturbance", "guidance", "controller", "magnetorquers")
    procs = [start_python(["-m", f"attitude_sil.nodes.{n}_node", "--ros-args", "--params-file", str(preset),
                           "--params-file", str(over)]) for n in names]
    rec = start_python(["-m", "attitude_sil.cli", "record", str(tmp_path / "bag"), "--episode"])
    try:
        seen = ""
        while "parameter snapshot" not in seen:  # the recorder has the graph's parameters
            line = rec.stderr.readline()
            assert line, seen
            seen += line
        assert "magnetorquers" in seen.splitlines()[-1], seen
        assert main(["episode", "--json", "--quiet", "--scenario", str(preset)]) == 0
        assert rec.wait(timeout=120) == 0, rec.stderr.read()
    finally:
        stop_processes(procs + [rec])
    snapshot = yaml.safe_load(open_bag(tmp_path / "bag").custom_data["attitude_sil.parameters"])
    assert snapshot["/**/magnetorquers"]["ros__parameters"]["rods.max_dipole"] == 3600.0


def test_a_magnetorquers_fault_flies_in_the_graph_as_in_the_stepwise_driver(tmp_path):
    faults = ["magnetorquers stuck at 0.5 for 1", "magnetorquers off at 2"]
    scn = load_scenario(CONFIG / "cubesat_1u_detumble.yaml").with_values("magnetorquers", faults=faults)
    graph, engine = _fly(scn, 3.0, record_dir=tmp_path / "bag")
    _assert_same(graph.trajectory, engine, ["omega_BN_B", "dipole_cmd_B", "magnetic_torque_B"], 31)
    assert np.all(engine.magnetic_torque_B[0, 20:] == 0.0) and np.any(engine.magnetic_torque_B[0, :20] != 0.0)
    said = [(r.log_time_ns, [s.message for s in m.status])
            for r, m in open_bag(tmp_path / "bag").iter_decoded(["/diagnostics"])]
    assert said == [(500_000_000, [f"fault: {faults[0]}"]), (1_500_000_000, [f"fault ended: {faults[0]}"]),
                    (2_000_000_000, [f"fault: {faults[1]}"])]
