"""A controller node that knows nothing of attitude_sil but its topics: flight software in the loop.

It imports rclpy and the ROS message packages only, and uses the QoS every
ROS tutorial uses (``10``: reliable, volatile, depth 10). Run it in place of
the simulator's own controller:

    attitude-sil run config/hst_roll_step.yaml --external controller &
    python examples/external_controller/pid_controller.py

The per-step contract it follows (docs/flight-software.md):

* it waits, for each step t_k, for ``attitude`` (geometry_msgs/QuaternionStamped,
  q_BN, x y z w) and ``attitude_setpoint`` (q_RN) both stamped t_k; the
  simulator publishes them (and ``body_rate``, ``rate_setpoint``) once per
  step and then waits for the command;
* it publishes one ``voltage_cmd`` (geometry_msgs/Vector3Stamped, body axes,
  V) stamped t_k, the stamp of the inputs it answers;
* a step stamped 0 starts an episode: the controller state is reset. A step
  it has answered already (the same stamp again) is answered with the same
  command, not computed twice.

The law is paper 000's PID, the arithmetic of attitude_sil's ``pid`` law
(``e = -vec(q_RN* q_BN)`` with a non-negative scalar part, a first-order
derivative filter ``N/(s + N)``; the command held over a period is the
mean over that period of the continuous PID's output for the held error:
derivative ``(1 - a)/dt (e - x_f)`` with ``a = exp(-N dt)``, integral
``I + e dt/2``; conditional integration at the output limit), so
a run with this node gives the built-in law's numbers. ``compute_delay``
(s) makes each step take that long, as slow flight software would.
``declare_failed_wheel`` (1..n; 0: none) and ``declare_failed_at`` (s) stand
for the flight software's own FDIR: at the first step from that time it
declares that wheel failed on ``wheel_status`` (diagnostic_msgs/DiagnosticArray,
level ERROR, ``hardware_id`` ``wheel<n>``, stamped t_k), and the simulator's
wheels share the commands from the next step among the others
(``wheels.allocation: available``).
"""

from __future__ import annotations

import math
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

HST_GA_GAINS = {"kp": 48.894, "ki": 0.071, "kd": 106.046, "n": 1.427}  # paper 000, the GA design


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class Pid:
    """Paper 000's per-axis PID on the quaternion error, the arithmetic of attitude_sil's ``pid`` law."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.integral = [0.0, 0.0, 0.0]
        self.filt = [0.0, 0.0, 0.0]

    def step(self, q_BN: tuple, q_RN: tuple, p: dict, u_max: float, dt: float) -> tuple[float, float, float]:
        """The command (V per body axis) held over the next ``dt`` s for attitude ``q_BN`` and setpoint
        ``q_RN`` (x, y, z, w), with gains ``p`` (kp, ki, kd, n: 3 values each) and the limit ``u_max`` V."""
        bx, by, bz, bw = q_BN
        rx, ry, rz, rw = -q_RN[0], -q_RN[1], -q_RN[2], q_RN[3]
        e = [rw * bx + bw * rx + ry * bz - rz * by,
             rw * by + bw * ry + rz * bx - rx * bz,
             rw * bz + bw * rz + rx * by - ry * bx]
        ew = rw * bw - rx * bx - ry * by - rz * bz
        e = [x if ew < 0.0 else -x for x in e]  # -vec(q_BR), the short way round
        u = []
        for i in range(3):
            a = math.exp(-p["n"][i] * dt)
            deriv = (1.0 - a) / dt * (e[i] - self.filt[i])  # mean of N (e - x_f(t)) over the period
            raw = p["kp"][i] * e[i] + p["ki"][i] * (self.integral[i] + 0.5 * e[i] * dt) + p["kd"][i] * deriv
            out = min(max(raw, -u_max), u_max)
            if not (out != raw and e[i] * raw > 0.0):  # no integration into the limit
                self.integral[i] += e[i] * dt
            self.filt[i] = a * self.filt[i] + (1.0 - a) * e[i]
            u.append(out)
        return u[0], u[1], u[2]


class PidController(Node):
    """Per-axis PID on the quaternion error, one command per step of the simulator's lockstep."""

    def __init__(self) -> None:
        super().__init__("controller")
        for name, value in HST_GA_GAINS.items():
            self.declare_parameter(name, [value] * 3)
        self.declare_parameter("output_limit", 314.79)  # V, the HST preset's drive
        self.declare_parameter("control_period", 0.01)  # s
        self.declare_parameter("compute_delay", 0.0)  # s, simulated computation time per step
        self.declare_parameter("declare_failed_wheel", 0)  # 1..n: a wheel this flight software's FDIR fails
        self.declare_parameter("declare_failed_at", 0.0)  # s
        self.pub_status = self.create_publisher(DiagnosticArray, "wheel_status", 10)
        self.pub = self.create_publisher(Vector3Stamped, "voltage_cmd", 10)
        self.create_subscription(QuaternionStamped, "attitude", lambda m: self.on_input("q", m), 10)
        self.create_subscription(QuaternionStamped, "attitude_setpoint", lambda m: self.on_input("r", m), 10)
        self.pending: dict[int, dict[str, tuple]] = {}
        self.answered: dict[int, tuple[float, float, float]] = {}
        self.law = Pid()

    def reset(self) -> None:
        self.law.reset()
        self.answered.clear()

    def on_input(self, key: str, msg: QuaternionStamped) -> None:
        t = stamp_ns(msg.header.stamp)
        q = msg.quaternion
        slot = self.pending.setdefault(t, {})
        slot.setdefault(key, (q.x, q.y, q.z, q.w))
        if len(slot) < 2:
            return
        del self.pending[t]
        for old in [s for s in self.pending if s < t]:
            del self.pending[old]
        if t in self.answered and t != 0:
            u = self.answered[t]  # a repeat of a step answered already: the same command
        else:
            if t == 0:
                self.reset()
            gains = {name: self.get_parameter(name).value for name in HST_GA_GAINS}
            u = self.law.step(slot["q"], slot["r"], gains, self.get_parameter("output_limit").value,
                              self.get_parameter("control_period").value)
            self.answered[t] = u
        self.declare_failure(t)
        delay = self.get_parameter("compute_delay").value
        if delay > 0.0:
            time.sleep(delay)  # stands for the flight software's own computation
        out = Vector3Stamped()
        out.header.stamp.sec, out.header.stamp.nanosec = divmod(t, 1_000_000_000)
        out.header.frame_id = "body"
        out.vector.x, out.vector.y, out.vector.z = u
        self.pub.publish(out)

    def declare_failure(self, t: int) -> None:
        """Step ``t`` (ns): at the first step from ``declare_failed_at``, say the wheel failed on ``wheel_status``."""
        wheel = self.get_parameter("declare_failed_wheel").value
        at_ns = round(self.get_parameter("declare_failed_at").value * 1e9)
        dt_ns = round(self.get_parameter("control_period").value * 1e9)
        if wheel < 1 or not at_ns <= t < at_ns + dt_ns:
            return
        status = DiagnosticStatus(level=DiagnosticStatus.ERROR, name=f"flight software: wheel{wheel}",
                                  hardware_id=f"wheel{wheel}", message="failed")
        msg = DiagnosticArray(status=[status])
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
        self.pub_status.publish(msg)


def spin(node: Node) -> int:
    """Spin ``node`` until Ctrl-C or a shutdown, then destroy it and shut rclpy down: exit code 0."""
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main() -> int:
    rclpy.init()
    return spin(PidController())


if __name__ == "__main__":
    raise SystemExit(main())
