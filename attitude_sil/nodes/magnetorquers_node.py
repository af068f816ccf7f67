"""``magnetorquers`` node: the magnetic torquer rods.

Once it holds ``dipole_cmd`` (the controller's body dipole, A m^2) and
``magnetic_field`` (the plant's true field in B, tesla) stamped t_k, it shares
the dipole among its rods (``rods.axes``), saturates each at
``rods.max_dipole`` and publishes ``magnetic_torque`` = m x B (N m in B)
stamped t_k, held over the step, which the plant takes in lockstep
(:class:`attitude_sil.core.plant.magnetorquers.Magnetorquers`). The runner
starts it where the controller commands a dipole (``momentum.mode``, or
``bdot`` among its laws). It flies the rods' faults (``magnetorquers off`` or
``stuck``, docs/faults.md), scheduled or added while the graph runs, and says
each on ``/diagnostics``.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.faults import first_step
from attitude_sil.core.sim.build import build_magnetorquers
from attitude_sil.errors import ScenarioError
from attitude_sil.ros.contract import DIPOLE_CMD, MAGNETIC_FIELD, MAGNETIC_TORQUE
from attitude_sil.ros.convert import message_to_array, stamp_to_ns
from attitude_sil.ros.node import LockstepNode, NodeFaults, run_node
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
        self.faults = NodeFaults(self, "magnetorquers")  # rebuild() resets it
        self.k = -1  # the latest step taken
        self.new_episode()

    def rebuild(self) -> None:
        self.core = build_magnetorquers(self.scenario())
        self.faults.reset()
        self.k = -1

    def check_parameters(self, pending: dict) -> str:
        """Faults may only be added, and must be the rods'."""
        if "faults" not in pending:
            return ""
        try:
            return self.faults.refusal(pending["faults"])
        except ScenarioError as exc:
            return str(exc)

    def on_parameters_set(self, names: list[str]) -> None:
        if "faults" in names:  # each from its time, or from the step after the one taken last
            for fault in self.faults.added():
                step = max(first_step(fault.time_s, self.dt_ns), self.k + 1)
                self.core.faults.add(fault, self.dt_ns, step)
                self.faults.started(fault, step, self.dt_ns)

    def _on_input(self, name: str, value: np.ndarray, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        slot = self.gather(name, value, t)
        if slot is None:
            return
        self.k = t // self.dt_ns
        tau = self.core.torque(self.core.command_at(slot[DIPOLE_CMD], self.k), slot[MAGNETIC_FIELD])
        self.pub.publish(stamped_vector_cdr(tau[0], t, "body"))
        self.faults.say(t, self.dt_ns)


def main(args: list[str] | None = None) -> int:
    """Console script ``magnetorquers_node``."""
    return run_node(MagnetorquersNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
