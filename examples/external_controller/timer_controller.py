"""Flight software as it is usually written: a node that caches its inputs and computes on a timer.

It knows nothing of attitude_sil but its topics (rclpy and the message
packages only, QoS ``10``), and it is the same code on either clock:

* on sim time, in lockstep and deterministic (``use_sim_time`` true)::

    attitude-sil run config/hst_roll_step.yaml --external controller --external-timing sim_timer &
    python examples/external_controller/timer_controller.py --ros-args -p use_sim_time:=true

* on the wall clock, the simulator paced at real time::

    attitude-sil run config/hst_roll_step.yaml --external controller --external-timing wall --real-time &
    python examples/external_controller/timer_controller.py

What it does, as a cFS app, an F' rate group or a ros2_control update loop
would:

* it keeps the newest ``attitude`` and ``attitude_setpoint`` it has received,
  subscribing with depth 1 (reliable): a latest-value buffer, as a flight
  computer reads its sensor registers. With the tutorials' depth 10 a node
  whose timer is slower than the simulator's steps can fall behind the
  queue (an executor takes one message per subscription per round, timers
  first) and compute from inputs a few steps old;
* every ``1/rate`` s of its clock (``create_timer``) it computes paper 000's
  PID (:class:`pid_controller.Pid`, the arithmetic of attitude_sil's ``pid``
  law, with the timer's period as its step) and publishes ``voltage_cmd``
  stamped with its clock's ``now()``;
* an ``attitude`` stamped earlier than the one before means the simulation
  started a new episode: the law's state is reset;
* a tick at a time it has computed already (the plant sent ``/clock`` 0
  and the tick's time again, to bring a timer that missed the jump back
  to 0 into phase) sends the same command again: the law steps once a tick.
"""

from __future__ import annotations

import rclpy
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from pid_controller import HST_GA_GAINS, Pid, spin, stamp_ns
from rclpy.node import Node


class TimerController(Node):
    """Per-axis PID on the quaternion error, computed on a timer from the newest inputs."""

    def __init__(self) -> None:
        super().__init__("controller")
        for name, value in HST_GA_GAINS.items():
            self.declare_parameter(name, [value] * 3)
        self.declare_parameter("output_limit", 314.79)  # V, the HST preset's drive
        self.declare_parameter("rate", 100.0)  # Hz, the timer's rate
        self.pub = self.create_publisher(Vector3Stamped, "voltage_cmd", 10)
        self.create_subscription(QuaternionStamped, "attitude", self.on_attitude, 1)
        self.create_subscription(QuaternionStamped, "attitude_setpoint", self.on_setpoint, 1)
        self.q_BN: tuple | None = None
        self.q_RN: tuple | None = None
        self.last_stamp = -1
        self.last_tick: tuple[int, Vector3Stamped] | None = None  # (sim time ns, command) of the latest tick
        self.law = Pid()
        self.period = 1.0 / self.get_parameter("rate").value
        self.create_timer(self.period, self.tick)

    def on_attitude(self, msg: QuaternionStamped) -> None:
        t = stamp_ns(msg.header.stamp)
        if t < self.last_stamp:  # the simulation started again
            self.law.reset()
        self.last_stamp = t
        q = msg.quaternion
        self.q_BN = (q.x, q.y, q.z, q.w)

    def on_setpoint(self, msg: QuaternionStamped) -> None:
        q = msg.quaternion
        self.q_RN = (q.x, q.y, q.z, q.w)

    def tick(self) -> None:
        if self.q_BN is None or self.q_RN is None:
            return  # nothing to fly yet
        now = self.get_clock().now()
        if self.last_tick is not None and self.last_tick[0] == now.nanoseconds:
            self.pub.publish(self.last_tick[1])  # this tick again: its command, the law not stepped twice
            return
        gains = {name: self.get_parameter(name).value for name in HST_GA_GAINS}
        u = self.law.step(self.q_BN, self.q_RN, gains, self.get_parameter("output_limit").value, self.period)
        out = Vector3Stamped()
        out.header.stamp = now.to_msg()
        out.header.frame_id = "body"
        out.vector.x, out.vector.y, out.vector.z = u
        self.last_tick = (now.nanoseconds, out)
        self.pub.publish(out)


def main() -> int:
    rclpy.init()
    return spin(TimerController())


if __name__ == "__main__":
    raise SystemExit(main())
