"""``run --foxglove``: Foxglove WebSocket clients watch a run live; the shipped layout; bad ports.

Every run here holds its step 0 until a client has subscribed
(``--wait-for-viewer``), so a client that starts late on a loaded machine
still sees the run: each test waits by that condition, with a generous
``--wait-for-viewer`` limit and process timeouts as hang guards only.

Two clients, one per subprotocol name the server must accept. The official
open-source one, ``@foxglove/ws-protocol`` (``test/js/client.mjs``, pinned
in ``test/js/package-lock.json``), asks for ``foxglove.websocket.v1``, as
Lichtblick and older Foxglove releases do; it subscribes to every channel
and decodes the attitude quaternion and the ``/tf`` transforms with ``@foxglove/cdr``. A Python one
(``websockets``) asks for ``foxglove.sdk.v1``, the name of foxglove-sdk's
server and of current Foxglove, and speaks the protocol itself: it waits for the
``advertise`` of ``/attitude``
(message encoding ``cdr``, schema encoding ``ros2msg`` with the bag's message
definition), subscribes, and decodes the binary message-data frames (opcode
1: subscription id, log time, CDR payload) with rclpy's deserializer.
"""

from __future__ import annotations

import json
import re
import socket
import struct
import subprocess
import sys
import time

import numpy as np
from geometry_msgs.msg import QuaternionStamped
from rclpy.serialization import deserialize_message
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from attitude_sil.cli import main
from attitude_sil.core.plant.disturbance import lvlh_attitude, orbit_rate
from attitude_sil.core.plant.quaternion import quat_from_euler
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.ros.contract import RECORDED_TOPICS, VIEW_TOPICS, recorded_topics
from attitude_sil.storage.foxglove import STATUS_TOPIC
from attitude_sil.storage.msgdefs import message_definition
from conftest import CONFIG, ROOT

SCENARIO = str(CONFIG / "hst_roll_step.yaml")
LAYOUT = CONFIG / "foxglove" / "attitude.json"
#: wall s: how long a run holds step 0 for its client, and the bound of every wait here; hang guards only, far
#: beyond what a client needs to connect on a loaded machine (the tests wait by condition)
HANG_GUARD = 180


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _connect(port: int, proc: subprocess.Popen, deadline: float):
    # a port that is not open yet has no event to wait on: polled, bounded by the hang guard
    while True:
        try:
            return connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], open_timeout=2)
        except OSError:
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, "the Foxglove server did not come up"
            time.sleep(0.05)  # polling a port that is not open yet: nothing to wait on but time


def test_a_foxglove_client_watches_attitude_live():
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "run", SCENARIO, "--duration", "3",
                             "--no-record", "--quiet", "--foxglove", str(port), "--foxglove-fast",
                             "--wait-for-viewer", str(HANG_GUARD)], cwd=ROOT,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 2 * HANG_GUARD
    stamps, norms, status = [], [], []
    try:
        subs: dict[int, str] = {}
        with _connect(port, proc, deadline) as ws:
            assert ws.subprotocol == "foxglove.sdk.v1"
            try:
                while time.monotonic() < deadline:
                    frame = ws.recv(timeout=max(deadline - time.monotonic(), 0.1))
                    if isinstance(frame, str):
                        msg = json.loads(frame)
                        if msg["op"] != "advertise":
                            continue
                        # /attitude subscribed first: the run holds step 0 until a subscription, so it gets every step
                        for ch in sorted(msg["channels"], key=lambda c: c["topic"] != "/attitude"):
                            if ch["topic"] == "/attitude":
                                assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg"
                                assert ch["schemaName"] == "geometry_msgs/msg/QuaternionStamped"
                                assert ch["schema"] == message_definition("geometry_msgs/msg/QuaternionStamped")
                            if ch["topic"] in ("/attitude", STATUS_TOPIC):
                                subs[len(subs) + 1] = ch["topic"]
                                ws.send(json.dumps({"op": "subscribe",
                                                    "subscriptions": [{"id": len(subs), "channelId": ch["id"]}]}))
                        continue
                    assert frame[0] == 1  # message data
                    sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                    payload = frame[13:]
                    if subs[sub_id] == STATUS_TOPIC:
                        status.append(json.loads(payload))
                        continue
                    q = deserialize_message(payload, QuaternionStamped)
                    t = q.header.stamp.sec * 1_000_000_000 + q.header.stamp.nanosec
                    assert t == log_time  # the message is logged at its sim-time stamp, as in the bags
                    stamps.append(t)
                    norms.append(np.linalg.norm([q.quaternion.x, q.quaternion.y, q.quaternion.z, q.quaternion.w]))
            except ConnectionClosed:
                pass  # the run ended and stopped its server
        out, err = proc.communicate(timeout=max(deadline - time.monotonic(), 1))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert f"ws://127.0.0.1:{port}" in err
    # every step from step 0, in order: the run waited for the subscription (--wait-for-viewer)
    assert stamps == [k * 10_000_000 for k in range(301)], (len(stamps), stamps[:3])
    assert "holding step 0 until a client subscribes" in err
    assert np.allclose(norms, 1.0, atol=1e-12)
    assert status and {s["controller_type"] for s in status} == {"pid"}


NODE_CLIENT = ROOT / "test" / "js" / "client.mjs"


def _official_client(port: int, *args: str, duration: float = 3.0, bag=None,
                     scenario: str = SCENARIO) -> tuple[dict, str]:
    """``run --foxglove PORT`` for ``duration`` s and the official client against it: (its JSON, run's stdout).

    The run holds step 0 until the client subscribes (``--wait-for-viewer``): a client that is slow to start
    still watches the run."""
    record = ["--record", str(bag)] if bag is not None else ["--no-record"]
    run = subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "run", scenario, "--duration", str(duration),
                            *record, "--quiet", "--json", "--foxglove", str(port), "--wait-for-viewer",
                            str(HANG_GUARD)], cwd=ROOT, stdin=subprocess.DEVNULL,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        client = subprocess.run(["node", str(NODE_CLIENT), f"ws://127.0.0.1:{port}", *args, "--timeout",
                                 str(2 * HANG_GUARD)], cwd=NODE_CLIENT.parent, capture_output=True, text=True,
                                timeout=3 * HANG_GUARD)
        out, err = run.communicate(timeout=3 * HANG_GUARD)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 0, err
    assert client.returncode == 0, client.stdout + client.stderr
    return json.loads(client.stdout), out


def test_the_official_open_source_client_watches_every_channel_and_the_frames():
    # Hawai'iSat tracking LVLH: the frames are the body in inertial and, the scenario having an orbit, LVLH
    lvlh = str(CONFIG / "hawaiisat_lvlh.yaml")
    got, _ = _official_client(_free_port(), "--attitude", "60", "--tf", "60", duration=2.0, scenario=lvlh)
    assert got["subprotocol"] == "foxglove.websocket.v1"  # the name Lichtblick and ws-protocol ask for
    channels = {c["topic"]: c for c in got["channels"]}
    # every topic the run records (it runs no sensing loop: no sensor channels), and the 3D view's
    assert {n if n.startswith("/") else "/" + n for n in {**recorded_topics(False), **VIEW_TOPICS}} | {
        STATUS_TOPIC} <= set(channels)
    assert all(c["encoding"] == "cdr" and c["schemaEncoding"] == "ros2msg" for c in got["channels"]
               if c["topic"] != STATUS_TOPIC)
    assert channels["/tf"]["schemaName"] == "tf2_msgs/msg/TFMessage"
    assert channels["/body_model"]["schemaName"] == "visualization_msgs/msg/MarkerArray"
    assert got["counts"]["/body_model"] >= 1  # the model, sent with the first attitude after the subscription
    att = np.array(got["attitude"])  # sec, nanosec, x, y, z, w decoded by @foxglove/cdr
    stamps = att[:, 0] * 1_000_000_000 + att[:, 1]
    assert len(att) == 60 and np.all(np.diff(stamps) == 20_000_000)  # one per 20 ms step, in order
    assert np.allclose(np.linalg.norm(att[:, 2:], axis=1), 1.0, atol=1e-12)
    assert got["counts"]["/clock"] > 0 and got["counts"]["/body_rate"] > 0
    # /tf, decoded by the official client: inertial -> body is the attitude, inertial -> lvlh the orbit frame
    scn = load_scenario(lvlh)
    q_LN0 = quat_from_euler(np.radians(scn.param("guidance", "orbit.lvlh_initial_rpy_deg")))
    rate = orbit_rate(scn.param("guidance", "orbit.mu"), scn.param("guidance", "orbit.radius"))
    by_stamp = {int(s): a[2:] for s, a in zip(stamps, att, strict=True)}
    compared = 0
    for message in got["tf"]:
        assert [(t[2], t[3]) for t in message] == [("inertial", "body"), ("inertial", "lvlh")]
        t_ns = message[0][0] * 1_000_000_000 + message[0][1]
        assert all(t[0] * 1_000_000_000 + t[1] == t_ns for t in message)  # one stamp: the step's
        assert all(t[4:7] == [0.0, 0.0, 0.0] for t in message)  # one origin: the centre of mass
        if t_ns in by_stamp:
            assert np.max(np.abs(np.array(message[0][7:]) - by_stamp[t_ns])) <= 1e-12
            compared += 1
        assert np.max(np.abs(np.array(message[1][7:]) - lvlh_attitude(t_ns * 1e-9, q_LN0, rate))) <= 1e-12
    assert compared >= 50, compared
    # the frame turns: at the orbit rate, 2 s moves LVLH measurably from N
    assert max(abs(m[1][8]) for m in got["tf"]) > 1e-4


def test_the_official_client_reads_and_sets_parameters_and_swaps_the_law(tmp_path):
    # the Parameters panel's calls, under foxglove_bridge's names: get, subscribe, set (one value refused)
    bag = tmp_path / "swapped"
    got, out = _official_client(
        _free_port(), "--attitude", "1", "--get", "/controller.controller_type,/controller.pid.kp",
        "--set", '/controller.controller_type="ga_flc"', "--set", "/controller.geometric.k=[1.0, 1.0, 2.0]",
        "--set-after", "10", "--updates", "1", duration=6.0, bag=bag)  # the sets once the run is under way
    assert {"parameters", "parametersSubscribe"} <= set(got["capabilities"])
    values = {p["name"]: p["value"] for p in got["parameters"]}
    assert values == {"/controller.controller_type": "pid", "/controller.pid.kp": [48.894, 48.894, 48.894]}, (
        got["statuses"])  # the server's reason, if a get failed
    after = {p["name"]: p["value"] for p in got["setResult"]}
    assert after["/controller.controller_type"] == "ga_flc"
    assert after["/controller.geometric.k"] != [1.0, 1.0, 2.0]  # refused: the node keeps its value
    # the same one-line reason param set prints, as a status message to the client
    assert "Setting parameter failed: controller.geometric.k entries must be distinct (paper 001: k1 != k2 != k3)" \
        in got["statuses"]
    assert {"name": "/controller.controller_type", "value": "ga_flc"} in got["updates"]
    # the swap went through the node's parameter service: it is in the bag's /parameter_events
    from mcap_ros2.reader import read_ros2_messages

    events = [m.ros_msg for m in read_ros2_messages(str(next(bag.glob("*.mcap"))), topics=["/parameter_events"])]
    assert any(p.name == "controller_type" and p.value.string_value == "ga_flc"
               for e in events if e.node == "/controller" for p in e.changed_parameters)
    metrics = json.loads(out.splitlines()[-1])
    assert [s["controller_type"] for s in metrics["segments"]] == ["pid", "ga_flc"]  # in the run's summary


def test_without_a_viewer_the_held_run_starts_after_its_limit():
    # nobody connects: the run says it holds step 0, then that nobody came, and runs to its end
    run = subprocess.run([sys.executable, "-m", "attitude_sil.cli", "run", SCENARIO, "--duration", "1", "--no-record",
                          "--quiet", "--json", "--foxglove", str(_free_port()), "--foxglove-fast", "--wait-for-viewer",
                          "0.5"], cwd=ROOT, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                         timeout=3 * HANG_GUARD)
    assert run.returncode == 0, run.stderr
    assert "holding step 0 until a client subscribes (at most 0.5 s)" in run.stderr
    assert "no client subscribed within 0.5 s; the run starts" in run.stderr
    assert json.loads(run.stdout.splitlines()[-1])["sim_time_s"] == 1.0


def test_wait_for_viewer_bad_values_are_one_line(capfd):
    for argv, needle in ((["--foxglove", "8765", "--wait-for-viewer", "-1"], "> 0"),
                         (["--foxglove", "8765", "--wait-for-viewer", "nan"], "> 0"),
                         (["--wait-for-viewer", "5"], "--foxglove")):
        code = main(["run", SCENARIO, "--no-record", *argv])
        err = capfd.readouterr().err
        assert code == 2 and err.count("\n") == 1 and needle in err and err.startswith("attitude-sil: error:"), err


def test_port_in_use_is_one_line(capfd):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["run", SCENARIO, "--no-record", "--foxglove", str(port)])
    err = capfd.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "in use" in err and err.startswith("attitude-sil: error:"), err


def test_the_layout_plots_what_the_graph_publishes():
    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
    # the titles Foxglove and Lichtblick read, and a Parameters panel to swap the law from
    assert all(cfg.get("foxglovePanelTitle") and "title" not in cfg for cfg in panels.values())
    assert any(key.startswith("Parameters!") for key in panels)
    paths = [p for cfg in panels.values() for p in cfg.get("paths", [])]
    topics = {re.match(r"(/[a-z_/]+?)[.{]", p["value"]).group(1) for p in paths}
    assert topics == {"/attitude", "/attitude_error", "/body_rate", "/wheel_state", "/voltage_cmd", "/torque_cmd",
                      "/wheel_momentum", "/dipole_cmd", "/parameter_events", STATUS_TOPIC}
    assert topics - {STATUS_TOPIC} <= {n if n.startswith("/") else "/" + n for n in RECORDED_TOPICS}
    # on sim time: the header stamp where the message has one; the status channel and /parameter_events have
    # none and are logged (live and in the bags) at their sim time, which a client takes as their time
    for p in paths:
        header = not p["value"].startswith((STATUS_TOPIC, "/parameter_events"))
        assert p["timestampMethod"] == ("headerStamp" if header else "receiveTime"), p
    wheels = next(cfg for key, cfg in panels.items() if "wheel" in key)
    assert wheels["yAxisLabel"] == "rad/s" and all("rad/s" in p["label"] for p in wheels["paths"])
    # the layout opens with a 3D panel beside the plots: in the inertial frame, drawing the body model (the
    # frames come from /tf), its frames those the view's /tf carries
    (three_d,) = [key for key in panels if key.startswith("3D!")]
    beside = layout["layout"]["first"]
    assert beside["direction"] == "row" and beside["first"] == three_d
    assert all(leaf.startswith("Plot!") or leaf.startswith("StateTransitions!") for leaf in leaves(beside["second"]))
    cfg = panels[three_d]
    assert cfg["followTf"] == "inertial"
    assert {"/" + t for t in VIEW_TOPICS} >= set(cfg["topics"]) and cfg["topics"]["/body_model"]["visible"]
    assert set(cfg["transforms"]) == {"frame:inertial", "frame:body", "frame:lvlh"}
