"""``magnetorquers`` node: the magnetic torquer rods.

Once it holds ``dipole_cmd`` (the controller's body dipole, A m^2) and
``magnetic_field`` (the plant's true field in B, tesla) stamped t_k, it shares
the dipole among its rods (``rods.axes``), saturates each at
``rods.max_dipole`` and publishes ``magnetic_torque`` = m x B (N m in B)
stamped t_k, held over the step, which the plant takes in lockstep
(:class:`attitude_sil.core.plant.magnetorquers.Magnetorquers`). The runner
starts it where the controller commands a dipole (``momentum.mode``, or
``bdot`` among its laws).
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.sim.build import build_magnetorquers
from attitude_sil.ros.contract import DIPOLE_CMD, MAGNETIC_FIELD, MAGNETIC_TORQUE
from attitude_sil.ros.convert import message_to_array, stamp_to_ns
from attitude_sil.ros.node import LockstepNode, run_node
from attitude_sil.storage.cdr import stamped_vector_cdr

INPUTS = (DIPOLE_CMD, MAGNETIC_FIELD)


class MagnetorquersNode(LockstepNode):
    """Magnetic torquer rods in lockstep; see the module docstring."""

    schema_name = "magnetorquers"
    step_inputs = INPUTS

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub = self.step_publisher(MAGNETIC_TORQUE)
        for name in INPUTS:
            self.step_subscription(name, lambda m, n=name: self._on_input(n, message_to_array(m)[None], m))
        self.new_episode()

    def rebuild(self) -> None:
        self.core = build_magnetorquers(self.scenario())

    def _on_input(self, name: str, value: np.ndarray, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        slot = self.gather(name, value, t)
        if slot is None:
            return
        tau = self.core.torque(slot[DIPOLE_CMD], slot[MAGNETIC_FIELD])
        self.pub.publish(stamped_vector_cdr(tau[0], t, "body"))


def main(args: list[str] | None = None) -> int:
    """Console script ``magnetorquers_node``."""
    return run_node(MagnetorquersNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
