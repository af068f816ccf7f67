"""The ROS graph end to end: lockstep runs, graph == batch, and the recorded bag."""

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.session import run_graph
from attitude_sil.ros.contract import RECORDED_TOPICS, STEP_TOPICS
from attitude_sil.storage.msgdefs import message_definition
from conftest import CONFIG


def _assert_same_as_batch(scn, result, duration):
    tr = simulate(scn, 1, duration=duration)
    k = tr.t.size
    g = result.trajectory
    assert g.q_BN.shape == (1, k, 4) and g.omega_BN_B.shape == (1, k, 3)
    assert np.array_equal(np.round(g.t * 1e9).astype(np.int64), np.round(tr.t * 1e9).astype(np.int64))
    assert np.max(np.abs(g.q_BN - tr.q_BN)) <= 1e-9
    assert np.max(np.abs(g.omega_BN_B - tr.omega_BN_B)) <= 1e-9
    # the commands, wheel torques and momenta the graph exchanged are the batch engine's too
    assert np.max(np.abs(g.u_cmd - tr.u_cmd)) <= 1e-9
    assert np.max(np.abs(g.tau_c_B - tr.tau_c_B)) <= 1e-9
    assert np.max(np.abs(g.h_wheels_B - tr.h_wheels_B)) <= 1e-9
    assert g.kind == tr.kind
    # and the run really moved: otherwise agreement would prove nothing
    assert np.max(np.abs(tr.omega_BN_B)) > 1e-4


@pytest.fixture(scope="module")
def roll_run(tmp_path_factory):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    bag = tmp_path_factory.mktemp("bags") / "roll"
    return scn, run_graph(scn, record_dir=bag, progress=False, keep_trajectory=True)  # the whole 20 s scenario


def test_in_process_graph_completes_and_matches_batch(roll_run):
    scn, result = roll_run
    assert result.metrics["sim_time_s"] == 20.0
    assert result.metrics["overshoot_pct"] is not None
    _assert_same_as_batch(scn, result, 20.0)


def test_bag_holds_every_topic_with_types_and_counts(roll_run):
    _, result = roll_run
    mcap_file = result.bag / f"{result.bag.name}_0.mcap"
    assert (result.bag / "metadata.yaml").is_file()
    counts, types, stamps = {}, {}, {}
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            types[channel.topic] = schema.name
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            if channel.topic == "/attitude":
                stamps.setdefault("att", []).append(decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec)
                assert decoded.header.frame_id == "inertial"
            if channel.topic == "/wheel_state":
                assert list(decoded.name) == ["wheel_1", "wheel_2", "wheel_3", "wheel_4"]
    steps = 2001  # 20 s at 100 Hz, k = 0..2000
    for name, type_name in STEP_TOPICS.items():
        topic = name if name.startswith("/") else "/" + name
        if name in ("torque_cmd", "wheel_cmd"):  # the PID commands volts: no torque or wheel command in this run
            assert topic not in counts
            continue
        assert counts.get(topic) == steps, (topic, counts.get(topic))
        assert types[topic] == type_name
    assert types["/parameter_events"] == RECORDED_TOPICS["/parameter_events"]
    assert stamps["att"] == [k * 10_000_000 for k in range(steps)]


def test_bag_carries_the_frames_and_the_body_model(roll_run):
    # /tf (tf2_msgs/msg/TFMessage: no wheel on PyPI, its definition and CDR are the storage layer's) and
    # /body_model, read by two independent readers: mcap-ros2-support and rosbags
    from rosbags.highlevel import AnyReader

    _, result = roll_run
    steps = 2001
    attitude, frames, models = {}, [], []
    with open(result.bag / f"{result.bag.name}_0.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=["/attitude", "/tf", "/body_model"]):
            if channel.topic == "/attitude":
                q = decoded.quaternion
                attitude[message.log_time] = (q.x, q.y, q.z, q.w)
            elif channel.topic == "/tf":
                # the full ros2msg definition, dependencies included, as rosbag2 writes it
                assert schema.name == "tf2_msgs/msg/TFMessage"
                assert schema.data.decode() == message_definition("tf2_msgs/msg/TFMessage")
                frames.append((message.log_time, decoded.transforms))
            else:
                assert schema.data.decode() == message_definition("visualization_msgs/msg/MarkerArray")
                models.append((message.log_time, decoded.markers))
    assert len(frames) == steps and len(attitude) == steps
    for t, transforms in frames:
        (tf,) = transforms  # no orbit in this scenario: the body in inertial alone
        assert (tf.header.frame_id, tf.child_frame_id) == ("inertial", "body")
        assert tf.header.stamp.sec * 10**9 + tf.header.stamp.nanosec == t
        r, p = tf.transform.rotation, tf.transform.translation
        assert (r.x, r.y, r.z, r.w) == attitude[t]  # the attitude itself, to the bit
        assert (p.x, p.y, p.z) == (0.0, 0.0, 0.0)
    (t0, markers), = models  # once, with step 0
    assert t0 == 0 and all(m.header.frame_id == "body" and m.frame_locked for m in markers)
    kinds = [m.type for m in markers]
    assert kinds.count(1) == 1 and kinds.count(0) == 4  # the body's box, the four HST wheels' axes
    # rosbags reads the same transforms from the metadata's type hash and the schema
    with AnyReader([result.bag]) as any_reader:
        (conn,) = [c for c in any_reader.connections if c.topic == "/tf"]
        assert conn.msgtype == "tf2_msgs/msg/TFMessage"
        last = None
        for connection, _t, raw in any_reader.messages(connections=[conn]):
            last = any_reader.deserialize(raw, connection.msgtype)
        r = last.transforms[0].transform.rotation
        assert (r.x, r.y, r.z, r.w) == attitude[20 * 10**9]
    metadata = (result.bag / "metadata.yaml").read_text()
    assert "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087" in metadata


def test_graph_with_disturbances_matches_batch(tmp_path):
    scn = load_scenario(CONFIG / "hst_roll_yaw.yaml")
    result = run_graph(scn, duration=3.0, record_dir=None, progress=False, keep_trajectory=True)
    _assert_same_as_batch(scn, result, 3.0)


def test_multi_process_graph_completes_and_matches_batch(tmp_path):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    result = run_graph(scn, record_dir=tmp_path / "mp", processes=True, progress=False, keep_trajectory=True)
    assert result.counts["wheel_torque"] == 2001
    _assert_same_as_batch(scn, result, 20.0)


def test_ctrl_c_keeps_a_readable_bag(tmp_path):
    """Ctrl-C mid-run: exit 130, one line, and the bag holds whole steps up to the stop."""
    import re
    import signal
    import subprocess
    import sys

    from conftest import ROOT

    bag = tmp_path / "interrupted"
    proc = subprocess.Popen(
        [sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml", "--real-time",
         "--record", str(bag)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    first = proc.stderr.readline()  # the first progress line: the episode is running
    assert "real time" in first, first
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130
    assert "Traceback" not in err and "interrupted" in err
    counts = {}
    with open(bag / "interrupted_0.mcap", "rb") as f:
        for _schema, channel, _msg, _decoded in make_reader(f, decoder_factories=[DecoderFactory()]) \
                .iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    # the progress line reports the steps the recorder held when it was printed ("sim T / 20.00 s": the wheel
    # torques of steps 0..T/dt had arrived, and each step's attitude is published before its wheel torque);
    # the bag keeps at least those, however loaded the machine (a fixed count was a race with the recorder)
    sim_t = float(re.match(r"\s*sim\s+([0-9.]+)\s*/", first).group(1))
    held = round(sim_t / 0.01) + 1
    assert held >= 1
    assert counts["/wheel_torque"] >= held, (counts["/wheel_torque"], first)
    assert counts["/attitude"] >= held, (counts["/attitude"], first)
    assert counts["/attitude"] < 2001  # and it stopped before the end


def test_three_runs_at_once_with_default_settings_do_not_see_each_other(tmp_path):
    import json
    import os
    import subprocess
    import sys

    from attitude_sil.storage.reader import open_bag
    from conftest import ROOT

    env = {k: v for k, v in os.environ.items() if k not in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}

    def start(name):
        return subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml",
                                 "--duration", "3", "--json", "--quiet", "--record", str(tmp_path / name)],
                                cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                stdin=subprocess.DEVNULL)

    runs = [start(f"run{i}") for i in range(3)]
    outs = [r.communicate(timeout=240) for r in runs]
    solo = start("solo")
    outs.append(solo.communicate(timeout=240))
    domains = set()
    metrics = []
    for (out, err), run in zip(outs, runs + [solo], strict=True):
        assert run.returncode == 0, err
        domains.add(err.split("ROS_DOMAIN_ID=")[1].split()[0])  # the run says where it is
        m = json.loads(out.strip().splitlines()[-1])
        metrics.append({k: v for k, v in m.items() if k not in ("wall_time_s", "real_time_factor", "bag")})
    assert len(domains) >= 3  # the three concurrent runs had a domain each
    assert metrics[0] == metrics[1] == metrics[2] == metrics[3]
    for name in ("run0", "run1", "run2", "solo"):
        reader = open_bag(tmp_path / name)
        counts = {t: info.count for t, info in reader.topics.items() if t not in (
            "/parameter_events", "/flexible_mode", "/torque_cmd", "/wheel_cmd", "/body_model",
            "/diagnostics")}  # the body model: once
        assert set(counts.values()) == {301}, counts  # exactly one message per step on every topic
