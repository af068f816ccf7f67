"""The lockstep step objects: the models every driver steps, the graph's nodes one message at a time.

The five graph nodes each hold one of these objects (or a controller bank,
:class:`~attitude_sil.core.control.bank.ControllerBank`) and call exactly the
methods the drivers of :mod:`attitude_sil.core.sim.engine` call, in the same
order, so a run through the ROS graph and the batch engine with P = 1
produce the same numbers (docs/architecture.md, "Lockstep"). One control
step k of the lockstep protocol:

1. ``Plant.state`` at t_k (published as ``attitude``, ``body_rate``);
2. ``Guidance.setpoint(t_k)`` and ``DisturbanceModel.torque(q_BN)``;
3. ``ControllerBank.compute(...)`` -> command held over ``[t_k, t_k+1]``;
4. ``Wheels.advance(command)`` -> momentum at t_k and mean torque;
5. ``Plant.advance(tau_c, h_w, tau_ext)`` -> state at t_k+1.

Every object carries a leading episode axis P. :mod:`attitude_sil.core.sim.build`
builds them from a scenario.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from attitude_sil.core.control.momentum import DipoleCommand
from attitude_sil.core.environment.ephemeris import FieldAlongOrbit
from attitude_sil.core.plant.command_faults import command_fault_record, command_fault_rows
from attitude_sil.core.plant.disturbance import lvlh_attitude
from attitude_sil.core.plant.fdir import WheelFdir
from attitude_sil.core.plant.kernels import WheelFailure
from attitude_sil.core.plant.lanes import ANGLE, FAIL_FRICTION, SPEED
from attitude_sil.core.plant.magnetorquers import Magnetorquers
from attitude_sil.core.plant.quaternion import quat_from_euler
from attitude_sil.core.plant.rigid_body import BodyState, rk4_step
from attitude_sil.core.plant.wheels import WheelAssembly
from attitude_sil.core.sensing.mekf import Mekf
from attitude_sil.core.sensing.models import SensorSuite
from attitude_sil.core.trajectory import WheelStep

__all__ = ["Plant", "Wheels", "Guidance", "Sensing", "MagneticLoop", "SENSING_FIELDS", "per_episode"]


def per_episode(value, n: int, width: int) -> np.ndarray:
    """Broadcast a (width,) or (P, width) value to (P, width)."""
    a = np.asarray(value, dtype=float)
    return np.array(np.broadcast_to(a, (n, width)))


def _inverse(m: np.ndarray) -> np.ndarray:
    """``np.linalg.inv(m)`` for a stack (..., 3, 3), the same bits, inverted once where every matrix is the
    first (the common case: one inertia for all episodes, where a LAPACK call per 3 x 3 dominates a large
    batch's set-up)."""
    if m.ndim == 3 and m.shape[0] > 1 and np.array_equal(m, np.broadcast_to(m[:1], m.shape)):
        return np.repeat(np.linalg.inv(m[:1]), m.shape[0], axis=0)
    return np.linalg.inv(m)


class Plant:
    """Spacecraft body: RK4 over each held-input interval (paper 000 eq. 4, 10-11)."""

    def __init__(self, inertia: np.ndarray, dt: float, substeps: int,
                 q0: np.ndarray, omega0: np.ndarray) -> None:
        self.inertia = np.asarray(inertia, dtype=float)
        self.inertia_inv = _inverse(self.inertia)
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.q0 = np.asarray(q0, dtype=float)
        self.omega0 = np.asarray(omega0, dtype=float)
        self.reset()

    @property
    def n_episodes(self) -> int:
        return self.q0.shape[0]

    def reset(self) -> None:
        """Return to the initial state (wheel momentum comes from the wheels each step)."""
        self.state = BodyState(self.q0.copy(), self.omega0.copy(), np.zeros_like(self.omega0))

    def advance(self, tau_c_B: np.ndarray, h_wheels_B: np.ndarray, tau_ext_B: np.ndarray) -> BodyState:
        """Integrate from t_k to t_k+1 with the step's inputs.

        Parameters
        ----------
        tau_c_B : (P, 3) N m, mean wheel torque on the body over the step
        h_wheels_B : (P, 3) N m s, wheel momentum at t_k
        tau_ext_B : (P, 3) N m, disturbance torque held over the step
        """
        self.state.h_wheels_B = np.asarray(h_wheels_B, dtype=float)
        self.state = rk4_step(self.state, self.inertia, self.inertia_inv, tau_c_B, tau_ext_B,
                              self.dt, self.substeps)
        return self.state


class Wheels:
    """Reaction-wheel assembly driven by a body-axis voltage command.

    ``failure`` is ``(wheel (P,) int, -1 none; step (P,) int; mode (P,) int; value (P,))``:
    from that step on the wheel is lost (open circuit), its drive is stuck at
    the voltage of the step before, limited to ``value`` N m or rad/s, or its
    bearing's friction ``value`` times
    (:data:`~attitude_sil.core.plant.lanes.WHEEL_FAILURE_MODES`, :func:`attitude_sil.core.plant.kernels.wheel_step`).
    ``command_faults`` are the ``controller`` faults (gain, delay) on the command it takes
    (:mod:`attitude_sil.core.plant.command_faults`).
    """

    def __init__(self, assembly: WheelAssembly, n_episodes: int, speed0: np.ndarray | None,
                 failure: tuple | None = None, command_faults: list | None = None, fdir: WheelFdir | None = None
                 ) -> None:
        self.assembly = assembly
        self.n_episodes = n_episodes
        self.speed0 = speed0
        self.command_faults = list(command_faults or [])
        self.fdir = fdir  # the drive's FDIR (core.plant.fdir), or None
        self.isolated_now = np.zeros(0, dtype=np.int64)  # the episodes whose FDIR isolated a wheel at this step
        self.dt_ns = int(round(assembly.dt * 1e9))
        if failure is None or not np.any(np.asarray(failure[0]) >= 0):
            self.failure = None
        else:
            f = n_episodes  # the held voltage is per episode
            self.failure = tuple(np.broadcast_to(np.atleast_1d(np.asarray(a)), (f,)).astype(t)
                                 for a, t in zip(failure, (np.int64, np.int64, np.int64, np.float64), strict=True))
        self._friction()
        self.reset()

    def _friction(self) -> None:
        """The friction fault's motor transitions (per episode), or a placeholder row where none flies."""
        f = self.failure
        if f is not None and np.any((f[0] >= 0) & (f[2] == FAIL_FRICTION)):
            self.friction = self.assembly.friction_transition(np.where(f[2] == FAIL_FRICTION, f[3], 1.0))
        else:
            self.friction = (np.zeros((1, 3, 3)), np.zeros((1, 3)))

    def reset(self) -> None:
        self.x = self.assembly.initial_state(self.n_episodes, self.speed0)
        self.k = 0
        self.e_hold = None if self.failure is None else np.zeros(len(self.failure[0]))
        self.command_fault = command_fault_record(self.command_faults, self.dt_ns, self.n_episodes)
        self.last_cmd = np.zeros((self.n_episodes, 3))  # the command applied at the step before
        if self.fdir is not None:
            self.fdir.reset(self.x)

    @property
    def names(self) -> list[str]:
        return [f"wheel_{i + 1}" for i in range(self.assembly.n_wheels)]

    def fail(self, wheel: int, step: int, mode: int, value: float = 0.0) -> None:
        """Wheel ``wheel`` (0-based) fails from step ``step`` on in every episode, in ``mode`` (a code of
        :data:`~attitude_sil.core.plant.lanes.WHEEL_FAILURE_MODES`) of size ``value`` (N m, rad/s or a
        friction factor): a fault injected while a run goes. ``step`` must be after the step in hand
        (``step > k``): a stuck drive holds the voltage of the step before, which the steps until then record.
        """
        if step <= self.k:
            raise ValueError(f"a wheel fails from a step to come (> {self.k}), not {step}")
        f = self.n_episodes
        self.failure = (np.full(f, wheel, dtype=np.int64), np.full(f, step, dtype=np.int64),
                        np.full(f, mode, dtype=np.int64), np.full(f, float(value)))
        self._friction()
        self.e_hold = np.zeros(f)

    def add_command_fault(self, fault, step: int) -> None:
        """A ``controller`` fault injected while a run goes, from step ``step`` (> k) for its duration; a delay
        reads the command applied before it for the steps it did not record."""
        if step <= self.k:
            raise ValueError(f"a fault starts at a step to come (> {self.k}), not {step}")
        old = self.command_fault
        self.command_faults.append(replace(fault, time_s=step * self.dt_ns * 1e-9))
        self.command_fault = command_fault_record(self.command_faults, self.dt_ns, self.n_episodes, self.last_cmd)
        if old is not None and old.ring.shape == self.command_fault.ring.shape:  # a gain after a delay
            self.command_fault.ring[:] = old.ring
            self.command_fault.held[:] = old.held

    def failure_arrays(self) -> WheelFailure | None:
        """The kernel's failure record (with the held voltages, state), or None: the wheel isolated is the
        FDIR's, or (ideal isolation) the failed one from its failure's step."""
        if self.fdir is not None:
            f = self.fdir
            if self.failure is None:
                return f.isolation()
            return WheelFailure(*self.failure, self.e_hold, f.isolated, f.isolated_step, *self.friction)
        return None if self.failure is None else WheelFailure(*self.failure, self.e_hold, *self.failure[:2],
                                                              *self.friction)

    def advance(self, cmd_B: np.ndarray, torque_mode: bool = False, wheel_cmd: np.ndarray | None = None
                ) -> WheelStep:
        """Hold a body-axis command (P, 3) over one step; return the step's outputs.

        The command is a voltage (V), or with ``torque_mode`` a body torque (N m)
        that the inverse motor model turns into voltages; or, with ``wheel_cmd``
        (P, n) N m, each wheel's own motor torque (``cmd_B`` unused: a user's
        allocation, the ``wheel_cmd`` topic).
        """
        x = self.x
        cmd_B = np.ascontiguousarray(cmd_B, dtype=float)
        if self.command_fault is not None and wheel_cmd is None:  # the controller output's gain and delay
            applied = np.empty_like(cmd_B)
            command_fault_rows(cmd_B, self.k, self.command_fault, applied)
            cmd_B = applied
        self.last_cmd = cmd_B
        if self.fdir is not None:  # the tachometer read at t_k, before the step's command is shared
            self.isolated_now = self.fdir.check(self.k, x)
        self.x, tau_c, h = self.assembly.advance(x, cmd_B, torque_mode, self.k, self.failure_arrays(), wheel_cmd)
        if self.fdir is not None:
            self.fdir.predict(cmd_B, torque_mode, self.k, wheel_cmd)
        self.k += 1
        return WheelStep(h, tau_c, x[:, :, ANGLE], x[:, :, SPEED], self.assembly.motor_torque(x))


class Guidance:
    """Setpoints of the ``guidance`` node.

    * ``step``: ``initial`` attitude until ``step_time``, then ``final``; zero rate.
    * ``lvlh``: the orbit frame, ``q_RN(t) = q_LN(0) ⊗ R_y(Omega_0 t)`` with
      ``omega_RN_R = [0, Omega_0, 0]`` (paper 001: the body tracks LVLH); with
      ``orbit`` (an :class:`~attitude_sil.core.environment.ephemeris.Ephemeris`
      of a propagated orbit) that orbit's LVLH frame and rate.
    """

    def __init__(self, initial_rpy_deg, final_rpy_deg, step_time: float, n_episodes: int, mode: str = "step",
                 lvlh_rpy_deg=(0.0, 0.0, 0.0), orbit_rate_rad_s: float = 0.0, orbit=None) -> None:
        self.mode = mode
        self.orbit = orbit
        self.n = n_episodes
        self.q_initial = per_episode(quat_from_euler(np.radians(initial_rpy_deg)), n_episodes, 4)
        self.q_final = per_episode(quat_from_euler(np.radians(final_rpy_deg)), n_episodes, 4)
        self.step_time = float(step_time)
        self.q_LN0 = quat_from_euler(np.radians(np.asarray(lvlh_rpy_deg, dtype=float)))
        self.rate = float(orbit_rate_rad_s)
        self.omega = np.zeros((n_episodes, 3))
        if mode == "lvlh":
            self.omega[:, 1] = self.rate

    def setpoint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Reference (q_RN (P, 4), omega_RN_R (P, 3) rad/s) at sim time t."""
        if self.mode == "lvlh" and self.orbit is not None:
            now = self.orbit.at(int(round(t * 1e9)))
            return per_episode(now.q_LN, self.n, 4), per_episode(now.omega_LN_L, self.n, 3)
        if self.mode == "lvlh":
            return per_episode(lvlh_attitude(t, self.q_LN0, self.rate), self.n, 4), self.omega
        # compare in integer-safe form: t is k*dt computed from integer ns
        q = self.q_final if t >= self.step_time - 1e-12 else self.q_initial
        return q, self.omega


class Sensing:
    """The sensing loop of P episodes: the sensors and the estimator, stepped together (docs/sensors.md).

    ``step(k, q_BN, omega_BN_B)`` samples the sensors on the truth at t_k and
    runs the filter on what they report, as the ``sensors`` and ``estimator``
    nodes do for one episode; it returns the filter's estimate at t_k.
    """

    def __init__(self, suite: SensorSuite, mekf: Mekf, feedback: str) -> None:
        self.suite = suite
        self.mekf = mekf
        self.feedback = feedback

    def step(self, k: int, q_BN: np.ndarray, omega_BN_B: np.ndarray):
        """The estimate at step ``k`` (a :class:`~attitude_sil.core.sensing.mekf.Estimate`) and the gyro reading."""
        sample = self.suite.sample(q_BN, omega_BN_B, k)
        return self.mekf.step(k, sample.omega_meas_B, sample.star_tracker), sample.omega_meas_B


class MagneticLoop:
    """The magnetorquers' loop of P episodes: the field, the controller's dipole command, the rods' torque.

    One control step k, after the wheels' (the momentum at t_k is theirs):
    the field at the spacecraft in B at t_k (what the plant publishes on
    ``magnetic_field``), the controller's dipole (B-dot under ``bdot``, else
    the law's torque demand through the rods on a spacecraft without wheels,
    else the dumping law's from the wheel momentum) from the field it reads (the truth, or the magnetometer's reading
    with ``feedback: estimate``; the controller node's ``dipole_cmd``), the
    rods' torque m x B on the body held over the step (the ``magnetorquers``
    node's ``magnetic_torque``), which the plant adds to the disturbance.
    """

    def __init__(self, field: FieldAlongOrbit, law: DipoleCommand, rods: Magnetorquers) -> None:
        self.field = field
        self.law = law
        self.rods = rods

    def field_B(self, t_ns: int, q_BN: np.ndarray) -> np.ndarray:
        """The true field (P, 3) tesla in B at step time ``t_ns`` for attitudes ``q_BN`` (P, 4)."""
        return self.field.field_B(np.array([t_ns]), q_BN[:, None, :])[:, 0]

    def step(self, active: str, h_wheels_B: np.ndarray, b_B: np.ndarray, b_read_B: np.ndarray,
             tau_cmd_B: np.ndarray, k: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The dipole command (P, 3) A m^2 under law ``active`` for the wheel momentum ``h_wheels_B`` (P, 3)
        N m s, the field the controller reads ``b_read_B`` (P, 3) T and the law's command ``tau_cmd_B`` (P, 3)
        (its torque demand, N m, where the rods are the torque actuator), and the rods' torque (P, 3) N m in
        the true field ``b_B``, at step ``k`` (the rods' faults, :meth:`Magnetorquers.command_at`)."""
        m_cmd = self.law.dipole(active, h_wheels_B, b_read_B, tau_cmd_B)
        return m_cmd, self.rods.torque(self.rods.command_at(m_cmd, k), b_B)


#: the arrays a run with the sensing loop adds to its trajectory (:class:`~attitude_sil.core.trajectory.Trajectory`)
SENSING_FIELDS = ("q_BN_est", "omega_BN_B_est", "gyro_bias_est", "attitude_sigma", "omega_BN_B_meas",
                  "gyro_bias_true")
