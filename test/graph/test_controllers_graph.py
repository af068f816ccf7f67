"""Every controller through the graph, swaps (scheduled and live), bumpless bounds, refusals."""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from attitude_sil.core.control import registry
from attitude_sil.core.control.momentum import BDOT
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.session import run_graph
from conftest import CONFIG, ROOT

ONE_DEG = np.radians(1.0)


@pytest.mark.parametrize("controller", [n for n in registry.names() if n != BDOT])  # B-dot detumbles: test_bdot
def test_each_controller_settles_the_hst_step_in_graph_and_batch(controller):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    result = run_graph(scn, controller=controller, progress=False, keep_trajectory=True)
    m = result.metrics
    assert m["controller_type"] == controller
    assert m["settling_time_s"] is not None and m["settling_time_s"] < 15.0
    assert m["steady_state_error_rad"] < 0.02 * ONE_DEG
    assert m["overshoot_pct"] < 2.0
    tr = simulate(scn, 1, controller=controller)
    assert np.max(np.abs(result.trajectory.q_BN[0] - tr.q_BN[0])) <= 1e-9
    assert np.max(np.abs(result.trajectory.omega_BN_B[0] - tr.omega_BN_B[0])) <= 1e-9
    kind_topic = "torque_cmd" if registry.output_of(controller) == "torque" else "voltage_cmd"
    assert result.counts[kind_topic] == 2001


def _jump(tr, k):
    return np.max(np.abs(tr.u_cmd[0, k] - tr.u_cmd[0, k - 1]))


@pytest.mark.parametrize("old,new", [("pid", "fuzzy_pid"), ("fuzzy_pid", "pid"), ("pid", "ga_flc"),
                                     ("ga_flc", "fuzzy_pid"), ("ga_flc", "pid")])
def test_swap_mid_transient_is_bumpless_within_a_command_kind(old, new):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    assert registry.output_of(old) == registry.output_of(new) == "command"
    tr = simulate(scn, 1, duration=4.0, controller=old, schedule=[(150, new)])
    assert max(_jump(tr, k) for k in range(140, 150)) > 1e-4  # mid-transient: the command is moving
    assert _jump(tr, 150) <= 1e-9  # the new law's first command is the old law's last
    # and the new law really took over: without a swap the commands differ
    tr_old = simulate(scn, 1, duration=4.0, controller=old, schedule=[])
    assert np.max(np.abs(tr.u_cmd[0, 200:] - tr_old.u_cmd[0, 200:])) > 1e-3


def test_swap_between_command_kinds_is_bounded():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    tr = simulate(scn, 1, duration=4.0, controller="pid", schedule=[(150, "geometric")])
    assert tr.kind[149] == "voltage" and tr.kind[150] == "torque"
    limit = scn.param("controller", "geometric.torque_limit")
    # documented bound: the new law starts from its own command, |u| <= its limit
    assert np.max(np.abs(tr.u_cmd[0, 150:])) <= limit
    # the body torque the wheels deliver does not jump by more than the limit either
    assert np.max(np.abs(tr.tau_c_B[0, 150] - tr.tau_c_B[0, 149])) <= 2 * limit


def test_scheduled_swap_in_yaml_runs_through_the_parameter_service(tmp_path):
    data = yaml.safe_load((CONFIG / "hst_roll_step.yaml").read_text())
    data["scenario"]["ros__parameters"]["schedule.times"] = [1.5, 3.0]
    data["scenario"]["ros__parameters"]["schedule.controller_types"] = ["fuzzy_pid", "geometric"]
    path = tmp_path / "swap.yaml"
    path.write_text(yaml.safe_dump(data))
    scn = load_scenario(path)
    result = run_graph(scn, duration=5.0, record_dir=tmp_path / "bag", progress=False, keep_trajectory=True)
    tr = simulate(scn, 1, duration=5.0)
    assert np.max(np.abs(result.trajectory.q_BN[0] - tr.q_BN[0])) <= 1e-9
    assert np.max(np.abs(result.trajectory.omega_BN_B[0] - tr.omega_BN_B[0])) <= 1e-9
    assert [s["controller_type"] for s in result.metrics["segments"]] == ["pid", "fuzzy_pid", "geometric"]
    # the bag shows the swaps as parameter events, and the command topic follows the law
    changes, cmds = [], {"/voltage_cmd": [], "/torque_cmd": []}
    with open(result.bag / "bag_0.mcap", "rb") as f:
        for _s, channel, _m, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic == "/parameter_events" and msg.node == "/controller":
                changes += [(p.name, p.value.string_value) for p in msg.changed_parameters]
            if channel.topic in cmds:
                cmds[channel.topic].append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
    assert ("controller_type", "fuzzy_pid") in changes and ("controller_type", "geometric") in changes
    assert max(cmds["/voltage_cmd"]) == pytest.approx(2.99) and min(cmds["/torque_cmd"]) == pytest.approx(3.0)
    # the hold is released: no lingering hold_at
    assert len(cmds["/voltage_cmd"]) + len(cmds["/torque_cmd"]) == 501


def _param(*args, timeout=60.0):
    # discovery of a fresh process can take long on a loaded machine: wait for the node up to
    # 60 s (by condition, inside param), unless the call gives its own --timeout
    if "--timeout" not in args:
        args = (*args, "--timeout", str(timeout))
    return subprocess.run([sys.executable, "-m", "attitude_sil.cli", "param", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout + 60, stdin=subprocess.DEVNULL)


def test_live_param_list_get_set_dump_load_from_a_second_process(tmp_path, cli):
    # the first calls run as real processes (what a user types in a second terminal); the rest
    # run cli.main in this process, which is the same code without 2 s of start-up per call

    def here(*args):
        return cli("param", *args, *(() if "--timeout" in args else ("--timeout", "60")))

    bag = tmp_path / "live"
    # the episode outlasts any test run (it is stopped with Ctrl-C below), so a slow machine
    # cannot end it before the parameter calls are done: each call waits by condition only
    run = subprocess.Popen(
        [sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml", "--real-time",
         "--duration", "3600", "--record", str(bag)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        assert "real time" in run.stderr.readline()  # running
        listing = _param("list", "controller")
        assert listing.returncode == 0 and "  pid.kp" in listing.stdout.splitlines()  # as ros2 param list
        # refusals name the parameter and the rule; the node keeps its values
        for name, value, needle in (("geometric.k", "[1.0, 1.0, 2.0]", "distinct"),
                                    ("pid.kp", "[1.0, 2.0]", "3 elements"),
                                    ("controller_type", "bangbang", "one of"),
                                    ("pid.ki", "[-1, 0, 0]", ">= 0.0")):
            bad = (_param if name == "geometric.k" else here)("set", "controller", name, value)
            assert bad.returncode == 2, bad.stdout
            assert needle in bad.stderr and name in bad.stderr and "Traceback" not in bad.stderr
            assert "Setting parameter failed" in bad.stderr
        got = _param("get", "controller", "pid.kp")
        assert got.stdout.strip() == "Double values are: [48.894, 48.894, 48.894]", got.stderr
        ok = _param("set", "controller", "controller_type", "ga_flc")
        assert ok.returncode == 0 and ok.stdout.strip() == "Set parameter successful", ok.stderr
        got = here("get", "controller", "controller_type")
        assert got.stdout.strip() == "String value is: ga_flc", got.stderr
        # YAML 1.2 numbers, as the scenario files take them
        assert here("set", "controller", "pid.kp", "[1e2, 1e2, 1e2]").returncode == 0
        assert here("get", "controller", "pid.kp", "--hide-type").stdout.strip() == "[100.0, 100.0, 100.0]"
        # what the schema marks not changeable at runtime is refused, naming the parameter
        for name, value in (("command", "torque"), ("control_period", "0.02")):
            refused = here("set", "controller", name, value)
            assert refused.returncode == 2 and name in refused.stderr and "read-only" in refused.stderr, \
                refused.stderr
        # dump, edit, load: ros2 param's file form, one verdict line per parameter sent
        dumped = tmp_path / "controller.yaml"
        assert here("dump", "/controller", str(dumped)).returncode == 0
        data = yaml.safe_load(dumped.read_text())
        values = data["/controller"]["ros__parameters"]
        assert values["pid"]["kp"] == [100.0, 100.0, 100.0] and values["controller_type"] == "ga_flc"
        assert values["use_sim_time"] is True and values["command"] == "voltage"
        values["pid"]["kd"] = [120.0, 120.0, 120.0]
        values["pid"]["ki"] = [-1.0, 0.0, 0.0]  # refused by the node: the rest still goes in
        values["pid"]["nosuch"] = 1.0  # not declared: refused here
        dumped.write_text(yaml.safe_dump(data))
        loaded = here("load", "controller", str(dumped))
        assert loaded.returncode == 2, loaded.stdout + loaded.stderr
        assert loaded.stdout.splitlines()[0] == "Set parameter pid.kd successful", loaded.stdout
        assert "Set parameter pid.ki failed: " in loaded.stderr and ">= 0.0" in loaded.stderr
        assert "Set parameter pid.nosuch failed: controller has no parameter 'pid.nosuch'" in loaded.stderr
        assert "Traceback" not in loaded.stderr
        assert "already at the file's value, not sent" in loaded.stdout  # read-only ones included
        assert here("get", "controller", "pid.kd", "--hide-type").stdout.strip() == "[120.0, 120.0, 120.0]"
        assert here("get", "controller", "pid.ki", "--hide-type").stdout.strip() == "[0.071, 0.071, 0.071]"
        # a tuner's best.yaml (/**/controller) applies a tuned design to the live graph
        best = tmp_path / "best.yaml"
        best.write_text("/**/controller:\n  ros__parameters:\n    controller_type: pid\n"
                        "    pid.kp: [60, 60, 60]\n")
        loaded = here("load", "/controller", str(best))
        assert loaded.returncode == 0, loaded.stderr
        assert loaded.stdout.splitlines() == ["Set parameter controller_type successful",
                                              "Set parameter pid.kp successful"]
        assert here("get", "controller", "pid.kp").stdout.strip() == "Double values are: [60.0, 60.0, 60.0]"
        assert run.poll() is None, "the run ended during the test"
        missing = here("get", "nosuchnode", "x", "--timeout", "1")
        assert missing.returncode == 2 and "not found" in missing.stderr
    finally:
        run.send_signal(signal.SIGINT)
        _, err = run.communicate(timeout=30)
    assert run.returncode == 130, err
    changed = []
    with open(bag / "live_0.mcap", "rb") as f:
        for _s, channel, _m, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic == "/parameter_events" and msg.node == "/controller":
                changed += [(p.name, p.value.string_value) for p in msg.changed_parameters]
    assert ("controller_type", "ga_flc") in changed


def _children(pid: int) -> list[int]:
    out = []
    for status in __import__("pathlib").Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines() if ":\t" in line)
        except OSError:
            continue
        if int(fields.get("PPid", "0").strip()) == pid:
            out.append(int(status.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = open(f"/proc/{pid}/status").read().split("State:\t", 1)[1][0]
    except (OSError, IndexError):
        return False
    return state != "Z"


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
@pytest.mark.parametrize("processes", [False, True], ids=["one-process", "processes"])
def test_sigterm_and_sighup_close_the_bag_and_end_every_node(tmp_path, sig, code, processes):
    bag = tmp_path / "stopped"
    cmd = [sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml", "--real-time",
           "--duration", "3600", "--record", str(bag)] + (["--processes"] if processes else [])
    run = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           stdin=subprocess.DEVNULL, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                           start_new_session=True)
    try:
        assert "real time" in run.stderr.readline()  # the episode runs
        nodes = _children(run.pid)
        # --processes: one process per node, each of which must be gone at the end (`left`, below); in one
        # process the nodes are the runner's own and end with it (its exit code, below)
        assert len(nodes) == (5 if processes else 0)
        run.send_signal(sig)
        _, err = run.communicate(timeout=60)
        left = [pid for pid in nodes if _alive(pid)]  # looked at before the clean-up below kills anything
    finally:
        _kill_group(run)
    assert run.returncode == code, err
    assert "Traceback" not in err and signal.Signals(sig).name in err
    assert not left  # no node process left behind
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] > 0
    with open(bag / "stopped_0.mcap", "rb") as f:
        summary = make_reader(f, decoder_factories=[DecoderFactory()]).get_summary()
    assert summary.statistics.message_count == info["message_count"]


def _kill_group(run: subprocess.Popen) -> None:
    """SIGKILL a runner started in a session of its own and every process of its group (its node processes)."""
    try:
        os.killpg(run.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    run.wait()


def _node_of(pid: int) -> str:
    cmdline = open(f"/proc/{pid}/cmdline").read().split("\0")
    return next(a.split(".")[-1].removesuffix("_node") for a in cmdline if a.startswith("attitude_sil.nodes."))


# every node killed (each exit is seen by the runner); a stopped node is seen by the stall watchdog,
# which watches the step topics whoever stops: the clock's owner and one node it waits for cover it
FAULTS = [(victim, signal.SIGKILL) for victim in ("plant", "wheels", "disturbance", "guidance", "controller")] + [
    ("plant", signal.SIGSTOP), ("controller", signal.SIGSTOP)]


@pytest.mark.parametrize("victim,fault", FAULTS, ids=[f"{v}-{'kill-9' if f == signal.SIGKILL else 'stop'}"
                                                      for v, f in FAULTS])
def test_a_failed_node_process_ends_the_run_with_one_line_and_a_readable_bag(tmp_path, victim, fault):
    bag = tmp_path / "faulty"
    run = subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml",
                            "--real-time", "--duration", "3600", "--processes", "--record", str(bag)], cwd=ROOT,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                           start_new_session=True)
    nodes = []
    try:
        assert "real time" in run.stderr.readline()
        if fault == signal.SIGSTOP:
            # once the episode runs (node processes loaded and stepping), a stopped node is to be noticed after 2 s
            # instead of 10, by the plant and by the runner's watchdog, which follows the live value: set at start,
            # a node process still loading its kernels under load tripped it at step 0 (a killed node's exit is
            # seen at once)
            fast = subprocess.run([sys.executable, "-m", "attitude_sil.cli", "param", "set", "plant",
                                   "input_timeout", "2.0"], cwd=ROOT, capture_output=True, text=True, timeout=120,
                                  stdin=subprocess.DEVNULL)
            assert fast.returncode == 0, fast.stderr
        nodes = _children(run.pid)
        assert len(nodes) == 5, nodes  # every node process, so that none left behind is missed below
        target = next(pid for pid in nodes if _node_of(pid) == victim)
        os.kill(target, fault)
        _, err = run.communicate(timeout=60)  # bounded: the watchdogs, not the hour of sim time, end it
        left = [pid for pid in nodes if _alive(pid)]  # looked at before the clean-up below kills anything
    finally:
        _kill_group(run)  # a failed assertion above must not leave the node processes to the next tests
        for pid in nodes:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert run.returncode == 2, err
    last = [ln for ln in err.splitlines() if ln.startswith("attitude-sil:")]
    assert len(last) == 1 and "error:" in last[0] and "Traceback" not in err
    if fault == signal.SIGKILL:  # seen as the exit it is, not later as a stall by the watchdog
        assert f"node process attitude_sil.nodes.{victim}_node exited" in last[0], last[0]
    assert not left  # no node process left behind
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] > 0


def test_ctrl_c_in_a_terminal_stops_every_process_with_one_line(tmp_path):
    # a terminal's Ctrl-C reaches the whole process group: the runner and every node process at once
    bag = tmp_path / "ctrl_c"
    run = subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml",
                            "--real-time", "--duration", "3600", "--processes", "--record", str(bag)], cwd=ROOT,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                           start_new_session=True)
    try:
        assert "real time" in run.stderr.readline()
        nodes = _children(run.pid)
        assert len(nodes) == 5, nodes  # every node process, so that none left behind is missed below
        os.killpg(run.pid, signal.SIGINT)
        _, err = run.communicate(timeout=60)
        left = [pid for pid in nodes if _alive(pid)]  # looked at before the clean-up below kills anything
    finally:
        _kill_group(run)
    assert run.returncode == 130
    assert err.strip().splitlines() == ["interrupted (SIGINT); everything recorded so far is kept"], err
    assert not left
    assert (bag / "metadata.yaml").is_file()
