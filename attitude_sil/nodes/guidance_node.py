"""``guidance`` node: the attitude and rate setpoints.

For each step the plant publishes (its ``attitude``, stamped t_k) it publishes
``attitude_setpoint`` (q_RN, frame ``inertial``) and ``rate_setpoint``
(omega_RN in R, rad/s) stamped t_k
(:class:`attitude_sil.core.sim.models.Guidance`: a step from
``initial_setpoint_rpy_deg`` to ``setpoint_rpy_deg`` at ``step_time``).
Setpoint parameters changed at runtime apply from the next step. It follows
``attitude`` rather than ``/clock`` because a plant whose controller runs on
a sim-time timer publishes ``/clock`` only once the setpoints are out
(``command_timing: sim_timer``); at a tick of that timer (``command_rate``)
the setpoints go out acknowledged by every reader, so the tick finds them
delivered.
"""

from __future__ import annotations

from attitude_sil.core.sim.build import build_guidance
from attitude_sil.core.sim.lockstep import is_tick, tick_period_ns
from attitude_sil.ros.contract import ATTITUDE, ATTITUDE_SETPOINT, RATE_SETPOINT
from attitude_sil.ros.convert import stamp_to_ns
from attitude_sil.ros.node import SchemaNode, run_node
from attitude_sil.storage.cdr import stamped_vector_cdr


class GuidanceNode(SchemaNode):
    """Setpoint source in lockstep; see the module docstring."""

    schema_name = "guidance"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_q = self.step_publisher(ATTITUDE_SETPOINT)
        self.pub_w = self.step_publisher(RATE_SETPOINT)
        self.step_subscription(ATTITUDE, self._on_step)
        self.on_parameters_set([])

    def on_parameters_set(self, names: list[str]) -> None:
        scn = self.scenario()
        self.core = build_guidance(scn, 1)
        # a controller on a sim-time timer: its ticks must find the setpoints delivered (0: no ticks to serve)
        self.tick_ns = tick_period_ns(self.param("command_timing"), self.param("command_rate"),
                                      int(round(scn.dt * 1e9)))

    def _on_step(self, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        q_RN, w_RN = self.core.setpoint(t * 1e-9)
        self.pub_q.publish(stamped_vector_cdr(q_RN[0], t, "inertial"))
        self.pub_w.publish(stamped_vector_cdr(w_RN[0], t, "reference"))
        if is_tick(t, self.tick_ns):
            self.await_readers((self.pub_q, self.pub_w), t)


def main(args: list[str] | None = None) -> int:
    """Console script ``guidance_node``."""
    return run_node(GuidanceNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
