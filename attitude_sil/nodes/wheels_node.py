"""``wheels`` node: the reaction-wheel DC motors.

On ``voltage_cmd`` (or ``torque_cmd``, turned into voltages by the inverse
motor model) stamped t_k it integrates the motors exactly over
``[t_k, t_k+1]`` with the voltage held (:class:`attitude_sil.core.sim.models.Wheels`)
and publishes, stamped t_k: ``wheel_torque`` (mean torque on the body over the
step, so momentum is exchanged exactly), ``wheel_momentum`` (h_w at t_k, in B)
and ``wheel_state`` (per wheel angle, speed and motor torque at t_k).
"""

from __future__ import annotations

from attitude_sil.core.sim.build import build_wheels
from attitude_sil.core.sim.lockstep import StepSequencer
from attitude_sil.ros.contract import TORQUE_CMD, VOLTAGE_CMD, WHEEL_MOMENTUM, WHEEL_STATE, WHEEL_TORQUE
from attitude_sil.ros.convert import stamp_to_ns, vector_to_array
from attitude_sil.ros.node import LockstepNode, run_node
from attitude_sil.storage.cdr import joint_state_cdr, stamped_vector_cdr


class WheelsNode(LockstepNode):
    """Reaction-wheel assembly in lockstep; see the module docstring."""

    schema_name = "wheels"
    step_inputs = ()

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_torque = self.step_publisher(WHEEL_TORQUE)
        self.pub_momentum = self.step_publisher(WHEEL_MOMENTUM)
        self.pub_state = self.step_publisher(WHEEL_STATE)
        self.step_subscription(VOLTAGE_CMD, lambda m: self._on_command(m, False))
        self.step_subscription(TORQUE_CMD, lambda m: self._on_command(m, True))
        self.new_episode()

    def rebuild(self) -> None:
        scn = self.scenario()
        self.core = build_wheels(scn, 1)

    def _on_command(self, msg, torque_mode: bool) -> None:
        t = stamp_to_ns(msg.header.stamp)
        v = vector_to_array(msg)[None]
        if not self.finite(v):  # before sequencing: a refused message must not take the step's place
            self.get_logger().error(f"command at t={t * 1e-9:.6f} s is not finite: {v[0].tolist()}; ignored",
                                    throttle_duration_sec=1.0)
            return
        kind = self.seq.classify(t, self.dt_ns)
        if kind == StepSequencer.NEW:
            self.new_episode()
        elif kind != StepSequencer.NEXT:
            self.refuse_stamp(TORQUE_CMD if torque_mode else VOLTAGE_CMD, t, kind)
            return
        out = self.core.advance(v, torque_mode)
        self.pub_torque.publish(stamped_vector_cdr(out.tau_c_B[0], t, "body"))
        self.pub_momentum.publish(stamped_vector_cdr(out.h_wheels_B[0], t, "body"))
        self.pub_state.publish(joint_state_cdr(self.core.names, out.position[0], out.velocity[0], out.effort[0], t))


def main(args: list[str] | None = None) -> int:
    """Console script ``wheels_node``."""
    return run_node(WheelsNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
