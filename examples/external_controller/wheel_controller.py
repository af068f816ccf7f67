"""Flight software that shares its command among the wheels itself: one ``wheel_cmd`` a step.

It imports rclpy, numpy, the ROS message packages and the PID example beside it
(its ``spin`` and ``stamp_ns``) only. Run it in place of
the simulator's own controller:

    attitude-sil run config/hst_roll_step.yaml --external controller &
    python examples/external_controller/wheel_controller.py

For each step t_k it waits for ``attitude``, ``body_rate`` and
``attitude_setpoint`` stamped t_k, computes a body torque with a PD law on
the quaternion error and the body rate,

    tau = -Kp e - Kd omega,    e = vec(q_RN* q_BN) (scalar part made non-negative),

shares it among HST's four wheels by the pseudo-inverse of their spin axes
(paper 000 eq. 13-14; the wheels' motor torque T = -A+ tau, the body taking
the reaction -sum g_j T_j), and publishes it on ``wheel_cmd``
(sensor_msgs/JointState stamped t_k: ``name`` wheel_1 ... wheel_4, ``effort``
each wheel's motor torque, N m; docs/flight-software.md). A step it has
answered already is answered with the same command.
"""

from __future__ import annotations

import math

import numpy as np
import rclpy
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from pid_controller import spin, stamp_ns
from rclpy.node import Node
from sensor_msgs.msg import JointState

#: HST's wheel spin axes in B, one column a wheel (paper 000 eq. 13, as attitude_sil's hst_pyramid)
_S20, _C20, _R = math.sin(math.radians(20.0)), math.cos(math.radians(20.0)), math.sqrt(0.5)
HST_AXES = np.array([[-_S20 * _R, _S20 * _R, _S20 * _R, -_S20 * _R],
                     [-_C20 * _R, -_C20 * _R, _C20 * _R, _C20 * _R],
                     [_R, _R, _R, _R]])
NAMES = ["wheel_1", "wheel_2", "wheel_3", "wheel_4"]


def pd_wheel_torques(q_BN, omega_BN_B, q_RN, kp: float, kd: float, axes: np.ndarray = HST_AXES) -> np.ndarray:
    """Each wheel's motor torque (n,) N m for attitude ``q_BN``, rate ``omega_BN_B`` (rad/s) and setpoint
    ``q_RN`` (quaternions x, y, z, w): the PD body torque shared by the pseudo-inverse of ``axes`` (3, n)."""
    bx, by, bz, bw = q_BN
    rx, ry, rz, rw = -q_RN[0], -q_RN[1], -q_RN[2], q_RN[3]
    e = np.array([rw * bx + bw * rx + ry * bz - rz * by,
                  rw * by + bw * ry + rz * bx - rx * bz,
                  rw * bz + bw * rz + rx * by - ry * bx])
    if rw * bw - rx * bx - ry * by - rz * bz < 0.0:  # the short way round
        e = -e
    tau = -kp * e - kd * np.asarray(omega_BN_B, dtype=float)
    return -np.linalg.pinv(axes) @ tau


class WheelController(Node):
    """PD on the attitude error, its own allocation, one ``wheel_cmd`` per step of the lockstep."""

    def __init__(self) -> None:
        super().__init__("controller")
        self.declare_parameter("kp", 20.0)  # N m per unit quaternion error
        self.declare_parameter("kd", 60.0)  # N m s
        self.pub = self.create_publisher(JointState, "wheel_cmd", 10)
        self.create_subscription(QuaternionStamped, "attitude", lambda m: self.on_input("q", m), 10)
        self.create_subscription(QuaternionStamped, "attitude_setpoint", lambda m: self.on_input("r", m), 10)
        self.create_subscription(Vector3Stamped, "body_rate", lambda m: self.on_input("w", m), 10)
        self.pending: dict[int, dict[str, tuple]] = {}
        self.answered: dict[int, np.ndarray] = {}

    def on_input(self, key: str, msg) -> None:
        t = stamp_ns(msg.header.stamp)
        v = msg.quaternion if key != "w" else msg.vector
        slot = self.pending.setdefault(t, {})
        slot.setdefault(key, (v.x, v.y, v.z, v.w) if key != "w" else (v.x, v.y, v.z))
        if len(slot) < 3:
            return
        del self.pending[t]
        for old in [s for s in self.pending if s < t]:
            del self.pending[old]
        if t == 0:
            self.answered.clear()
        if t not in self.answered:
            self.answered[t] = pd_wheel_torques(slot["q"], slot["w"], slot["r"],
                                                self.get_parameter("kp").value, self.get_parameter("kd").value)
        out = JointState()
        out.header.stamp.sec, out.header.stamp.nanosec = divmod(t, 1_000_000_000)
        out.name = NAMES
        out.effort = [float(x) for x in self.answered[t]]
        self.pub.publish(out)


def main() -> int:
    rclpy.init()
    return spin(WheelController())


if __name__ == "__main__":
    raise SystemExit(main())
