"""Flight software on its own timer: ``run --external controller --external-timing sim_timer | wall``.

The node is ``examples/external_controller/timer_controller.py``: it caches
its newest ``attitude`` and ``attitude_setpoint`` and computes paper 000's PID
on ``create_timer``, stamping with ``now()``, the same code on sim time and
on the wall clock.

On sim time the run is checked against a reference of its own kind: the same
episode stepped here with the package's core models and the example's own
``Pid``, under the rule the guide states (a tick at t_j reads the state and
setpoint of t_j; its command acts over [t_j + T, t_j + 2 T), zero before).
That the graph matches it to 1e-12, at the control rate and at 10 Hz on the
100 Hz plant, shows each tick read the inputs of its own time and its command
went in one period later; two runs in a row match bit for bit.
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from attitude_sil.cli import main
from attitude_sil.core.sim.build import build_disturbance, build_guidance, build_plant, build_wheels
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.errors import RunError
from attitude_sil.graph.session import command_period_of, run_graph
from attitude_sil.storage.cdr import stamp_from_cdr, stamped_values
from attitude_sil.storage.reader import open_bag
from conftest import CONFIG, ROOT
from conftest import start_python as _start
from conftest import stop_processes as _stop

SCENARIO = CONFIG / "hst_roll_step.yaml"
EXAMPLES = ROOT / "examples" / "external_controller"
TIMER = EXAMPLES / "timer_controller.py"

def _example(name: str):
    """An example module by its file (not a package: it is loaded, not imported)."""
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


PID = _example("pid_controller")  # the example's own law, for the reference
HST_GA_GAINS, Pid = PID.HST_GA_GAINS, PID.Pid

OUTPUT_LIMIT = 314.79  # V, the example's default


def vectors(bag, topic: str) -> list[tuple[int, np.ndarray]]:
    """(header stamp ns, (3,) values) of each message of a Vector3Stamped topic of ``bag``."""
    return [(stamp_from_cdr(m.data), stamped_values(m.data, 3)) for m in bag.iter_raw(topic)]


def let_reference(scn, duration: float, period_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The episode under logical execution time, stepped with the core models: (q_BN (K+1, 4), command (K+1, 3))."""
    dt_ns = int(round(scn.dt * 1e9))
    period_ns = period_steps * dt_ns
    plant, wheels = build_plant(scn, 1), build_wheels(scn, 1)
    disturbance, guidance = build_disturbance(scn, 1), build_guidance(scn, 1)
    law, ticks = Pid(), {}
    gains = {name: [value] * 3 for name, value in HST_GA_GAINS.items()}
    steps = int(round(duration / scn.dt))
    q_out, u_out = [], []
    for k in range(steps + 1):
        t_ns = k * dt_ns
        q_BN = plant.state.q_BN
        q_RN, _ = guidance.setpoint(t_ns * 1e-9)
        if t_ns > 0 and t_ns % period_ns == 0:  # a tick reads the inputs of its own time
            ticks[t_ns] = law.step(tuple(q_BN[0]), tuple(q_RN[0]), gains, OUTPUT_LIMIT, period_ns * 1e-9)
        u = np.array([ticks.get((t_ns // period_ns - 1) * period_ns, (0.0, 0.0, 0.0))])  # one period later
        q_out.append(q_BN[0].copy())
        u_out.append(u[0])
        out = wheels.advance(u, False)
        if k < steps:
            plant.advance(out.tau_c_B, out.h_wheels_B, disturbance.torque(q_BN, t_ns))
    return np.array(q_out), np.array(u_out)


def test_a_sim_time_timer_node_flies_in_lockstep_deterministically(tmp_path):
    scn = load_scenario(SCENARIO).with_values("wheels", command_timing="sim_timer")
    node = _start([str(TIMER), "--ros-args", "-p", "use_sim_time:=true"])
    try:
        first = run_graph(scn, duration=2.0, external=("controller",), record_dir=tmp_path / "bag",
                          keep_trajectory=True, progress=False)
        second = run_graph(scn, duration=2.0, external=("controller",), keep_trajectory=True, progress=False)
    finally:
        assert _stop([node]) == [0], node.stderr.read()
    q_ref, u_ref = let_reference(scn, 2.0, 1)
    tr = first.trajectory
    assert tr.q_BN.shape[1] == len(q_ref) == 201
    assert np.max(np.abs(tr.u_cmd[0] - u_ref)) <= 1e-12
    assert np.max(np.abs(tr.q_BN[0] - q_ref)) <= 1e-12
    for key, value in first.metrics.items():  # bit for bit, run after run (wall-clock figures aside)
        if key not in ("wall_time_s", "real_time_factor", "bag") and not key.startswith("controller_latency"):
            assert value == second.metrics[key], key
    m = first.metrics
    assert m["command_timing"] == "sim_timer" and m["command_period_ms"] == pytest.approx(10.0)
    assert m["command_delay_ms"] == pytest.approx(10.0)  # the one-period computation delay
    assert 0.0 < m["controller_latency_mean_ms"] <= m["controller_latency_max_ms"]
    bag = open_bag(tmp_path / "bag")
    assert bag.topics["/voltage_cmd"].count == 200  # one per tick: t = 10 ms ... 2 s
    assert bag.topics["/applied/voltage_cmd"].count == 201  # one per step, what the wheels held


def test_a_10_hz_flight_computer_on_the_100_hz_plant(tmp_path, capfd):
    scn = load_scenario(SCENARIO)
    node = _start([str(TIMER), "--ros-args", "-p", "use_sim_time:=true", "-p", "rate:=10.0"])
    try:
        capfd.readouterr()
        code = main(["run", str(SCENARIO), "--external", "controller", "--external-timing", "sim_timer",
                     "--external-rate", "10", "--duration", "3", "--record", str(tmp_path / "bag"), "--quiet"])
        out = capfd.readouterr().out
        again = run_graph(scn.with_values("wheels", command_timing="sim_timer", command_rate=10.0), duration=3.0,
                          external=("controller",), keep_trajectory=True, progress=False)
    finally:
        _stop([node])
    assert code == 0
    assert "controller period        100 ms" in out and "command delay (sim)      100 ms" in out
    # each tick read the state of its own time, 10 plant steps apart, and its command acted one period later:
    # the reference says so to 1e-12, in both runs
    q_ref, u_ref = let_reference(scn, 3.0, 10)
    bag = open_bag(tmp_path / "bag")
    q_bag = np.array([stamped_values(m.data, 4) for m in bag.iter_raw("/attitude")])
    assert q_bag.shape == q_ref.shape and np.max(np.abs(q_bag - q_ref)) <= 1e-12
    assert np.max(np.abs(again.trajectory.q_BN[0] - q_ref)) <= 1e-12
    assert np.max(np.abs(again.trajectory.u_cmd[0] - u_ref)) <= 1e-12
    # the bag shows the hold: each applied command is the tick's one period before, held for the whole period
    ticks = dict(vectors(bag, "/voltage_cmd"))
    assert sorted(ticks) == [j * 100_000_000 for j in range(1, 31)]
    for t, v in vectors(bag, "/applied/voltage_cmd"):
        assert np.array_equal(v, ticks.get((t // 100_000_000 - 1) * 100_000_000, np.zeros(3))), t


def test_a_wall_clock_timer_node_flies_at_real_time(tmp_path):
    scn = load_scenario(SCENARIO).with_values("wheels", command_timing="wall")
    node = _start([str(TIMER)])
    try:
        result = run_graph(scn, duration=1.0, external=("controller",), real_time=True,
                           record_dir=tmp_path / "bag", progress=False)
    finally:
        _stop([node])
    m = result.metrics
    assert m["command_timing"] == "wall" and m["command_count"] > 0
    assert isinstance(m["command_stale_steps"], int) and isinstance(m["command_missed_periods"], int)
    assert 0.0 < m["controller_latency_mean_ms"] <= m["controller_latency_max_ms"]
    assert math.isfinite(m["iae"])
    # what the wheels applied is a command the node sent (or zero before its first): sample and hold
    bag = open_bag(tmp_path / "bag")
    sent = {tuple(v) for _, v in vectors(bag, "/voltage_cmd")} | {(0.0, 0.0, 0.0)}
    applied = [tuple(v) for _, v in vectors(bag, "/applied/voltage_cmd")]
    assert len(applied) == 101 and set(applied) <= sent


def test_a_timer_node_on_the_wrong_clock_is_named_at_the_stall(capfd):
    # the node on the wall clock, run as sim_timer: its wall stamps are no ticks; the run ends at the plant's
    # timeout with one line naming the controller, its topic, what came instead and what to check
    scn = load_scenario(SCENARIO).with_values("wheels", command_timing="sim_timer").with_values(
        "plant", input_timeout=2.0)
    node = _start([str(TIMER)])
    try:
        with pytest.raises(RunError) as err:
            run_graph(scn, duration=1.0, external=("controller",), progress=False)
    finally:
        _stop([node])
    line = str(err.value)
    assert "\n" not in line
    assert "the controller sent no voltage_cmd or torque_cmd or wheel_cmd stamped 0.010000 s" in line, line
    assert "use_sim_time" in line and "--external-rate" in line, line
    # and the refused stamps (the recorder's count, in the line: none if the node, slow to start on a loaded
    # machine, sent nothing within the timeout) got the wheels' throttled line naming the tick expected
    err = capfd.readouterr().err
    if "message(s) refused" in line:
        assert "refused (not a tick of the controller's period 0.01 s); expected 0.010000 s" in err, err


@pytest.mark.parametrize("args, words", [
    (["--external-timing", "sim_timer"], "add --external controller"),
    (["--external", "controller", "--external-timing", "wall"], "add --real-time"),
    (["--external", "controller", "--external-timing", "sim_timer", "--external-rate", "30"],
     "not a whole number of control periods"),
    (["--external", "controller", "--external-rate", "10"], "goes with --external-timing sim_timer or wall"),
    (["--external", "controller", "--external", "guidance", "--external-timing", "sim_timer"],
     "leave out --external guidance"),
    (["--external", "controller", "--external-timing", "sim_timer", "--processes"], "leave out --processes"),
])
def test_timing_flags_that_cannot_fly_are_one_line_errors(args, words, capfd):
    assert main(["run", str(SCENARIO), "--no-record", "--quiet", *args]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and words in err, err


def test_sim_timer_refuses_the_sensing_loop_in_one_line(capfd):
    # its topics are not ordered before a tick's /clock: refused rather than flown non-deterministically
    sensors = str(CONFIG / "hst_roll_step_sensors.yaml")
    assert main(["run", sensors, "--no-record", "--quiet", "--external", "controller", "--external-timing",
                 "sim_timer"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and "does not order the sensing loop's topics" in err, err


def test_a_wall_clock_rate_needs_no_whole_number_of_steps():
    # only a sim-time timer must meet the plant's steps; a wall-clock one's rate sets the missed-period count
    scn = load_scenario(SCENARIO).with_values("wheels", command_timing="wall", command_rate=30.0)
    assert command_period_of(scn) == 33_333_333
    with pytest.raises(ValueError, match="not a whole number of control periods"):
        command_period_of(scn.with_values("wheels", command_timing="sim_timer"))


DROPS_A_CLOCK = """
import sys
import rclpy
from geometry_msgs.msg import Vector3Stamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
rclpy.init()
node = rclpy.create_node("my_controller")
pub = node.create_publisher(Vector3Stamped, "voltage_cmd", 10)
seen = set()
def on_clock(msg):
    t = msg.clock.sec * 10**9 + msg.clock.nanosec
    if t == 10_000_000 and t not in seen:  # the tick at 10 ms lost once, as a best-effort reader can lose it
        seen.add(t)
        print("dropped", file=sys.stderr, flush=True)
        return
    if t > 0:  # a tick at every step: zero volts stamped with it
        cmd = Vector3Stamped()
        cmd.header.stamp = msg.clock
        cmd.header.frame_id = "body"
        pub.publish(cmd)
node.create_subscription(Clock, "/clock", on_clock, QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
try:
    rclpy.spin(node)
except BaseException:
    pass
"""


def test_a_lost_clock_of_a_tick_is_sent_again():
    # a sim-time timer reads /clock best effort (rclpy's TimeSource): a /clock lost is a tick that never fires.
    # The plant sends a waiting step's /clock again, so the episode goes on instead of stopping at its timeout
    scn = load_scenario(SCENARIO).with_values("wheels", command_timing="sim_timer")
    node = _start(["-c", DROPS_A_CLOCK])
    try:
        result = run_graph(scn, duration=0.1, external=("controller",), progress=False)
    finally:
        _stop([node])
        err = node.stderr.read()
    assert "dropped" in err, err
    assert result.metrics["sim_time_s"] == pytest.approx(0.1)


def test_a_timer_that_missed_the_jump_back_to_0_is_brought_back_in_phase(tmp_path, capfd):
    # a new episode sends /clock back to 0; a sim-time reader that loses that 0 (depth 1, best effort) first sees a
    # later time t_s, and rcl restarts its timer from there: it would tick at t_s + T, never at the tick T the
    # wheels wait for. The relay loses the 0 every time; the plant sends /clock 0 again at the unanswered first
    # tick, and the second episode matches the reference as the first does, its bag one /clock a step
    scn = load_scenario(SCENARIO).with_values("wheels", command_timing="sim_timer", command_rate=10.0)
    relay = _start([str(ROOT / "test" / "graph" / "lossy_clock.py"), "0.1"])
    node = _start([str(TIMER), "--ros-args", "-p", "use_sim_time:=true", "-p", "rate:=10.0",
                   "-r", "/clock:=/lossy_clock"])
    try:
        first = run_graph(scn, duration=1.0, external=("controller",), keep_trajectory=True, progress=False)
        capfd.readouterr()
        second = run_graph(scn, duration=1.0, external=("controller",), record_dir=tmp_path / "bag",
                           keep_trajectory=True, progress=False)
        err = capfd.readouterr().err
    finally:
        assert _stop([node, relay]) == [0, 0], node.stderr.read() + relay.stderr.read()
    assert "sending /clock 0 again" in err, err
    q_ref, u_ref = let_reference(scn, 1.0, 10)
    for run in (first, second):
        assert np.max(np.abs(run.trajectory.q_BN[0] - q_ref)) <= 1e-12
        assert np.max(np.abs(run.trajectory.u_cmd[0] - u_ref)) <= 1e-12
    bag = open_bag(tmp_path / "bag")
    assert [stamp_from_cdr(m.data) for m in bag.iter_raw("/clock")] == [k * 10_000_000 for k in range(101)]
    assert sorted(t for t, _ in vectors(bag, "/voltage_cmd")) == [j * 100_000_000 for j in range(1, 11)]


def test_the_example_computes_a_tick_once_and_sends_its_command_again():
    # after the plant's /clock 0 of an unanswered first tick, a node in phase ticks at that time again: the
    # example sends the command it computed, its law stepped once (the run stays reproducible)
    import sys

    import rclpy
    from rclpy.time import Time

    sys.path.insert(0, str(EXAMPLES))  # the example imports its sibling pid_controller
    try:
        timer = _example("timer_controller")
    finally:
        sys.path.remove(str(EXAMPLES))
    started = not rclpy.ok()  # the example's node takes the default context, as the example's main() does
    if started:
        rclpy.init(args=[])
    try:
        node = timer.TimerController()
        sent, steps = [], []
        node.pub.publish = sent.append
        law_step = node.law.step
        node.law.step = lambda *a: steps.append(a) or law_step(*a)
        node.q_BN, node.q_RN = (0.0, 0.0, 0.0, 1.0), (0.00872654, 0.0, 0.0, 0.99996192)
        clock = [Time(nanoseconds=100_000_000)]
        node.get_clock = lambda: type("Clock", (), {"now": lambda self: clock[0]})()
        node.tick()
        node.tick()  # the same tick again
        assert len(steps) == 1 and len(sent) == 2 and sent[0] is sent[1]
        clock[0] = Time(nanoseconds=200_000_000)
        node.tick()
        assert len(steps) == 2 and sent[2] is not sent[1]
        node.destroy_node()
    finally:
        if started:
            rclpy.shutdown()
