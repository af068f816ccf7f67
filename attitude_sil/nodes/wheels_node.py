"""``wheels`` node: the reaction-wheel DC motors.

On ``voltage_cmd`` (or ``torque_cmd``, turned into voltages by the inverse
motor model) stamped t_k it integrates the motors exactly over
``[t_k, t_k+1]`` with the voltage held (:class:`attitude_sil.core.engine.Wheels`)
and publishes, stamped t_k: ``wheel_torque`` (mean torque on the body over the
step, so momentum is exchanged exactly), ``wheel_momentum`` (h_w at t_k, in B)
and ``wheel_state`` (per wheel angle, speed and motor torque at t_k).
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import JointState

from attitude_sil.core.engine import build_wheels
from attitude_sil.nodes.common import LOCKSTEP_QOS, SchemaNode, StepSequencer, run_node, stamp_to_ns


class WheelsNode(SchemaNode):
    """Reaction-wheel assembly in lockstep; see the module docstring."""

    schema_name = "wheels"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_torque = self.create_publisher(Vector3Stamped, "wheel_torque", LOCKSTEP_QOS)
        self.pub_momentum = self.create_publisher(Vector3Stamped, "wheel_momentum", LOCKSTEP_QOS)
        self.pub_state = self.create_publisher(JointState, "wheel_state", LOCKSTEP_QOS)
        self.create_subscription(Vector3Stamped, "voltage_cmd", lambda m: self._on_command(m, False), LOCKSTEP_QOS)
        self.create_subscription(Vector3Stamped, "torque_cmd", lambda m: self._on_command(m, True), LOCKSTEP_QOS)
        self.seq = StepSequencer()
        self._rebuild()

    def _rebuild(self) -> None:
        scn = self.scenario()
        self.core = build_wheels(scn, 1)
        self.dt_ns = int(round(self.param("control_period") * 1e9))

    def _on_command(self, msg: Vector3Stamped, torque_mode: bool) -> None:
        t = stamp_to_ns(msg.header.stamp)
        kind = self.seq.classify(t, self.dt_ns)
        if kind == StepSequencer.NEW:
            self._rebuild()
        elif kind == StepSequencer.DUPLICATE:
            return
        elif kind == StepSequencer.MISMATCH:
            self.get_logger().error(
                f"command stamped {t * 1e-9:.6f} s does not follow {self.seq.last_ns * 1e-9:.6f} s; ignored")
            return
        v = np.array([[msg.vector.x, msg.vector.y, msg.vector.z]])
        if not self.finite(v):
            self.get_logger().error(f"command at t={t * 1e-9:.6f} s is not finite: {v[0].tolist()}; ignored")
            return
        out = self.core.advance(v, torque_mode)
        stamp = msg.header.stamp
        for pub, vec in ((self.pub_torque, out.tau_c_B[0]), (self.pub_momentum, out.h_wheels_B[0])):
            m = Vector3Stamped()
            m.header.stamp = stamp
            m.header.frame_id = "body"
            m.vector.x, m.vector.y, m.vector.z = (float(x) for x in vec)
            pub.publish(m)
        js = JointState()
        js.header.stamp = stamp
        js.name = self.core.names
        js.position = out.position[0].tolist()
        js.velocity = out.velocity[0].tolist()
        js.effort = out.effort[0].tolist()
        self.pub_state.publish(js)


def main(args: list[str] | None = None) -> int:
    """Console script ``wheels_node``."""
    return run_node(WheelsNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
