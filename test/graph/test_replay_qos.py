"""``replay`` offers each topic with the QoS its bag recorded, and draws its progress line only on a terminal."""

import os
import pty
import select
import subprocess
import sys

import pytest
import rclpy
from geometry_msgs.msg import Vector3Stamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
from rclpy.serialization import serialize_message

from attitude_sil.ros.qos import LOCKSTEP_QOS, offered_qos_yaml, recorded_qos
from attitude_sil.storage.reader import open_bag
from attitude_sil.storage.writer import BagWriter, qos_profiles_yaml
from attitude_sil.tools.replay import ReplayOptions, replay_bag
from conftest import ROOT

STEPS = 250  # the progress line comes every 200 messages
BEST_EFFORT = qos_profiles_yaml(reliability="best_effort", depth=5)


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "small"
    with BagWriter(path) as writer:
        writer.add_topic("/wheel_torque", "geometry_msgs/msg/Vector3Stamped", offered_qos_yaml("wheel_torque"))
        writer.add_topic("/body_rate", "geometry_msgs/msg/Vector3Stamped", BEST_EFFORT)
        for k in range(STEPS):
            msg = Vector3Stamped()
            msg.header.stamp.nanosec = k * 10_000_000 % 1_000_000_000
            msg.header.stamp.sec = k // 100
            for topic in ("/wheel_torque", "/body_rate"):
                writer.write(topic, serialize_message(msg), k * 10_000_000)
    return path


def test_recorded_profiles_become_the_offered_qos():
    lockstep = recorded_qos(offered_qos_yaml("attitude"))
    assert (lockstep.reliability, lockstep.durability, lockstep.history, lockstep.depth) == (
        LOCKSTEP_QOS.reliability, LOCKSTEP_QOS.durability, LOCKSTEP_QOS.history, LOCKSTEP_QOS.depth)
    lossy = recorded_qos(BEST_EFFORT)
    assert (lossy.reliability, lossy.durability, lossy.depth) == (
        ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE, 5)
    # two recorded publishers: only what both offered
    both = recorded_qos(offered_qos_yaml("attitude") + "\n" + BEST_EFFORT)
    assert (both.reliability, both.durability, both.depth) == (
        ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE, LOCKSTEP_QOS.depth)
    default = recorded_qos("")  # a bag that recorded none: rclpy's default profile
    assert (default.reliability, default.durability, default.history, default.depth) == (
        ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, HistoryPolicy.KEEP_LAST, 10)
    with pytest.raises(ValueError, match="reliability"):
        recorded_qos("- {reliability: sometimes}")


def test_the_reader_gives_each_topic_its_recorded_profiles(bag):
    topics = open_bag(bag).topics
    assert topics["/body_rate"].offered_qos_profiles == BEST_EFFORT
    assert topics["/wheel_torque"].offered_qos_profiles == offered_qos_yaml("wheel_torque")


def test_replay_publishers_offer_the_recorded_qos(bag):
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    probe = rclpy.create_node("qos_probe", context=context)
    seen = {}

    def look():  # polled between messages, while replay's publishers exist
        if not seen:
            for topic in ("/wheel_torque", "/body_rate"):
                infos = [i for i in probe.get_publishers_info_by_topic(topic) if i.node_name == "replay"]
                seen[topic] = infos[0].qos_profile if infos else None
        return False

    try:
        sent = replay_bag(bag, ReplayOptions(rate=0), context=context, should_stop=look)
    finally:
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
    assert sent == 2 * STEPS
    # the graph reports what subscribers match against (DDS does not announce history or depth)
    lockstep, lossy = seen["/wheel_torque"], seen["/body_rate"]
    assert (lockstep.reliability, lockstep.durability) == (ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL)
    assert (lossy.reliability, lossy.durability) == (ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE)


def _replay_cli(bag, stderr):
    return subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "replay", str(bag), "--rate", "0"],
                            cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=stderr)


def test_progress_line_only_on_a_terminal(bag):
    piped = _replay_cli(bag, subprocess.PIPE)
    out, err = piped.communicate(timeout=120)
    assert piped.returncode == 0, err
    assert out.decode().strip() == f"replayed {2 * STEPS} messages"
    assert b"\r" not in err and b"replay t=" not in err
    # the same with stderr on a terminal
    master, slave = pty.openpty()
    try:
        term = _replay_cli(bag, slave)
        os.close(slave)
        got = b""
        while True:  # read until the child closes the terminal (EIO), bounded by the select timeout
            ready, _, _ = select.select([master], [], [], 120)
            assert ready, "no output from replay within 120 s"
            try:
                chunk = os.read(master, 4096)
            except OSError:
                break
            if not chunk:
                break
            got += chunk
        out = term.communicate(timeout=120)[0]
    finally:
        os.close(master)
    assert term.returncode == 0
    assert b"\rreplay t=" in got and b"400 messages" in got, got
    assert out.decode().strip() == f"replayed {2 * STEPS} messages"
