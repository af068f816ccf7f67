"""Bag commands end to end: replay into a live controller, verify-controller, info, plot, integrity."""

import subprocess
import sys
import threading

import numpy as np
import pytest
import yaml

from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.session import run_graph
from attitude_sil.storage.reader import open_bag
from attitude_sil.tools.plot import controller_swaps, effective_swaps
from attitude_sil.tools.replay import ReplayOptions, replay_bag
from conftest import CONFIG, ROOT


def cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "attitude_sil.cli", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL)


@pytest.fixture(scope="module")
def swap_bag(tmp_path_factory):
    """A 4 s HST run that swaps from PID to the hybrid fuzzy PID at 2 s, recorded."""
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values(
        "scenario", **{"schedule.times": [2.0], "schedule.controller_types": ["fuzzy_pid"]})
    bag = tmp_path_factory.mktemp("bags") / "swap"
    run_graph(scn, duration=4.0, record_dir=bag, progress=False)
    return bag


def _recorded(bag, topic):
    reader = open_bag(bag)
    return {raw.log_time_ns: np.array([m.vector.x, m.vector.y, m.vector.z])
            for raw, m in reader.iter_decoded(topics=[reader.find_topic(topic)])}


def test_replay_drives_a_live_controller_like_the_recorded_run(tmp_path):
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.experimental import EventsExecutor

    from attitude_sil.core.sim.params import spec_for
    from attitude_sil.nodes.controller_node import ControllerNode
    from attitude_sil.ros.convert import stamp_to_ns, vector_to_array
    from attitude_sil.ros.parameters import typed_parameter
    from attitude_sil.ros.qos import LOCKSTEP_QOS

    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    bag = tmp_path / "plain"
    run_graph(scn, duration=3.0, record_dir=bag, progress=False)
    recorded = _recorded(bag, "voltage_cmd")
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    got = {}
    stop = threading.Event()
    spinner = executor = ctrl = listener = None
    try:
        overrides = [typed_parameter(spec_for("controller", k), v) for k, v in scn.values["controller"].items()
                     if v != []]
        ctrl = ControllerNode(context=context, parameter_overrides=overrides)
        listener = rclpy.create_node("listener", context=context)
        all_in = threading.Event()

        def on_command(m):
            got[stamp_to_ns(m.header.stamp)] = vector_to_array(m)
            if len(got) >= len(recorded):
                all_in.set()

        listener.create_subscription(Vector3Stamped, "voltage_cmd", on_command, LOCKSTEP_QOS)
        executor = EventsExecutor(context=context)
        executor.add_node(ctrl)
        executor.add_node(listener)
        spinner = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.05) for _ in iter(stop.is_set,
                                                                                                       True)])
        spinner.start()
        sent = replay_bag(bag, ReplayOptions(rate=0.0, topics=["attitude", "body_rate", "attitude_setpoint",
                                                                "rate_setpoint"], wait_for_subscribers=1),
                          context=context)
        assert sent == 4 * 301
        all_in.wait(timeout=120)  # the spinner thread collects the commands; woken by the last one
    finally:
        stop.set()
        spinner.join()
        executor.shutdown()
        ctrl.destroy_node()
        listener.destroy_node()
        rclpy.try_shutdown(context=context)
    assert sorted(got) == sorted(recorded)
    assert max(np.max(np.abs(got[t] - recorded[t])) for t in recorded) <= 1e-12


def test_verify_controller_passes_unchanged_and_fails_on_a_changed_gain(swap_bag, tmp_path):
    ok = cli("replay", str(swap_bag), "--verify-controller")
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert ok.stdout.startswith("PASS") and "1 recorded parameter change(s) applied" in ok.stdout
    changed = yaml.safe_load((CONFIG / "hst_roll_step.yaml").read_text())
    changed["/**/controller"]["ros__parameters"]["fuzzy_pid.kd"] = [90.0, 90.0, 90.0]
    path = tmp_path / "changed.yaml"
    path.write_text(yaml.safe_dump(changed))
    bad = cli("replay", str(swap_bag), "--verify-controller", "--params", str(path))
    assert bad.returncode == 1 and bad.stdout.startswith("FAIL")
    # the change only acts after the swap at 2 s
    worst_t = float(bad.stdout.split("at t=")[1].split(" s")[0])
    assert worst_t >= 2.0


def test_bag_info_and_plot_show_the_swap(swap_bag, tmp_path):
    info = cli("bag", "info", str(swap_bag))
    assert info.returncode == 0
    assert "Topic: /attitude | Type: geometry_msgs/msg/QuaternionStamped | Count: 401" in info.stdout
    assert "Duration:          4.000000000s" in info.stdout  # sim time, parameter events included
    assert controller_swaps(open_bag(swap_bag)) == [(pytest.approx(1.99), "fuzzy_pid")]  # the event's log time
    assert effective_swaps(open_bag(swap_bag)) == [(pytest.approx(2.0), "fuzzy_pid")]  # the plot's: the swap at 2 s
    out = tmp_path / "swap.png"
    res = cli("plot", str(swap_bag), "-o", str(out))
    assert res.returncode == 0 and out.stat().st_size > 20_000


def test_broken_bags_get_one_line_errors(swap_bag, tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not an mcap file at all" * 100)
    for args in (("bag", "info", str(garbage)), ("plot", str(garbage), "-o", str(tmp_path / "g.png")),
                 ("replay", str(garbage), "--rate", "0"), ("bag", "info", str(tmp_path / "missing"))):
        res = cli(*args)
        assert res.returncode == 2, (args, res.stderr)
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and "Traceback" not in res.stderr
    # a bag cut short (a crash) is still readable, and says so
    mcap = next(swap_bag.glob("*.mcap"))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mcap.read_bytes()[: int(mcap.stat().st_size * 0.6)])
    info = cli("bag", "info", str(cut))
    assert info.returncode == 0 and "Recovered:         yes" in info.stdout
