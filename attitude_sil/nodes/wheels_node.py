"""``wheels`` node: the reaction-wheel DC motors.

On ``voltage_cmd`` (or ``torque_cmd``, turned into voltages by the inverse
motor model) stamped t_k it integrates the motors exactly over
``[t_k, t_k+1]`` with the voltage held (:class:`attitude_sil.core.sim.models.Wheels`)
and publishes, stamped t_k: ``wheel_torque`` (mean torque on the body over the
step, so momentum is exchanged exactly), ``wheel_momentum`` (h_w at t_k, in B)
and ``wheel_state`` (per wheel angle, speed and motor torque at t_k). On
``wheel_cmd`` (each wheel's motor torque, N m: a user's own allocation) it
takes the step the same way, the allocation and the null-space loop left out.
On ``wheel_status`` (``diagnostic_msgs/DiagnosticArray``: a user's flight
software declaring wheels failed, level ERROR, or sound, OK, by
``hardware_id`` ``wheel<n>``) it sets its own ``available`` parameter before
the first command stamped after the declaration, so the declaration is checked
as any parameter set is and the bag's parameter events keep it.

With ``command_timing`` ``sim_timer`` or ``wall`` (a controller on a timer of
its own, docs/flight-software.md) a step starts on ``/clock`` instead, with
the command that :class:`~attitude_sil.core.sim.lockstep.CommandHold` holds
(at a tick of a ``sim_timer`` controller, once that tick's command is in),
and the command applied goes out on ``applied/voltage_cmd`` (or
``applied/torque_cmd``) stamped t_k, for the record and the metrics.
"""

from __future__ import annotations

import re

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter

from attitude_sil.core.faults import Fault, first_step, parse_faults, wheel_failure_values
from attitude_sil.core.plant.actuators import RPM
from attitude_sil.core.plant.lanes import WHEEL_FAILURE_MODES
from attitude_sil.core.plant.wheels import NO_NULL_SPACE, allocation_over, null_vector
from attitude_sil.core.sim.build import available_wheels, build_wheels, command_faults_of
from attitude_sil.core.sim.lockstep import CommandHold, tick_period_ns
from attitude_sil.errors import ScenarioError
from attitude_sil.ros.contract import (
    APPLIED_COMMAND_TOPIC,
    CLOCK,
    TORQUE_CMD,
    VOLTAGE_CMD,
    WHEEL_CMD,
    WHEEL_MOMENTUM,
    WHEEL_STATE,
    WHEEL_STATUS,
    WHEEL_TORQUE,
)
from attitude_sil.ros.convert import isolation_diagnostics_msg, stamp_to_ns, vector_to_array
from attitude_sil.ros.node import LockstepNode, NodeFaults, run_node
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
        self.step_subscription(WHEEL_CMD, self._on_wheel_command)
        self.step_subscription(WHEEL_STATUS, self._on_wheel_status, "diagnostic_msgs/msg/DiagnosticArray")
        self.declared: list[tuple[int, dict[int, bool]]] = []  # (stamp ns, wheel (1..n) -> sound), to apply
        self._before_declared: list[int] | None = None  # `available` before the episode's first declaration
        self.hold: CommandHold | None = None  # a controller on a timer of its own: the command held
        if self.param("command_timing") != "stamped":
            self.pub_applied = {mode: self.step_publisher(APPLIED_COMMAND_TOPIC["torque" if mode else "voltage"])
                                for mode in (False, True)}
            self.step_subscription(CLOCK, self._on_clock)
        self.step_ns: int | None = None  # held commands: the step started on /clock, not yet taken
        self.clock_ns: int | None = None  # held commands: the latest /clock
        self.faults = NodeFaults(self, "wheels")  # rebuild() resets it
        self.new_episode()

    def rebuild(self) -> None:
        if self._before_declared is not None:  # a new episode starts from the set before the declarations
            self.set_parameters([Parameter("available", Parameter.Type.INTEGER_ARRAY, self._before_declared)])
            self._before_declared = None
        scn = self.scenario()
        self.core = build_wheels(scn, 1)
        self.faults.reset()  # the list as it stands, each fault said on /diagnostics as it becomes active
        # a past episode's declarations not yet taken are not this one's (one of its first step may be here)
        self.declared = [d for d in self.declared if d[0] == 0]
        timing = self.param("command_timing")
        if timing != "stamped":
            zero = (np.zeros((1, 3)), self.param("actuator") in ("torque", "none"))
            self.hold = CommandHold(timing, tick_period_ns(timing, self.param("command_rate"), self.dt_ns), zero)
            self.step_ns = None

    def check_parameters(self, pending: dict) -> str:
        """The available wheels must span the three body axes; faults may only be added, and must fly."""
        values = {**self.values(), **pending}
        if "faults" in pending:
            wheels = self.param("actuator") == "reaction_wheels"
            try:
                foreign = self.faults.refusal(pending["faults"])
                if foreign:
                    return foreign
                parse_faults(values["faults"], 0.0, self.core.assembly.n_wheels if wheels else None)
                wheel_failure_values(values)
                command_faults_of(values)
            except ScenarioError as exc:
                return str(exc)
        if pending.get("null_space.time_constant_s", 0.0) > 0.0 and self.param("actuator") == "reaction_wheels":
            assembly = self.core.assembly  # the wheels in use keep a free direction for the speed loop
            if not np.any(null_vector(assembly.axes_B, assembly.allocation)):
                return NO_NULL_SPACE
        if not {"allocation", "available"} & set(pending) or self.param("actuator") != "reaction_wheels":
            return ""
        if "available" in pending:  # a set is checked as it is given, whichever allocation flies now
            values["allocation"] = "available"
        try:
            allocation_over(self.core.assembly.axes_B, available_wheels(values, self.core.assembly.n_wheels))
        except ScenarioError as exc:
            return str(exc)
        return ""

    def on_parameters_set(self, names: list[str]) -> None:
        if "faults" in names:
            self._inject(self.faults.added())
        if {"null_space.time_constant_s", "null_space.speed_rpm"} & set(names) \
                and self.param("actuator") == "reaction_wheels":  # from the next step on
            self.core.assembly.set_null_space(self.param("null_space.time_constant_s"),
                                              self.param("null_space.speed_rpm") * RPM)
        if {"allocation", "available"} & set(names) and self.param("actuator") == "reaction_wheels":
            # the next command on is shared among the wheels now available (the episode goes on)
            self.core.assembly.set_available(available_wheels(self.values(), self.core.assembly.n_wheels))
            self.get_logger().info(f"allocation {self.param('allocation')} over wheels "
                                   f"{self.param('available') or 'all'}")

    def _inject(self, faults: list[Fault]) -> None:
        """Faults added while the graph runs: each from its time, or, if that has passed, from the step after the
        one in hand (a stuck drive holds the voltage of the step before, which that step records)."""
        for fault in faults:
            step = max(first_step(fault.time_s, self.dt_ns), self.core.k + 1)
            if fault.kind == "controller":
                self.core.add_command_fault(fault, step)
            else:
                value = (fault.value or 0.0) * (RPM if fault.mode == "speed_limit" else 1.0)
                self.core.fail(fault.index - 1, step, WHEEL_FAILURE_MODES.index(fault.mode), value)
            self.faults.started(fault, step, self.dt_ns)

    def _on_command(self, msg, torque_mode: bool) -> None:
        t = stamp_to_ns(msg.header.stamp)
        v = vector_to_array(msg)[None]
        if not self.finite(v):  # before sequencing: a refused message must not take the step's place
            self.get_logger().error(f"command at t={t * 1e-9:.6f} s is not finite: {v[0].tolist()}; ignored",
                                    throttle_duration_sec=1.0)
            return
        if self.hold is not None:
            last = self.seq.last_ns  # the latest /clock taken: a tick's command may overtake the next one
            latest = None if last is None else (last if self.step_ns is not None else last + self.dt_ns)
            why = self.hold.offer(t, v, torque_mode, latest)
            if why:
                self.get_logger().error(f"{TORQUE_CMD if torque_mode else VOLTAGE_CMD} stamped {t * 1e-9:.6f} s "
                                        f"refused ({why}); expected {self.hold.next_tick(last or 0) * 1e-9:.6f} s",
                                        throttle_duration_sec=1.0)
            self._step_held()
            return
        if self.in_sequence(TORQUE_CMD if torque_mode else VOLTAGE_CMD, t):
            self._advance(t, v, torque_mode)

    def _on_wheel_status(self, msg) -> None:
        """``wheel_status``: wheels the flight software declares failed (ERROR) or sound (OK), stamped t."""
        t = stamp_to_ns(msg.header.stamp)
        if self.param("actuator") != "reaction_wheels":
            self.get_logger().error(f"{WHEEL_STATUS} needs actuator reaction_wheels; ignored", once=True)
            return
        said: dict[int, bool] = {}
        for s in msg.status:
            m = re.fullmatch(r"wheel_?([1-9][0-9]*)", s.hardware_id)
            if m is None or int(m.group(1)) > self.core.assembly.n_wheels:
                self.get_logger().error(f"{WHEEL_STATUS} stamped {t * 1e-9:.6f} s: hardware_id {s.hardware_id!r} "
                                        f"is no wheel (wheel1..wheel{self.core.assembly.n_wheels}); ignored")
                return
            if s.level in (DiagnosticStatus.OK, DiagnosticStatus.ERROR):
                said[int(m.group(1))] = s.level == DiagnosticStatus.OK
        if said:
            self.declared.append((t, said))
            if self.param("allocation") != "available":
                self.get_logger().warning(f"{WHEEL_STATUS} taken into the available wheels, which the allocation "
                                          "uses with allocation available (now pseudo_inverse)", once=True)

    def _take_declared(self, t: int) -> None:
        """Before the command stamped ``t``: the declarations stamped before it, into ``available``."""
        due = [d for d in self.declared if d[0] < t]
        if not due:
            return
        self.declared = [d for d in self.declared if d[0] >= t]
        n = self.core.assembly.n_wheels
        sound = {w: True for w in (self.param("available") or range(1, n + 1))}
        for _, said in due:
            sound.update(said)
        available = sorted(w for w, ok in sound.items() if ok)
        if not available:  # (an empty list is 'every wheel')
            self.get_logger().error(f"{WHEEL_STATUS}: every wheel declared failed; refused, the wheels left as they "
                                    f"were ({self.param('available') or 'all'})")
            return
        if self._before_declared is None:  # the user's own set, for the next episode
            self._before_declared = self.param("available")
        value = available if len(available) < n else []
        (result,) = self.set_parameters([Parameter("available", Parameter.Type.INTEGER_ARRAY, value)])
        if not result.successful:
            self.get_logger().error(f"{WHEEL_STATUS}: wheels {available} refused ({result.reason})")

    def _on_wheel_command(self, msg) -> None:
        """``wheel_cmd``: each wheel's motor torque (N m) stamped t_k, a user's own allocation (one step)."""
        t = stamp_to_ns(msg.header.stamp)
        why = self._wheel_command_problem(msg)
        if why:
            self.get_logger().error(f"{WHEEL_CMD} stamped {t * 1e-9:.6f} s refused ({why})", throttle_duration_sec=1.0)
            return
        names = list(msg.name) or self.core.names
        effort = np.array([dict(zip(names, msg.effort, strict=True))[n] for n in self.core.names])[None]
        if self.in_sequence(WHEEL_CMD, t):
            self._advance(t, np.zeros((1, 3)), True, effort)

    def _wheel_command_problem(self, msg) -> str:
        """Why a ``wheel_cmd`` cannot be taken ('' if it can)."""
        if self.hold is not None or self.param("actuator") != "reaction_wheels":
            return "wheel_cmd needs actuator reaction_wheels and command_timing stamped"
        names, n = list(msg.name), self.core.assembly.n_wheels
        if len(msg.effort) != n or (names and sorted(names) != sorted(self.core.names)):
            return f"expected an effort for each of {', '.join(self.core.names)}, got {len(msg.effort)} for {names}"
        if not self.finite(np.asarray(msg.effort, dtype=float)):
            return f"effort not finite: {list(msg.effort)}"
        return ""

    def _on_clock(self, msg) -> None:
        """A held-command step starts on ``/clock``."""
        t = stamp_to_ns(msg.clock)
        previous, self.clock_ns = self.clock_ns, t
        if self.hold.replays_start(t, previous):
            return  # the plant bringing a sim-time timer back in phase: the tick still waits
        if not self.in_sequence(CLOCK, t):  # a new episode: a hold of its own, with no command yet
            return
        self.step_ns = t
        self._step_held()

    def _step_held(self) -> None:
        """Take the step in hand with the command held, unless it is a tick whose command is still to come."""
        t = self.step_ns
        if t is None or self.hold.waits_at(t):
            return
        self.step_ns = None
        v, torque_mode = self.hold.applied(t)
        self.pub_applied[torque_mode].publish(stamped_vector_cdr(v[0], t, "body"))
        self._advance(t, v, torque_mode)

    def _advance(self, t: int, v: np.ndarray, torque_mode: bool, wheel_cmd: np.ndarray | None = None) -> None:
        self._take_declared(t)  # whichever way the step came: a stamped command, a held one, a per-wheel one
        out = self.core.advance(v, torque_mode) if wheel_cmd is None else self.core.advance(v, torque_mode, wheel_cmd)
        if getattr(self.core, "fdir", None) is not None and self.core.isolated_now.size:  # isolated at this step
            wheel = int(self.core.fdir.isolated[0]) + 1
            self.faults.publisher.publish(isolation_diagnostics_msg(wheel, t, self.param("reallocate_on_fault")))
            self.get_logger().warning(f"FDIR isolated wheel{wheel} at t={t * 1e-9:g} s")
        self.pub_torque.publish(stamped_vector_cdr(out.tau_c_B[0], t, "body"))
        self.pub_momentum.publish(stamped_vector_cdr(out.h_wheels_B[0], t, "body"))
        self.pub_state.publish(joint_state_cdr(self.core.names, out.position[0], out.velocity[0], out.effort[0], t))
        self.faults.say(t, self.dt_ns)


def main(args: list[str] | None = None) -> int:
    """Console script ``wheels_node``."""
    return run_node(WheelsNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
