"""Reaction-wheel assembly: geometry, voltage allocation and PMDC motors.

* Geometry: the HST four-wheel pyramid, paper 000 eq. 13 (the ``A`` matrix,
  columns are wheel spin axes in B), and pseudo-inverse allocation eq. 14.
* Motor: the permanent-magnet DC motor of paper 000 eq. 15-16 with the wheel as
  its rotor (no external load, ``T_L = 0``), plus the wheel angle. Per wheel
  the state ``x = (theta rad, i_a A, omega_m rad/s)`` obeys the linear system
  ``x' = A_m x + B_m e_a``, so one held-voltage interval is integrated exactly
  with the matrix exponential (the electrical time constant ``L/R`` never
  limits the step).
* Wheel momentum (eq. 17): ``h_w = G J_m omega_m`` in B. ``omega_m`` is taken
  as the spin rate about the wheel axis; the body-rate part of the absolute
  spin rate (``a^T omega_BN``) is neglected in the back-EMF, which is standard
  for wheels spinning far faster than the body (HST: 1e-3 rad/s against
  up to 314 rad/s). Momentum is still exchanged exactly with the body: the
  body sees ``tau_c = -dh_w/dt``.
* Drive limits, applied to the held voltage at the start of each interval:
  bus voltage ``v_max``; a back-EMF-compensated current limit
  (``|e - K_b omega| <= R i_max``, i.e. motor torque ``<= K_i i_max``); and a
  speed limit that refuses voltage which would accelerate a wheel already at
  ``speed_max`` (it then coasts).

Sign convention: a positive body-axis voltage command asks for a positive
torque on the body about that axis; the wheels are driven the other way
(``e_w = -A_dagger v_B``, reaction ``tau_c = -A T_w``).
"""

from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass

import numpy as np

from attitude_sil.core.plant.kernels import WheelFailure, WheelParams, expm_small, wheel_step
from attitude_sil.core.plant.lanes import CURRENT, SPEED
from attitude_sil.errors import ScenarioError

__all__ = [
    "MotorParams",
    "hst_pyramid",
    "orthogonal_triad",
    "GEOMETRIES",
    "WheelAssembly",
    "allocation_over",
    "torque_envelope",
    "allocation_envelope",
    "no_failure",
    "HST_MOTOR",
]

#: HST wheel motor (the wheels' schema defaults). Paper 000 gives J_m = 0.84 kg m^2, 0.8 N m and 3000 rpm and
# names a commercial PMDC motor without its constants; the rest is assumed.
_RATED_SPEED = 3000.0 * 2.0 * math.pi / 60.0  # rad/s, paper 000
_K_MOTOR = 1.5  # assumed, see below

HST_MOTOR = {
    # Schema defaults (a generic wheel, assumed): K_i = K_b = 1.5 (SI units, ideal
    # PMDC), R_a = 1.5 ohm, 0.8 N m current limit, 3000 rpm no-load drive. The HST
    # presets (config/hst_*.yaml) override K and R with the constants identified from
    # paper 000's published results (K 1.002, R 1.1889 ohm; docs/fidelity.md) and keep
    # the 0.8 N m / 3000 rpm rating; hst_roll_step_unlimited.yaml lifts it, as the paper's model.
    "motor.back_emf_constant": _K_MOTOR,
    "motor.torque_constant": _K_MOTOR,
    "motor.resistance": 1.5,
    # assumed: drive voltage that gives the paper's 3000 rpm no-load speed.
    "motor.v_max": _K_MOTOR * _RATED_SPEED,
    # assumed: electrical time constant L/R = 1 ms.
    "motor.inductance": 1.5e-3,
    "motor.rotor_inertia": 0.84,
    # assumed: small bearing friction, 1e-4 N m per rad/s.
    "motor.viscous_friction": 1.0e-4,
    "motor.torque_max": 0.8,
    "motor.speed_max_rpm": 3000.0,
}


def hst_pyramid() -> np.ndarray:
    """Spin-axis matrix of the HST RWA (paper 000 eq. 13), shape (3, 4).

    Two pairs 90 deg apart, each wheel tilted 20 deg from the y-z plane.
    """
    s20, c20 = np.sin(np.radians(20.0)), np.cos(np.radians(20.0))
    c45, s45 = np.cos(np.radians(45.0)), np.sin(np.radians(45.0))
    return np.array(
        [
            [-s20 * c45, s20 * c45, s20 * c45, -s20 * c45],
            [-c20 * c45, -c20 * c45, c20 * c45, c20 * c45],
            [s45, s45, s45, s45],
        ]
    )


def orthogonal_triad() -> np.ndarray:
    """Three wheels along the body axes, shape (3, 3)."""
    return np.eye(3)


GEOMETRIES = {"hst_pyramid": hst_pyramid, "orthogonal": orthogonal_triad}


@dataclass(frozen=True)
class MotorParams:
    """PMDC wheel-motor constants (paper 000 eq. 15-16), SI units.

    Attributes
    ----------
    resistance : R_a, ohm
    inductance : L_a, H
    torque_constant : K_i, N m / A
    back_emf_constant : K_b, V s / rad
    rotor_inertia : J_m, kg m^2 (wheel plus rotor)
    viscous_friction : B_m, N m s / rad
    v_max : drive bus voltage, V
    torque_max : motor torque limit, N m (sets i_max = torque_max / K_i)
    speed_max : wheel speed limit, rad/s
    """

    resistance: float
    inductance: float
    torque_constant: float
    back_emf_constant: float
    rotor_inertia: float
    viscous_friction: float
    v_max: float
    torque_max: float
    speed_max: float

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first non-physical constant."""
        for name in ("resistance", "inductance", "torque_constant", "back_emf_constant",
                     "rotor_inertia", "v_max", "torque_max", "speed_max"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0.0:
                raise ScenarioError(f"motor {name} must be a positive finite number, got {value}")
        if not np.isfinite(self.viscous_friction) or self.viscous_friction < 0.0:
            raise ScenarioError(f"motor viscous_friction must be >= 0, got {self.viscous_friction}")

    @property
    def current_max(self) -> float:
        """Armature current limit, A."""
        return self.torque_max / self.torque_constant


@functools.lru_cache(maxsize=64)
def _motor_transition(resistance: float, inductance: float, torque_constant: float, back_emf_constant: float,
                      rotor_inertia: float, viscous_friction: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact one-step transition of the motor state (angle, current, speed) with the voltage held.

    The zero-order-hold discretisation of eq. 15-16 by the matrix exponential of
    the augmented system (:func:`attitude_sil.core.plant.kernels.expm_small`): returns
    ``(phi_T (3, 3), gamma (3,))`` with ``x_next = x @ phi_T + e_a * gamma``. Cached: every episode of a batch and
    every run of one set of constants shares it (callers copy).
    """
    a_m = np.array(
        [
            [0.0, 0.0, 1.0],
            [0.0, -resistance / inductance, -back_emf_constant / inductance],
            [0.0, torque_constant / rotor_inertia, -viscous_friction / rotor_inertia],
        ]
    )
    aug = np.zeros((4, 4))
    aug[:3, :3] = a_m
    aug[:3, 3] = [0.0, 1.0 / inductance, 0.0]
    e = expm_small(aug * dt)
    return e[:3, :3].T.copy(), e[:3, 3].copy()


def allocation_over(axes_B: np.ndarray, available: list[int] | None = None) -> np.ndarray:
    """The allocation (n, 3) of a body-axis command over the wheels ``available`` (0-based indices; None: all):
    the pseudo-inverse of their axes (paper 000 eq. 14 over them), zero rows for the others.

    Over every wheel of HST's pyramid, a unit roll command with wheel 1 lost
    delivers (0.750, -0.687, 0.731); over the three that remain, (1, 0, 0).

    Raises
    ------
    ScenarioError
        Available wheels whose axes do not span the three body axes.
    """
    a = np.asarray(axes_B, dtype=float)
    if available is None:
        return np.linalg.pinv(a)
    idx = sorted(set(int(i) for i in available))
    if np.linalg.matrix_rank(a[:, idx]) < 3 if idx else True:
        raise ScenarioError(f"wheels.available: wheels {', '.join(str(i + 1) for i in idx) or 'none'} do not span "
                            "the three body axes: some torques could not be made")
    out = np.zeros((a.shape[1], 3))
    out[idx] = np.linalg.pinv(a[:, idx])
    return out


#: why the null-space speed loop cannot run (the wheels in use have no free direction)
NO_NULL_SPACE = ("wheels.null_space.time_constant_s: the wheels in use have no null space (one free direction is "
                 "needed: e.g. four wheels in a pyramid)")


def null_vector(axes_B: np.ndarray, allocation: np.ndarray) -> np.ndarray:
    """The unit vector (n,) along which the wheels the ``allocation`` (n, 3) uses make no body torque
    (``axes_B @ n = 0``), signed so its last nonzero entry is positive; zeros where those wheels have no free
    direction, or more than one. HST's pyramid: (-1/2, 1/2, -1/2, 1/2)."""
    a = np.asarray(axes_B, dtype=float)
    used = np.flatnonzero(np.any(allocation != 0.0, axis=1))
    out = np.zeros(a.shape[1])
    if used.size - np.linalg.matrix_rank(a[:, used]) != 1:
        return out
    n = np.linalg.svd(a[:, used])[2][-1]
    n[np.abs(n) < 1e-15] = 0.0
    out[used] = n * np.sign(n[np.flatnonzero(n)[-1]])
    return out


def torque_envelope(axes_B: np.ndarray, torque_max: float, available: list[int] | None = None) -> np.ndarray:
    """The largest pure torque (N m) along +x, +y, +z of B that the wheels ``available`` (0-based; None: all),
    each at most ``torque_max`` N m, can make together: (3,).

    The torques they can make form a zonotope, the sum of the segments
    ``[-T g_j, T g_j]`` over the wheels' spin axes g_j. Each of its facets is
    normal to ``n = g_a x g_b`` for two axes, at ``|n . x| <= T sum_j |n . g_j|``;
    so a ray ``t e`` leaves it at ``t = min over facets of T sum_j |n . g_j| / |n . e|``
    (the zonotope is symmetric: -e gives the same). Zero where the wheels do not
    span the three axes.
    """
    g = np.asarray(axes_B, dtype=float)
    used = list(range(g.shape[1])) if available is None else sorted(set(available))
    g = g[:, used]
    out = np.zeros(3)
    if np.linalg.matrix_rank(g) < 3:
        return out
    normals = [np.cross(g[:, a], g[:, b]) for a in range(g.shape[1]) for b in range(a + 1, g.shape[1])]
    normals = [n / np.linalg.norm(n) for n in normals if np.linalg.norm(n) > 1e-12]
    for i in range(3):
        out[i] = min(torque_max * np.sum(np.abs(n @ g)) / abs(n[i]) for n in normals if abs(n[i]) > 1e-12)
    return out


def allocation_envelope(allocation: np.ndarray, torque_max: float) -> np.ndarray:
    """The largest pure torque (N m) along +x, +y, +z of B that an ``allocation`` (n, 3) makes before its
    first wheel reaches ``torque_max``: ``T / max_j |A_j e_i|`` per axis (3,); paper 000's eq. 14 shares a
    command by the pseudo-inverse, which is not the largest share a wheel set can make (:func:`torque_envelope`)."""
    a = np.abs(np.asarray(allocation, dtype=float))
    return torque_max / np.max(a, axis=0)


class WheelAssembly:
    """A set of identical PMDC reaction wheels on fixed axes, batch over episodes.

    Parameters
    ----------
    axes_B : ndarray, shape (3, n)
        Spin axes in B (columns).
    motor : MotorParams
    dt : float
        Held-voltage interval, s.
    """

    def __init__(self, axes_B: np.ndarray, motor: MotorParams, dt: float,
                 motors: list[MotorParams] | None = None, available: list[int] | None = None) -> None:
        motor.validate()
        self.axes_B = np.asarray(axes_B, dtype=float)
        self.n_wheels = self.axes_B.shape[1]
        self.motor = motor
        self.dt = float(dt)
        # eq. 14: body-axis command -> wheel command, over every wheel or the available ones
        self.allocation = allocation_over(self.axes_B, available)
        m = motor
        phi_T, gamma = _motor_transition(m.resistance, m.inductance, m.torque_constant, m.back_emf_constant,
                                         m.rotor_inertia, m.viscous_friction, self.dt)
        self.phi_T = phi_T.copy()  # x_next = x @ phi_T + e_a * gamma
        self.gamma = gamma.copy()
        # a lost wheel (open circuit) coasts: speed' = -B_m / J_m speed, exactly over one step
        decay = float(np.exp(-m.viscous_friction * self.dt / m.rotor_inertia))
        gain = m.rotor_inertia / m.viscous_friction * (1.0 - decay) if m.viscous_friction > 0.0 else self.dt
        self.coast = np.array([decay, gain])
        self.set_motors(motors)

    def set_available(self, available: list[int] | None) -> None:
        """Share commands from now on among the wheels ``available`` (0-based; None: all), :func:`allocation_over`;
        the null-space speed loop runs over them (none if they have no free direction)."""
        self.allocation = allocation_over(self.axes_B, available)
        self.params = self.params._replace(allocation=self.allocation,
                                           null=null_vector(self.axes_B, self.allocation))
        self.set_reallocation(self.params.reallocate, available)

    def set_reallocation(self, on: bool, available: list[int] | None = None) -> None:
        """With ``on``, a wheel that fails is dropped from the allocation at its failure's step (ideal
        isolation: a perfect, instant detector): the command is shared among the others of ``available``
        (0-based; None: all), where they span the body axes, else as before."""
        n = self.n_wheels
        base = list(range(n)) if available is None else sorted(set(available))
        realloc = np.zeros((n, n, 3))
        for f in range(n):
            rest = [i for i in base if i != f]
            try:
                realloc[f] = allocation_over(self.axes_B, rest)
            except ScenarioError:  # the others do not span the axes: keep sharing as before
                realloc[f] = self.allocation
        self.params = self.params._replace(realloc=realloc, reallocate=bool(on))

    def friction_transition(self, factor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The exact motor transition (phi_T (F, 3, 3), gamma (F, 3); x_next = x @ phi_T + e gamma) of each
        episode's motor with its viscous friction ``factor`` (F,) times the datasheet's: a bearing that wears
        (a large factor seizes it)."""
        factor = np.atleast_1d(np.asarray(factor, dtype=float))
        phi, gamma = np.empty((factor.size, 3, 3)), np.empty((factor.size, 3))
        for p, f in enumerate(factor):
            m = self.motors[p if len(self.motors) > 1 else 0]
            phi[p], gamma[p] = _motor_transition(m.resistance, m.inductance, m.torque_constant, m.back_emf_constant,
                                                 m.rotor_inertia, f * m.viscous_friction, self.dt)
        return phi, gamma

    def nominal(self) -> WheelAssembly:
        """A copy of the assembly as it stands (allocation, null-space loop, reallocation) flying the nominal
        motor in every episode: the drive's model of its motors (:mod:`attitude_sil.core.plant.fdir`)."""
        twin = copy.copy(self)
        twin.set_motors(None)
        return twin

    def set_null_space(self, time_constant: float, target: float) -> None:
        """Drive the wheel speeds' component along :func:`null_vector` to ``target`` (rad/s) as a first order
        of ``time_constant`` (s; 0: off), from the next step on: speed management that makes no body torque.

        Raises
        ------
        ScenarioError
            A time constant > 0 where the wheels in use have no free direction.
        """
        null = null_vector(self.axes_B, self.allocation)
        if time_constant > 0.0 and not np.any(null):
            raise ScenarioError(NO_NULL_SPACE)
        self.params = self.params._replace(null=null, null_tau=float(time_constant), null_target=float(target))

    def set_motors(self, motors: list[MotorParams] | None) -> None:
        """Per-episode motor constants (one :class:`MotorParams` per episode), or None for the nominal motor.

        Only the electrical constants may differ between episodes (``resistance``,
        ``inductance``, ``torque_constant``, ``back_emf_constant`` and
        ``torque_max``, i.e. the current limit): the rotor inertia, friction,
        bus voltage and speed limit stay the assembly's. Sets the (M, ...) arrays the step kernel reads, M = 1 or P.
        """
        base = self.motor
        motors = [base] if motors is None else list(motors)
        self.motors = motors  # one per episode, or the nominal one for all
        for mp in motors:
            mp.validate()
            for name in ("rotor_inertia", "viscous_friction", "v_max", "speed_max"):
                if getattr(mp, name) != getattr(base, name):
                    raise ScenarioError(f"per-episode motors may not change motor {name}")
        n = len(motors)
        self.phi_e = np.empty((n, 3, 3))
        self.gamma_e = np.empty((n, 3))
        self.k_b_e = np.array([mp.back_emf_constant for mp in motors], dtype=float)
        self.k_i_e = np.array([mp.torque_constant for mp in motors], dtype=float)
        self.r_a_e = np.array([mp.resistance for mp in motors], dtype=float)
        self.headroom_e = np.array([mp.resistance * mp.current_max for mp in motors], dtype=float)
        for i, mp in enumerate(motors):
            self.phi_e[i], self.gamma_e[i] = _motor_transition(mp.resistance, mp.inductance, mp.torque_constant,
                                                               mp.back_emf_constant, mp.rotor_inertia,
                                                               mp.viscous_friction, self.dt)
        b = self.motor
        # the null-space loop and the reallocation as they were (off at first: WheelAssembly.set_null_space,
        # WheelAssembly.set_reallocation)
        n = self.n_wheels
        kept = self.params[-5:] if hasattr(self, "params") else (np.zeros(n), 0.0, 0.0, np.zeros((n, n, 3)), False)
        self.params = WheelParams(self.allocation, self.axes_B, self.phi_e, self.gamma_e, self.k_b_e,
                                  self.headroom_e, self.k_i_e, self.r_a_e, self.coast, float(b.rotor_inertia),
                                  float(b.viscous_friction), float(b.speed_max), float(b.v_max), self.dt, *kept)

    # -- helpers -------------------------------------------------------------
    def initial_state(self, n_episodes: int, speed0: np.ndarray | None = None) -> np.ndarray:
        """Wheel state array (P, n, 3): angle rad, current A, speed rad/s."""
        x = np.zeros((n_episodes, self.n_wheels, 3))
        if speed0 is not None:
            x[:, :, SPEED] = speed0
        return x

    def momentum_B(self, x: np.ndarray) -> np.ndarray:
        """Wheel angular momentum in B (eq. 17), (P, 3) N m s."""
        return (x[:, :, SPEED] * self.motor.rotor_inertia) @ self.axes_B.T

    def motor_torque(self, x: np.ndarray) -> np.ndarray:
        """Electromagnetic torque K_i i_a on each wheel (each episode's K_i), (P, n) N m."""
        return self.k_i_e[:, None] * x[:, :, CURRENT]

    def wheel_voltages(self, v_cmd_B: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Body-axis voltage command to limited per-wheel voltages, (P, n) V.

        Pseudo-inverse allocation (eq. 14) with the sign convention of the
        module docstring, then the drive limits (bus voltage, back-EMF
        compensated current limit, speed limit).
        """
        m = self.motor
        e = -(v_cmd_B @ self.allocation.T)
        speed = x[:, :, SPEED]
        emf = m.back_emf_constant * speed
        headroom = m.resistance * m.current_max
        e = np.clip(e, emf - headroom, emf + headroom)
        over = np.abs(speed) >= m.speed_max
        accel = (e - emf) * speed > 0.0
        e = np.where(over & accel, emf, e)
        return np.clip(e, -m.v_max, m.v_max)

    def step(self, x: np.ndarray, e_wheels: np.ndarray,
             h_start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Integrate the motors exactly over one held-voltage interval.

        Parameters
        ----------
        x : (P, n, 3) state at t_k
        e_wheels : (P, n) V, held over [t_k, t_k + dt]
        h_start : (P, 3) N m s, optional
            ``momentum_B(x)`` if the caller has it already.

        Returns
        -------
        x_next : (P, n, 3) state at t_k + dt
        tau_c_B : (P, 3) N m, interval-mean control torque on the body,
            ``-(h_w(t_k+1) - h_w(t_k)) / dt``
        """
        x_next = x @ self.phi_T + e_wheels[:, :, None] * self.gamma
        if h_start is None:
            h_start = self.momentum_B(x)
        tau_c_B = -(self.momentum_B(x_next) - h_start) / self.dt
        return x_next, tau_c_B

    def advance(self, x: np.ndarray, v_cmd_B: np.ndarray, torque_mode: bool = False, k: int = 0,
                failure: tuple | None = None, wheel_cmd: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`wheel_voltages` then :meth:`step`, compiled in one loop, with each episode's motor.

        With ``torque_mode`` the command is a body torque (N m): each wheel's
        share ``-A_dagger tau`` becomes a voltage through the inverse motor
        model ``e = R_a (T + B_m omega) / K_i + K_b omega`` (steady state, the
        1 ms electrical lag neglected), then the same drive limits apply.
        ``failure`` is a :class:`attitude_sil.core.plant.kernels.WheelFailure`
        for step ``k`` (its held voltages are updated in place); None: no failure.
        ``wheel_cmd`` (P, n) N m: each wheel's own motor torque command
        (``wheel_cmd``, a user's allocation), in place of the body-axis command:
        the inverse motor model and the drive limits, no allocation and no
        null-space loop.

        Returns
        -------
        x_next : (P, n, 3)
        tau_c_B : (P, 3) N m, mean torque on the body over the step
        h_start : (P, 3) N m s, wheel momentum at t_k
        """
        w_cmd = np.zeros((x.shape[0], 0)) if wheel_cmd is None else np.asarray(wheel_cmd, dtype=float)
        return wheel_step(x, v_cmd_B, int(k), bool(torque_mode), self.params,
                          NO_FAILURE if failure is None else failure, w_cmd)


def no_failure() -> WheelFailure:
    """The failure record of :meth:`WheelAssembly.advance` for "no wheel fails" (F = 1)."""
    return WheelFailure(np.full(1, -1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64),
                        np.zeros(1), np.zeros(1), np.full(1, -1, dtype=np.int64), np.zeros(1, dtype=np.int64),
                        np.zeros((1, 3, 3)), np.zeros((1, 3)))


NO_FAILURE = no_failure()  # read-only in use: e_hold is written only for the failed wheel, and there is none
