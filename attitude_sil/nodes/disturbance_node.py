"""``disturbance`` node: external torques of paper 000 section 2.A.

On ``attitude`` stamped t_k it publishes ``disturbance_torque`` stamped t_k,
held over the step (:class:`attitude_sil.core.plant.disturbance.DisturbanceModel`).
With ``models: []`` (the default) it publishes zeros, so the lockstep has
every input whatever the scenario.
"""

from __future__ import annotations

from attitude_sil.core.plant.quaternion import unit_or_none
from attitude_sil.core.sim.build import build_disturbance
from attitude_sil.ros.contract import ATTITUDE, DISTURBANCE_TORQUE
from attitude_sil.ros.convert import quaternion_to_array, stamp_to_ns
from attitude_sil.ros.node import LockstepNode, run_node
from attitude_sil.storage.cdr import stamped_vector_cdr


class DisturbanceNode(LockstepNode):
    """Disturbance torques in lockstep; see the module docstring."""

    schema_name = "disturbance"
    step_inputs = ()

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub = self.step_publisher(DISTURBANCE_TORQUE)
        self.step_subscription(ATTITUDE, self._on_attitude)
        self.new_episode()

    def rebuild(self) -> None:
        scn = self.scenario()
        self.core = build_disturbance(scn, 1)

    def _on_attitude(self, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        q = unit_or_none(quaternion_to_array(msg)[None])  # None for a non-finite or non-unit quaternion
        if q is None:  # before sequencing: a refused message must not take the step's place
            self.get_logger().error(f"attitude at t={t * 1e-9:.6f} s is not a finite unit quaternion; ignored",
                                    throttle_duration_sec=1.0)
            return
        if not self.in_sequence(ATTITUDE, t):
            return
        tau = self.core.torque(q, t)[0]
        self.pub.publish(stamped_vector_cdr(tau, t, "body"))


def main(args: list[str] | None = None) -> int:
    """Console script ``disturbance_node``."""
    return run_node(DisturbanceNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
