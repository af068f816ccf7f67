"""A step that does not complete names who it waits for, what came instead, and what may cause it.

The outside controller here is flight software as it is often written: it
caches its inputs and publishes on a wall-clock timer, stamping with its own
clock (rclpy and the message packages only). The stamped lockstep refuses
every command it sends (stamped about 1.8e9 s, not t_k), so step 0 never
completes: the run's lines must name the controller and ``voltage_cmd``,
the refused stamps, and the timer as the likely cause, at the first restart
and in the line that ends the run, within the plant's input timeout.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.errors import RunError
from attitude_sil.graph.session import run_graph, stall_culprit
from conftest import CONFIG, ROOT

TIMER_NODE = textwrap.dedent('''
    import rclpy
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    from rclpy.node import Node

    class TimerController(Node):
        def __init__(self):
            super().__init__("controller")
            self.q = None
            self.create_subscription(QuaternionStamped, "attitude", self.on_attitude, 10)
            self.pub = self.create_publisher(Vector3Stamped, "voltage_cmd", 10)
            self.create_timer(0.01, self.tick)

        def on_attitude(self, msg):
            self.q = msg.quaternion

        def tick(self):
            if self.q is None:
                return
            msg = Vector3Stamped()
            msg.header.stamp = self.get_clock().now().to_msg()  # its own clock, not the input's stamp
            msg.header.frame_id = "body"
            msg.vector.x = -10.0 * self.q.x
            self.pub.publish(msg)

    rclpy.init()
    node = TimerController()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
''')


def test_a_timer_driven_controller_under_the_stamped_lockstep_is_named(tmp_path, capfd):
    script = tmp_path / "timer_controller.py"
    script.write_text(TIMER_NODE)
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("plant", input_timeout=4.0)
    node = subprocess.Popen([sys.executable, str(script)], cwd=ROOT, stdin=subprocess.DEVNULL,
                            start_new_session=True, stderr=subprocess.PIPE, text=True)
    started = time.monotonic()
    try:
        try:
            run_graph(scn, duration=1.0, external=("controller",), progress=False)
            raise AssertionError("the episode completed without a command stamped t_k")
        except RunError as exc:
            line = str(exc)
    finally:
        os.killpg(node.pid, signal.SIGINT)
        node.communicate(timeout=60)
    elapsed = time.monotonic() - started
    err = capfd.readouterr().err
    expected = "the controller sent no voltage_cmd or torque_cmd or wheel_cmd stamped 0.000000 s ("
    # the end of the run: the plant's own line, the wall time into the episode, and the culprit
    assert line.startswith("plant: no wheel_torque, wheel_momentum for step t=0.000000 s"), line
    assert " s into the episode); " + expected in line, line
    assert "message(s) refused, the last stamped 17" in line and "none taken" in line, line
    assert line.endswith("a timer-driven node? see --external-timing, docs/flight-software.md"), line
    # the first restart said it already, with the time it had waited
    first = [x for x in err.splitlines() if x.startswith("attitude-sil: step 0 not complete after ")]
    assert len(first) == 1 and expected in first[0], err
    # every refused stamp got a line naming the stamp expected (the wheels', throttled)
    assert "voltage_cmd stamped 17" in err and "refused (mismatch); expected 0.000000 s" in err, err
    assert elapsed < 120  # a hang guard only: the run ends on the plant's 4 s timeout after its restarts


def test_the_culprit_is_the_first_role_whose_output_is_missing():
    class Recorder:  # what spin_episode reads of the recorder
        newest_stamp = {"attitude": 20, "attitude_setpoint": 20, "rate_setpoint": 20, "disturbance_torque": 20,
                        "voltage_cmd": 10, "wheel_torque": 10}
        refused = {"voltage_cmd": 3}
        refused_stamp = {"voltage_cmd": 5_000_000_000}

    topics = ["attitude", "attitude_setpoint", "rate_setpoint", "disturbance_torque", "wheel_torque",
              "wheel_momentum"]
    line = stall_culprit(Recorder(), topics)
    assert line.startswith("the controller sent no voltage_cmd or torque_cmd or wheel_cmd stamped 0.000000 s "
                           "(3 message(s) refused, the last stamped 5.000000 s; the newest taken stamped "
                           "0.000000 s)"), line
    assert stall_culprit(Recorder(), topics, refused_only=True) == line  # refused ones came: said at a restart
    Recorder.refused = {}
    assert stall_culprit(Recorder(), topics, refused_only=True) == ""  # a lost first message: a quiet restart
    Recorder.newest_stamp["voltage_cmd"] = 20  # the command came: the wheels are next
    assert stall_culprit(Recorder(), topics).startswith("the wheels sent no wheel_torque stamped 0.000000 s")
    Recorder.newest_stamp.update(wheel_torque=20, wheel_momentum=20)
    assert stall_culprit(Recorder(), topics) == ""
