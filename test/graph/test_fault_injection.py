"""Faults injected while a graph runs (``attitude-sil fault``): taken from the next step, as the engine flies
the same fault from that time; refused in one line where they cannot fly."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from attitude_sil.cli import main
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.storage.cdr import stamped_values
from attitude_sil.storage.reader import open_bag
from conftest import CONFIG, ROOT
from conftest import stop_processes as _stop


def test_the_wheels_node_takes_added_faults_and_refuses_what_cannot_fly():
    from attitude_sil.nodes.wheels_node import WheelsNode

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = WheelsNode(context=context)
        for faults, words in ((["magnetorquers off at 1"], "flown by the magnetorquers node, not the wheels"),
                              (["wheel9 lost"], "the geometry has wheels 1..4"),
                              (["star_tracker off at 1"], "flown by the sensors node, not the wheels")):
            (result,) = node.set_parameters([Parameter("faults", value=faults)])
            assert not result.successful and words in result.reason, result.reason
        assert node.core.failure is None
        (result,) = node.set_parameters([Parameter("faults", value=["wheel2 stuck"])])
        assert result.successful, result.reason
        wheel, step, mode, _ = node.core.failure
        assert (wheel[0], step[0], mode[0]) == (1, 1, 1)  # stuck (code 1), from the step after the one in hand
        assert [str(f) for f in node.faults.faults] == ["wheel2 stuck at 0.01"]
        for faults, words in (([], "not taken back or changed: 'wheel2 stuck' is gone"),
                              (["wheel2 stuck", "wheel3 lost at 1"], "one wheel fault per run")):
            (result,) = node.set_parameters([Parameter("faults", Parameter.Type.STRING_ARRAY, faults)])
            assert not result.successful and words in result.reason, result.reason
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_the_wheels_node_takes_an_added_output_delay_reading_the_last_command_before_it():
    from attitude_sil.nodes.wheels_node import WheelsNode

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = WheelsNode(context=context)
        for k in range(3):  # three steps flown, the last with the command (3, 2, 3) V
            node.core.advance(np.array([[k + 1.0, 2.0, 3.0]]))
        (result,) = node.set_parameters([Parameter("faults", value=["controller delay 0.015"])])
        assert not result.successful and "not a whole number of 0.01 s control steps" in result.reason
        (result,) = node.set_parameters([Parameter("faults", value=["controller delay 0.05"])])
        assert result.successful, result.reason
        cf = node.core.command_fault
        assert (cf.delay[0], cf.delay_from[0]) == (5, 4)  # from the step after the one in hand (k = 3)
        assert [str(f) for f in node.faults.faults] == ["controller delay 0.05 at 0.04"]
        (result,) = node.set_parameters([Parameter("faults", value=["controller delay 0.05", "controller gain 2"])])
        assert result.successful, result.reason
        assert node.core.command_fault.gain_from[0] == 4 and node.core.command_fault is not cf
        np.testing.assert_array_equal(node.core.command_fault.held, [[3.0, 2.0, 3.0]])  # the last one applied
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def _wait_for_clock(t_ns: int, timeout: float) -> None:
    """Until the graph's /clock has reached ``t_ns`` (its transient-local history read by a node of our own)."""
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = rclpy.create_node("clock_watch", context=context)
        seen = []
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Clock, "/clock", lambda m: seen.append(m.clock.sec * 10**9 + m.clock.nanosec), qos)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + timeout
        while not (seen and seen[-1] >= t_ns):
            assert time.monotonic() < deadline, f"no /clock {t_ns} ns within {timeout} s (seen {seen[-1:]})"
            executor.spin_once(timeout_sec=0.1)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_fault_given_to_a_held_graph_flies_from_the_next_step_as_the_engine_flies_it(tmp_path, capfd):
    params = tmp_path / "hold.yaml"
    params.write_text("/**/plant:\n  ros__parameters:\n    hold_at: 1.0\n    input_timeout: 120.0\n")
    cmd = [sys.executable, "-m", "attitude_sil.cli"]
    run = subprocess.Popen([*cmd, "run", str(CONFIG / "hst_roll_step.yaml"), "--duration", "2", "--params",
                            str(params), "--record", str(tmp_path / "bag"), "--quiet"], cwd=ROOT,
                           stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           start_new_session=True)
    fault = None
    try:
        _wait_for_clock(990_000_000, 120.0)  # the plant holds before step t = 1.0: 0.99 s is the last /clock
        fault = subprocess.Popen([*cmd, "fault", "wheel2", "stuck", "--timeout", "60"], cwd=ROOT,
                                 stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 start_new_session=True)
        deadline = time.monotonic() + 60.0
        while True:  # the wheels node has the fault (asked by condition), then the hold is released
            capfd.readouterr()
            assert main(["param", "get", "/wheels", "faults"]) == 0
            if "wheel2 stuck at " in capfd.readouterr().out:  # at the latest /clock it read (0.99 s)
                break
            assert time.monotonic() < deadline and fault.poll() is None, fault.stderr.read() if fault.poll() else ""
        assert main(["param", "set", "/plant", "hold_at", "-1.0"]) == 0
        out, err = fault.communicate(timeout=90)
        assert fault.returncode == 0, err
        assert out.strip() == "wheel2 stuck at 1.01: active (on /wheels, said on /diagnostics)", out
        _, err = run.communicate(timeout=120)
        assert run.returncode == 0, err
    finally:
        _stop([p for p in (run, fault) if p is not None])
    bag = open_bag(tmp_path / "bag")
    said = [(r.log_time_ns, [s.message for s in m.status]) for r, m in bag.iter_decoded(["/diagnostics"])]
    assert said == [(1_010_000_000, ["fault: wheel2 stuck at 1.01"])]
    q_graph = np.array([stamped_values(m.data, 4) for m in bag.iter_raw("/attitude")])
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels", faults=["wheel2 stuck at 1.01"])
    engine = simulate(scn, 1, duration=2.0, driver="compiled")
    assert q_graph.shape == engine.q_BN[0].shape and np.max(np.abs(q_graph - engine.q_BN[0])) <= 1e-9
    nominal = simulate(load_scenario(CONFIG / "hst_roll_step.yaml"), 1, duration=2.0, driver="compiled")
    assert np.max(np.abs(engine.wheel_speed[0, -1] - nominal.wheel_speed[0, -1])) > 1e-3  # the fault acted


def test_the_sensors_node_takes_an_added_star_tracker_outage_from_its_next_step():
    from attitude_sil.nodes.sensors_node import SensorsNode

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = SensorsNode(context=context)
        node.k = 149  # as if it had sampled step 149 (t = 1.49 s)
        (result,) = node.set_parameters([Parameter("faults", value=["star_tracker off at 1 for 2"])])
        assert result.successful, result.reason
        assert node.core.star_tracker.errors.outages == ((1.5, 3.5),)  # from the next step, for its 2 s
        assert [str(f) for f in node.faults.faults] == ["star_tracker off at 1.5 for 2"]
        assert node.core.star_tracker.in_outage(150) and not node.core.star_tracker.in_outage(350)
        (result,) = node.set_parameters([Parameter("faults", value=["star_tracker off at 1 for 2",
                                                                 "star_tracker latency 0.005 at 1"])])
        assert not result.successful and "not a whole number of control steps" in result.reason, result.reason
        faults = ["star_tracker off at 1 for 2", "gyro.x stuck at 0.2"]
        (result,) = node.set_parameters([Parameter("faults", value=faults)])
        assert result.successful, result.reason
        fault, start, end = node.core.gyro.faults[-1]
        assert (fault.mode, start, end) == ("stuck", 150, np.iinfo(np.int64).max)  # from the next step on
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def _status(t_ns: int, *said: tuple[str, bytes]):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    msg = DiagnosticArray(status=[DiagnosticStatus(level=level, hardware_id=hw) for hw, level in said])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
    return msg


def test_the_wheels_node_takes_a_wheel_status_after_its_stamp_and_checks_it_as_a_parameter_set():
    from diagnostic_msgs.msg import DiagnosticStatus

    from attitude_sil.nodes.wheels_node import WheelsNode

    error, ok = DiagnosticStatus.ERROR, DiagnosticStatus.OK
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = WheelsNode(context=context)
        node._on_wheel_status(_status(20_000_000, ("wheel1", error)))
        node._take_declared(20_000_000)  # the command of the declaration's own step: not yet
        assert node.param("available") == []
        node._take_declared(30_000_000)
        assert node.param("available") == [2, 3, 4]
        node._on_wheel_status(_status(30_000_000, ("wheel2", error)))  # two of four left: no three axes
        node._take_declared(40_000_000)
        assert node.param("available") == [2, 3, 4]
        node._on_wheel_status(_status(40_000_000, ("wheel1", ok), ("wheel3", error)))  # wheel 1 back, 3 out
        node._take_declared(50_000_000)
        assert node.param("available") == [1, 2, 4]
        node._on_wheel_status(_status(50_000_000, ("wheel9", error)))  # no such wheel: ignored in one line
        node._take_declared(60_000_000)
        assert node.param("available") == [1, 2, 4] and not node.declared
        node._on_wheel_status(_status(60_000_000, *((f"wheel{i}", error) for i in (1, 2, 4))))  # none left
        node._take_declared(70_000_000)
        assert node.param("available") == [1, 2, 4]  # refused ([] would be every wheel)
        node._on_wheel_status(_status(0, ("wheel2", error)))
        node._on_wheel_status(_status(70_000_000, ("wheel4", error)))
        node.rebuild()  # a new episode: its first step's declaration stays, the past one's goes
        assert [d[0] for d in node.declared] == [0]
        assert node.param("available") == []  # and the set is the one before the declarations: every wheel
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
