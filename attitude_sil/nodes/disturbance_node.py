"""``disturbance`` node: external torques of paper 000 section 2.A.

On ``attitude`` stamped t_k it publishes ``disturbance_torque`` stamped t_k,
held over the step (:class:`attitude_sil.core.disturbance.DisturbanceModel`).
With ``models: []`` (the default) it publishes zeros, so the lockstep has
every input whatever the scenario.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped

from attitude_sil.core.engine import build_disturbance
from attitude_sil.nodes.common import LOCKSTEP_QOS, SchemaNode, StepSequencer, run_node, stamp_to_ns


class DisturbanceNode(SchemaNode):
    """Disturbance torques in lockstep; see the module docstring."""

    schema_name = "disturbance"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub = self.create_publisher(Vector3Stamped, "disturbance_torque", LOCKSTEP_QOS)
        self.create_subscription(QuaternionStamped, "attitude", self._on_attitude, LOCKSTEP_QOS)
        self.seq = StepSequencer()
        self._rebuild()

    def _rebuild(self) -> None:
        scn = self.scenario()
        self.core = build_disturbance(scn, 1)
        self.dt_ns = int(round(self.param("control_period") * 1e9))

    def _on_attitude(self, msg: QuaternionStamped) -> None:
        t = stamp_to_ns(msg.header.stamp)
        kind = self.seq.classify(t, self.dt_ns)
        if kind == StepSequencer.NEW:
            self._rebuild()
        elif kind != StepSequencer.NEXT:
            return
        q = msg.quaternion
        tau = self.core.torque(np.array([[q.x, q.y, q.z, q.w]]), t)[0]
        out = Vector3Stamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = "body"
        out.vector.x, out.vector.y, out.vector.z = (float(x) for x in tau)
        self.pub.publish(out)


def main(args: list[str] | None = None) -> int:
    """Console script ``disturbance_node``."""
    return run_node(DisturbanceNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
