"""``controller`` node: the attitude control laws, swappable at runtime.

Once it holds ``attitude``, ``body_rate``, ``attitude_setpoint`` and
``rate_setpoint`` all stamped t_k, it computes the command of the active law
(:class:`attitude_sil.core.control.bank.ControllerBank`) and publishes, stamped
t_k, ``voltage_cmd`` (V, body axes) or ``torque_cmd`` (N m), as the law's
``output`` and the ``command`` parameter say, and ``attitude_error`` (roll,
pitch, yaw of the rotation still to go, setpoint minus attitude, rad). The
laws are the registry's (:mod:`attitude_sil.core.control.registry`).

``controller_type`` and every gain may change while the graph runs (``ros2
param set`` or ``attitude-sil param set``). A new type takes over at the next
step, bumplessly as the bank documents; new gains apply from the next step and
keep the controllers' states. Invalid values are refused with a reason naming
the parameter and the rule; the controller keeps running on its old values.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.control.momentum import BDOT
from attitude_sil.core.plant.quaternion import euler_from_quat, quat_conjugate, quat_error
from attitude_sil.core.sim.build import build_controller, build_dipole_command
from attitude_sil.core.sim.lockstep import StepInputs, StepSequencer
from attitude_sil.ros.contract import (
    ATTITUDE,
    ATTITUDE_ERROR,
    ATTITUDE_SETPOINT,
    COMMAND_TOPIC,
    CONTROLLER_INPUTS,
    DIPOLE_CMD,
    DUMPING_INPUTS,
    MAGNETIC_FIELD,
    WHEEL_MOMENTUM,
)
from attitude_sil.ros.convert import message_to_array, stamp_to_ns
from attitude_sil.ros.node import LockstepNode, run_node
from attitude_sil.storage.cdr import stamped_vector_cdr

INPUTS = CONTROLLER_INPUTS


class ControllerNode(LockstepNode):
    """Attitude controller in lockstep; see the module docstring."""

    schema_name = "controller"
    step_inputs = INPUTS

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_cmd = {kind: self.step_publisher(topic) for kind, topic in COMMAND_TOPIC.items()}
        self.pub_err = self.step_publisher(ATTITUDE_ERROR)
        for name in INPUTS:
            self.step_subscription(name, lambda m, n=name: self._on_input(n, message_to_array(m)[None], m))
        if self.param("magnetorquers"):
            self.pub_dipole = self.step_publisher(DIPOLE_CMD)
            # its own stream of steps: the step's field comes with its state, the momentum after its command
            self.dumping, self.dumping_seq = StepInputs(DUMPING_INPUTS), StepSequencer()
            for name in DUMPING_INPUTS:
                self.step_subscription(name, lambda m, n=name: self._on_dumping(n, message_to_array(m)[None], m))
        self.new_episode()

    def rebuild(self) -> None:
        scn = self.scenario()
        self.core = build_controller(scn, 1)
        self.magnetic = build_dipole_command(scn)
        self.demand: tuple[int, np.ndarray] | None = None  # (stamp ns, the law's command (1, 3)) of the last step

    def check_parameters(self, pending: dict) -> str:
        """B-dot commands the magnetorquers: a swap to it where they do not fly is refused."""
        if pending.get("controller_type") == BDOT and not pending.get("magnetorquers", self.param("magnetorquers")):
            return ("controller_type bdot commands the magnetorquers, which this graph does not fly (start it from "
                    "a scenario with bdot among its laws or controller momentum.mode set)")
        return ""

    def on_parameters_set(self, names: list[str]) -> None:
        v = self.values()
        self.core.configure(v)
        if any(n.startswith("momentum.") for n in names):  # B-dot's difference goes on where it was
            self.magnetic.dumping = build_dipole_command(self.scenario()).dumping
        if "controller_type" in names:
            self.core.request(v["controller_type"])
            self.get_logger().info(f"controller_type -> {v['controller_type']} at the next step")

    def _on_input(self, name: str, value: np.ndarray, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        slot = self.gather(name, value, t)
        if slot is None:
            return
        k = t // self.dt_ns
        u = self.core.compute(*(slot[name] for name in INPUTS), k)
        if not self.finite(u):  # published as made: the wheels refuse it, the runner stops the episode naming the law
            self.get_logger().error(f"controller_type {self.core.active} commanded non-finite values "
                                    f"{u[0].tolist()} at step {k} (t={t * 1e-9:.6f} s)", throttle_duration_sec=1.0)
        err = euler_from_quat(quat_conjugate(quat_error(slot[ATTITUDE], slot[ATTITUDE_SETPOINT])))
        self.demand = (t, u)  # the rods' torque demand, where they make it
        self.pub_cmd[self.core.kind].publish(stamped_vector_cdr(u[0], t, "body"))
        self.pub_err.publish(stamped_vector_cdr(err[0], t, "body"))

    def _on_dumping(self, name: str, value: np.ndarray, msg) -> None:
        # its own stream of steps; a new episode drops what an aborted one left half-gathered (the next step's
        # field cannot come before this step's dipole, which the plant waits for through the rods)
        t = stamp_to_ns(msg.header.stamp)
        slot = self.gather(name, value, t, self.dumping, self.dumping_seq, self.dumping.pending.clear)
        if slot is None:
            return
        # this step's command came first: the wheels' momentum at t follows it
        tau = self.demand[1] if self.demand is not None and self.demand[0] == t else None
        if tau is None and self.magnetic.torque_rods:
            self.get_logger().error(f"no torque demand of step t={t * 1e-9:.6f} s for the rods; zero dipole",
                                    throttle_duration_sec=1.0)
            tau = np.zeros((1, 3))
        m = self.magnetic.dipole(self.core.active, slot[WHEEL_MOMENTUM], slot[MAGNETIC_FIELD], tau)
        self.pub_dipole.publish(stamped_vector_cdr(m[0], t, "body"))


def main(args: list[str] | None = None) -> int:
    """Console script ``controller_node``."""
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
