"""``guidance`` node: the attitude and rate setpoints.

On each ``/clock`` tick t_k it publishes ``attitude_setpoint`` (q_RN, frame
``inertial``) and ``rate_setpoint`` (omega_RN in R, rad/s) stamped t_k
(:class:`attitude_sil.core.engine.Guidance`: a step from
``initial_setpoint_rpy_deg`` to ``setpoint_rpy_deg`` at ``step_time``).
Setpoint parameters changed at runtime apply from the next tick.
"""

from __future__ import annotations

from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rosgraph_msgs.msg import Clock

from attitude_sil.core.engine import build_guidance
from attitude_sil.nodes.common import LOCKSTEP_QOS, SchemaNode, run_node, stamp_to_ns


class GuidanceNode(SchemaNode):
    """Setpoint source in lockstep; see the module docstring."""

    schema_name = "guidance"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_q = self.create_publisher(QuaternionStamped, "attitude_setpoint", LOCKSTEP_QOS)
        self.pub_w = self.create_publisher(Vector3Stamped, "rate_setpoint", LOCKSTEP_QOS)
        self.create_subscription(Clock, "/clock", self._on_clock, LOCKSTEP_QOS)
        self.on_parameters_set([])

    def on_parameters_set(self, names: list[str]) -> None:
        self.core = build_guidance(self.scenario(), 1)

    def _on_clock(self, msg: Clock) -> None:
        t = stamp_to_ns(msg.clock)
        q_RN, w_RN = self.core.setpoint(t * 1e-9)
        q = QuaternionStamped()
        q.header.stamp = msg.clock
        q.header.frame_id = "inertial"
        q.quaternion.x, q.quaternion.y, q.quaternion.z, q.quaternion.w = (float(v) for v in q_RN[0])
        self.pub_q.publish(q)
        w = Vector3Stamped()
        w.header.stamp = msg.clock
        w.header.frame_id = "reference"
        w.vector.x, w.vector.y, w.vector.z = (float(v) for v in w_RN[0])
        self.pub_w.publish(w)


def main(args: list[str] | None = None) -> int:
    """Console script ``guidance_node``."""
    return run_node(GuidanceNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
