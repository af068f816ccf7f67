"""Attitude controllers, batch over episodes, and the bank that swaps them.

Every controller maps the state at t_k (attitude, body rate) and the setpoint
(reference attitude and rate) to a body-axis command held over
``[t_k, t_k + dt]``. ``compute`` advances the controller's own state by one
step, so it is called exactly once per control step.

Types (``controller_type``, docs/architecture.md, "Parameters"):

* ``pid`` — per-axis PID on the quaternion error vector (paper 000), volts;
* ``fuzzy_pid`` — hybrid fuzzy PID (paper 003 section 5), volts;
* ``ga_flc`` — GA-designed fuzzy logic controller (paper 004), volts;
* ``geometric`` — almost-global tracking law on SO(3) (paper 001 eq. 7), N m.

:class:`ControllerBank` holds one of each and switches at a step boundary,
bumplessly where the new controller has state (see its docstring).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from attitude_sil.errors import ScenarioError

from .disturbance import aerodynamic_torque, gravity_gradient_torque, orbit_rate
from .fuzzy import FUZZY_PID_DEFAULT_RULES, UNIFORM_VERTICES, vertices_from_ratios
from .kernels import (
    apply_offsets,
    fuzzy_pid_bumpless,
    fuzzy_pid_step,
    ga_flc_step,
    geometric_step,
    measure,
    pid_bumpless,
    pid_step,
)
from .quaternion import cross, error_vector, quat_to_dcm

__all__ = [
    "CONTROLLER_TYPES",
    "OUTPUT_KIND",
    "StepInput",
    "PID",
    "FuzzyPID",
    "GAFLC",
    "Geometric",
    "ControllerBank",
    "FUZZY_PID_DEFAULT_RULES",
    "skew_vee",
]

#: the controller types and the command each publishes
OUTPUT_KIND = {"pid": "voltage", "fuzzy_pid": "voltage", "ga_flc": "voltage", "geometric": "torque"}
CONTROLLER_TYPES = tuple(OUTPUT_KIND)



@dataclass
class StepInput:
    """Everything a controller may use at step k, computed once.

    Attributes
    ----------
    q_BN, q_RN : (P, 4) attitude and reference attitude
    omega_BN_B : (P, 3) rad/s
    omega_RN_R : (P, 3) rad/s, reference rate in R
    e : (P, 3) quaternion error vector (:func:`~attitude_sil.core.quaternion.error_vector`)
    """

    q_BN: np.ndarray
    omega_BN_B: np.ndarray
    q_RN: np.ndarray
    omega_RN_R: np.ndarray

    def __post_init__(self) -> None:
        self._e = None
        self._Q = None

    @property
    def e(self) -> np.ndarray:
        """Quaternion error vector, (P, 3); computed on first use."""
        if self._e is None:
            self._e = error_vector(self.q_BN, self.q_RN)
        return self._e

    @property
    def Q(self) -> np.ndarray:
        """Attitude error matrix Q = R_d^T R (paper 001 eq. 5), (P, 3, 3)."""
        if self._Q is None:
            self._Q = np.swapaxes(quat_to_dcm(self.q_RN), -1, -2) @ quat_to_dcm(self.q_BN)
        return self._Q

    def reference_rate_B(self) -> np.ndarray:
        """Q^T omega_d: the reference rate in B, (P, 3) rad/s."""
        return np.einsum("pji,pj->pi", self.Q, self.omega_RN_R)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q_BN, omega_BN_B, q_RN, omega_RN_R) as contiguous float arrays, the kernels' argument order."""
        c = np.ascontiguousarray
        return (c(self.q_BN, dtype=float), c(self.omega_BN_B, dtype=float), c(self.q_RN, dtype=float),
                c(self.omega_RN_R, dtype=float))


def _pe(value, n: int, width: int) -> np.ndarray:
    """Broadcast to a contiguous (P, width) array."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(value, dtype=float), (n, width)))


def skew_vee(m: np.ndarray) -> np.ndarray:
    """vee of the skew part's generator: (M_32, M_13, M_21) of (P, 3, 3) M."""
    return np.stack((m[..., 2, 1], m[..., 0, 2], m[..., 1, 0]), axis=-1)


class PID:
    """Per-axis PID on the quaternion error vector (paper 000 eq. 19, 2nd).

    ``u = Kp e + Ki ∫e dt + Kd N s / (s + N) e`` per body axis.

    Discretisation at the control period ``dt`` (state held between steps):

    * the error vector is :func:`~attitude_sil.core.quaternion.error_vector`;
    * derivative filter: low-pass state ``x_f`` of ``N / (s + N)`` discretised
      exactly for a held error, ``x_f[k+1] = a x_f[k] + (1 - a) e[k]`` with
      ``a = exp(-N dt)``; derivative term ``N (e[k] - x_f[k])``. ``x_f`` starts
      at 0, so a step at t = 0 gives the derivative kick a continuous PID has.
    * integrator: forward Euler, ``I[k+1] = I[k] + e[k] dt``;
    * output saturation at ``±u_max`` with anti-windup by conditional
      integration: the integrator holds while the output is saturated and the
      error pushes further into the limit.

    Bumpless entry (:meth:`bumpless`): the filter state is set so the
    derivative term starts at the measured error rate (``x_f = e - ė / N``,
    ``ė`` from :func:`~attitude_sil.core.kernels.error_and_rate_row`), and the integrator takes the rest,
    ``I = (u_last - Kp e - Kd ė) / Ki``; the first command then equals
    ``u_last`` exactly when ``Ki > 0``, and the integrator holds only the real
    difference between the two laws (not the derivative action, which with a
    small Ki would decay for minutes).

    Parameters
    ----------
    kp, ki, kd, n : array_like, shape (P, 3) or (3,)
    dt : float, s
    u_max : float, output limit
    """

    def __init__(self, kp, ki, kd, n, dt: float, u_max: float, angle_mode: bool = False) -> None:
        self.dt = float(dt)
        self.u_max = float(u_max)
        self.angle_mode = bool(angle_mode)
        self.integral: np.ndarray | None = None
        self.filter_state: np.ndarray | None = None
        self.set_gains(kp, ki, kd, n)

    def set_gains(self, kp, ki, kd, n) -> None:
        """Replace the gains (arrays broadcastable to (P, 3)); state is kept."""
        self.kp = np.atleast_2d(np.asarray(kp, dtype=float))
        self.ki = np.atleast_2d(np.asarray(ki, dtype=float))
        self.kd = np.atleast_2d(np.asarray(kd, dtype=float))
        self.n = np.atleast_2d(np.asarray(n, dtype=float))
        self.a = np.exp(-self.n * self.dt)
        self._gains = None  # contiguous (P, 3) copies for the kernel, made on first use

    def reset(self, n_episodes: int) -> None:
        """Zero the integrator and derivative-filter states for P episodes."""
        self.integral = np.zeros((n_episodes, 3))
        self.filter_state = np.zeros((n_episodes, 3))

    def _kernel_gains(self) -> list[np.ndarray]:
        if self._gains is None or self._gains[0].shape != self.integral.shape:
            shape = self.integral.shape
            self._gains = [np.ascontiguousarray(np.broadcast_to(g, shape))
                           for g in (self.kp, self.ki, self.kd, self.n, self.a)]
        return self._gains

    def compute(self, inp: StepInput) -> np.ndarray:
        """Command for step k, shape (P, 3); advances the controller state."""
        if self.integral is None:
            self.reset(inp.q_BN.shape[0])
        return pid_step(np.ascontiguousarray(inp.q_BN, dtype=float), np.ascontiguousarray(inp.q_RN, dtype=float),
                        *self._kernel_gains(), self.integral, self.filter_state, self.dt, self.u_max,
                        self.angle_mode)

    def bumpless(self, inp: StepInput, u_last: np.ndarray) -> None:
        """Set the state so the next :meth:`compute` with ``inp`` returns ``u_last`` (needs Ki > 0).

        The kernel :func:`attitude_sil.core.kernels.pid_bumpless` (shared with
        the compiled driver) does the arithmetic per episode.
        """
        if self.integral is None:
            self.reset(inp.q_BN.shape[0])
        kp, ki, kd, n, _ = self._kernel_gains()
        pid_bumpless(*inp.arrays(), self.angle_mode, kp, ki, kd, n, self.integral, self.filter_state, self.u_max,
                     np.ascontiguousarray(u_last, dtype=float))


class _Stateless:
    """Bumpless entry for a controller without state: a decaying offset.

    At the switch the offset is ``u_last - u_new``; it decays as
    ``exp(-dt / tau_b)`` per step (``bumpless_time_constant`` tau_b), so the
    first command equals the old controller's last and the new law takes over
    smoothly. Each episode's offset ends on its own, once all three
    components are below 1e-15 (so an episode's numbers do not depend on the
    batch it runs in). With tau_b = 0 there is no offset and the jump is at
    most ``|u_last| + u_max``.
    """

    offset: np.ndarray | None = None  # (P, 3)
    has_offset: np.ndarray | None = None  # (P,) bool: the episodes whose offset still runs
    decay: float = 0.0

    def set_transfer(self, tau_b: float, dt: float) -> None:
        self.decay = float(np.exp(-dt / tau_b)) if tau_b > 0.0 else 0.0

    def _apply_offset(self, u: np.ndarray) -> np.ndarray:
        if self.offset is None:
            return u
        out = np.array(u, dtype=float)
        apply_offsets(out, self.offset, self.has_offset, self.decay)
        if not self.has_offset.any():
            self.offset = self.has_offset = None
        return out

    def bumpless(self, inp: StepInput, u_last: np.ndarray) -> None:
        self.offset = self.has_offset = None
        if self.decay > 0.0:
            self.offset = np.ascontiguousarray(np.asarray(u_last, dtype=float) - self._law(inp))
            self.has_offset = np.ones(self.offset.shape[0], dtype=bool)


class FuzzyPID(_Stateless):
    """Hybrid fuzzy PID of paper 003, section 5, per body axis.

    * Fuzzy part: inputs the error ``e`` (the quaternion error vector) and its
      change ``de = (e[k] - e[k-1]) / dt`` (0 at the first step), normalised by
      ``e_scale`` and ``de_scale`` to [-1, 1]; seven evenly spaced triangular
      sets each; rule table indexed ``rules[Δe, e]`` (paper 003 Table 3
      layout); product inference and weighted-average defuzzification;
      output scaled by ``u_scale`` (V).
    * PID part: :class:`PID` with its own gains.
    * Mixing (paper 003): ``f(e) = e_n^2`` with ``e_n = clip(e / e_scale, -1, 1)``.
      The paper leaves "which response is faster" open; here, per axis and
      causally, **the faster response is the one whose command at this step is
      larger in magnitude** (it would accelerate the body harder now).
      Case 1, fuzzy faster (``|u_f| > |u_pid|``): ``u = f u_pid + (1 - f) u_f``;
      case 2, PID faster: ``u = (1 - f) u_pid + f u_f``; case 3, equal (within
      1e-12 V): ``u = u_pid``. Then ``u`` is saturated at ``u_max``.

    Bumpless entry: the change-of-error memory is set from the measured error
    rate (``e[k-1] = e - ė dt``), then the PID's state is set so the mixed
    command equals the old controller's last whenever some PID output achieves
    that (solved per case). When none does (for small errors the mix follows
    whichever command is larger, so e.g. a small braking command cannot come
    out while the fuzzy part pushes), the PID gets the target and the rest is a
    decaying offset as for the stateless laws (``bumpless_time_constant``).
    """

    def __init__(self, pid: PID, e_scale, de_scale, u_scale, rules, dt: float, u_max: float) -> None:
        self.pid = pid
        self.dt = float(dt)
        self.u_max = float(u_max)
        self.set_params(e_scale, de_scale, u_scale, rules)
        self.e_prev: np.ndarray | None = None

    def set_params(self, e_scale, de_scale, u_scale, rules) -> None:
        self.e_scale = np.atleast_2d(np.asarray(e_scale, dtype=float))
        self.de_scale = np.atleast_2d(np.asarray(de_scale, dtype=float))
        self.u_scale = np.atleast_2d(np.asarray(u_scale, dtype=float))
        r = np.asarray(rules, dtype=np.int64)
        self.rules = r.reshape((-1, 7, 7)) if r.ndim != 3 else r
        self._cache = None

    def _params(self, n: int) -> tuple:
        """(rules (n, 7, 7), e_scale, de_scale, u_scale (n, 3)) for the kernels, cached per n."""
        if self._cache is None or self._cache[0].shape[0] != n:
            self._cache = (np.ascontiguousarray(np.broadcast_to(self.rules, (n, 7, 7))),
                           _pe(self.e_scale, n, 3), _pe(self.de_scale, n, 3), _pe(self.u_scale, n, 3))
        return self._cache

    @staticmethod
    def mix(u_pid: np.ndarray, u_f: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Paper 003's mixing block with the magnitude rule (see the class docstring)."""
        a_p, a_f = np.abs(u_pid), np.abs(u_f)
        fuzzy_faster = a_f > a_p + 1e-12
        pid_faster = a_p > a_f + 1e-12
        return np.where(fuzzy_faster, f * u_pid + (1.0 - f) * u_f,
                        np.where(pid_faster, (1.0 - f) * u_pid + f * u_f, u_pid))

    def compute(self, inp: StepInput) -> np.ndarray:
        """One step of the compiled loop (:func:`attitude_sil.core.kernels.fuzzy_pid_step`)."""
        n = inp.q_BN.shape[0]
        pid = self.pid
        if pid.integral is None:
            pid.reset(n)
        has_prev = self.e_prev is not None
        if not has_prev:
            self.e_prev = np.zeros((n, 3))
        rules, e_scale, de_scale, u_scale = self._params(n)
        mixed = fuzzy_pid_step(np.ascontiguousarray(inp.q_BN, dtype=float),
                               np.ascontiguousarray(inp.q_RN, dtype=float), self.e_prev, has_prev,
                               *pid._kernel_gains(), pid.integral, pid.filter_state, e_scale, de_scale, u_scale,
                               rules, UNIFORM_VERTICES, self.dt, pid.u_max, pid.angle_mode)
        return np.clip(self._apply_offset(mixed), -self.u_max, self.u_max)

    def reset(self, n_episodes: int) -> None:
        self.pid.reset(n_episodes)
        self.e_prev = None
        self.offset = self.has_offset = None

    def bumpless(self, inp: StepInput, u_last: np.ndarray) -> None:
        """Per episode, in :func:`attitude_sil.core.kernels.fuzzy_pid_bumpless` (shared with the compiled driver)."""
        n = inp.q_BN.shape[0]
        pid = self.pid
        if pid.integral is None:
            pid.reset(n)
        self.e_prev = np.zeros((n, 3))
        offset, has = np.zeros((n, 3)), np.zeros(n, dtype=bool)
        rules, e_scale, de_scale, u_scale = self._params(n)
        kp, ki, kd, nf, _ = pid._kernel_gains()
        fuzzy_pid_bumpless(*inp.arrays(), pid.angle_mode, self.e_prev, kp, ki, kd, nf, pid.integral, pid.filter_state,
                           e_scale, de_scale, u_scale, rules, UNIFORM_VERTICES.reshape(1, 1, 7), self.dt, self.u_max,
                           self.decay,
                           np.ascontiguousarray(u_last, dtype=float), offset, has)
        self.offset, self.has_offset = (offset, has) if has.any() else (None, None)


class GAFLC(_Stateless):
    """GA-designed fuzzy logic controller of paper 004, one per body axis.

    Inputs: the attitude error ``θ = -2 asin(vec(q_BR))`` per axis (rad, reference
    minus attitude; exact for a rotation about one axis) and the rate error
    ``q = Q^T ω_d - ω`` (rad/s), scaled by ``K_θ`` and ``K_q`` (eq. 6) to
    [-1, 1]. Errors, not deviations, are what paper 004's Fig. 2 feeds the FLC,
    and only with that sign does its Table 2 stabilise its own pitch model
    (checked for the impulse and the 30 deg initial-angle cases). Seven
    triangular sets per variable with vertices from positive ratios (eq. 5);
    49 integer rules (1..7 = NB..PB, Table 1), table indexed ``rules[θ, q]`` as
    paper 004 Table 2; product inference, weighted average over the output
    vertices (the δe sets' centres); output ``K_e × δe_n`` in volts.

    Genome layout (the tuner searches exactly these parameters):
    ``ga_flc.rules`` 49 integers, row-major over θ (NB..PB) then q (NB..PB);
    ``ga_flc.mf_ratios`` 18 positive numbers: a1..a6 for θ, then for q, then
    for δe; ``ga_flc.scales`` ``[K_θ (1/rad), K_q (s/rad), K_e (V)]``.
    """

    def __init__(self, rules, mf_ratios, scales, u_max: float) -> None:
        self.u_max = float(u_max)
        self.set_params(rules, mf_ratios, scales)

    def set_params(self, rules, mf_ratios, scales) -> None:
        r = np.asarray(rules, dtype=np.int64)
        self.rules = r.reshape((-1, 7, 7))
        ratios = np.asarray(mf_ratios, dtype=float).reshape((-1, 3, 6))
        self.vertices = vertices_from_ratios(ratios)  # (P or 1, 3 variables, 7)
        self.scales = np.atleast_2d(np.asarray(scales, dtype=float))
        self._cache = None

    def reset(self, n_episodes: int) -> None:
        self.offset = self.has_offset = None

    def _law(self, inp: StepInput) -> np.ndarray:
        """The compiled law (:func:`attitude_sil.core.kernels.ga_flc_step`), saturated."""
        n = inp.q_BN.shape[0]
        if self._cache is None or self._cache[0].shape[0] != n:
            self._cache = (np.ascontiguousarray(np.broadcast_to(self.rules, (n, 7, 7))),
                           np.ascontiguousarray(np.broadcast_to(self.vertices, (n, 3, 7))), _pe(self.scales, n, 3))
        rules, vertices, scales = self._cache
        c = np.ascontiguousarray
        return ga_flc_step(c(inp.q_BN, dtype=float), c(inp.omega_BN_B, dtype=float), c(inp.q_RN, dtype=float),
                           c(inp.omega_RN_R, dtype=float), rules, vertices, scales, self.u_max)

    def compute(self, inp: StepInput) -> np.ndarray:
        u = self._law(inp)  # saturated already
        if self.offset is None:
            return u
        return np.clip(self._apply_offset(u), -self.u_max, self.u_max)


class Geometric(_Stateless):
    """Almost-global attitude tracking law on SO(3) (paper 001 eq. 7), torque out.

    With ``R = R_NB`` (body to inertial), ``R_d = R_NR`` and the errors
    ``Q = R_d^T R`` (eq. 5), ``ω_e = ω - Q^T ω_d`` (eq. 6), ``ν = Q^T ω_d``::

        τ = -L ω_e - S_K(Q) + J Q^T ω̇_d + ν × (J ν) - M_env,
        S_K(Q) = vee(K Q - Q^T K) = Σ_i k_i (Q^T e_i) × e_i

    (eq. 7 writes ``+Σ k_i e_i^× Q^T e_i``, the same term). Lyapunov check: with
    ``Q̇ = Q ω_e^×`` and ``J ω̇ = -ω × J ω + τ + M_env``, the function
    ``V = ½ ω_e^T J ω_e + tr(K - K Q)`` has ``dV/dt = -ω_e^T L ω_e`` exactly:
    ``d tr(K - KQ)/dt = ω_e · S_K`` cancels the ``-S_K`` term, and the
    feed-forward ``ν × Jν`` leaves ``-ω_e·(ν × Jω_e) - ω_e·J(ν × ω_e) = 0``.
    K must be diagonal with distinct positive entries, L positive definite.
    ``ω̇_d`` is the backward difference of the reference rate (0 at the first
    step); ``M_env`` is the modelled environmental moment fed forward (zero
    unless the caller supplies it). Output saturated at ``±torque_limit`` per axis.
    """

    def __init__(self, k, l, inertia, dt: float, torque_limit: float,  # noqa: E741 - the paper's L
                 environment=None) -> None:
        self.dt = float(dt)
        self.u_max = float(torque_limit)
        self.set_params(k, l, inertia, environment)
        self.w_d_prev: np.ndarray | None = None

    def set_params(self, k, l, inertia, environment=None) -> None:  # noqa: E741 - L is the paper's name
        """Gains, the model inertia and the feed-forward environment.

        ``environment`` is None or a dict with ``models`` (names among
        ``gravity_gradient``, ``aerodynamic``), ``rate`` (orbit rate, rad/s),
        ``speed`` (m/s) and the ``aero.*`` values.
        """
        self.k = np.atleast_2d(np.asarray(k, dtype=float))
        self.l = np.atleast_2d(np.asarray(l, dtype=float))
        self.inertia = np.asarray(inertia, dtype=float)
        self.environment = environment
        self._cache = None

    def environment_torque(self, inp: StepInput) -> np.ndarray | None:
        """Modelled environmental moment, (P, 3) N m, with the reference taken as LVLH (R_BL = Q^T)."""
        env = self.environment
        if not env or not env["models"]:
            return None
        R_BL = np.swapaxes(inp.Q, -1, -2)
        tau = np.zeros(R_BL.shape[:-1])
        if "gravity_gradient" in env["models"]:
            tau += gravity_gradient_torque(R_BL, np.broadcast_to(self.inertia, R_BL.shape), env["rate"])
        if "aerodynamic" in env["models"]:
            tau += aerodynamic_torque(R_BL, env["aero.density"], env["aero.drag_coefficient"], env["aero.area"],
                                      env["speed"], np.asarray(env["aero.cp_offset"]))
        return tau

    def reset(self, n_episodes: int) -> None:
        self.offset = self.has_offset = None
        self.w_d_prev = None

    def torque_terms(self, inp: StepInput, tau_env_B: np.ndarray | None = None) -> np.ndarray:
        """The unsaturated law (P, 3) N m; does not advance any state."""
        Q = inp.Q
        nu = inp.reference_rate_B()
        w_e = inp.omega_BN_B - nu
        w_d = inp.omega_RN_R
        w_d_dot = np.zeros_like(w_d) if self.w_d_prev is None else (w_d - self.w_d_prev) / self.dt
        K = self.k[..., :, None] * np.eye(3)
        s_k = skew_vee(K @ Q - np.swapaxes(Q, -1, -2) @ K)
        J = np.broadcast_to(self.inertia, Q.shape)
        jv = np.einsum("pij,pj->pi", J, nu)
        ff = np.einsum("pij,pj->pi", J, np.einsum("pji,pj->pi", Q, w_d_dot)) + cross(nu, jv)
        tau = -self.l * w_e - s_k + ff
        if tau_env_B is not None:
            tau = tau - tau_env_B
        return tau

    def kernel_params(self, n: int) -> tuple:
        """The kernel's arguments after ``dt``, for n episodes: (k, l (n, 3), inertia (n, 3, 3), orbit rate,
        0.5 rho C_d A V^2, cp_offset (3,), use gravity gradient, use aerodynamic); cached per n."""
        if self._cache is None or self._cache[0].shape[0] != n:
            env = self.environment or {"models": [], "rate": 0.0, "speed": 0.0, "aero.density": 0.0,
                                       "aero.drag_coefficient": 0.0, "aero.area": 0.0,
                                       "aero.cp_offset": [0.0, 0.0, 0.0]}
            coeff = 0.5 * env["aero.density"] * env["aero.drag_coefficient"] * env["aero.area"] * env["speed"] ** 2
            self._cache = (_pe(self.k, n, 3), _pe(self.l, n, 3),
                           np.ascontiguousarray(np.broadcast_to(self.inertia, (n, 3, 3))), float(env["rate"]),
                           float(coeff), np.asarray(env["aero.cp_offset"], dtype=float),
                           "gravity_gradient" in env["models"], "aerodynamic" in env["models"])
        return self._cache

    def _law(self, inp: StepInput) -> np.ndarray:
        """The compiled law (:func:`attitude_sil.core.kernels.geometric_step`), saturated;
        :meth:`torque_terms` + :meth:`environment_torque` is its numpy reference."""
        n = inp.q_BN.shape[0]
        k, l, J, rate, coeff, cp, use_gg, use_aero = self.kernel_params(n)  # noqa: E741
        c = np.ascontiguousarray
        has_prev = self.w_d_prev is not None
        prev = self.w_d_prev if has_prev else np.zeros((n, 3))
        return geometric_step(c(inp.q_BN, dtype=float), c(inp.omega_BN_B, dtype=float), c(inp.q_RN, dtype=float),
                              c(inp.omega_RN_R, dtype=float), c(prev, dtype=float), has_prev, k, l, J, self.dt,
                              self.u_max, rate, coeff, cp, use_gg, use_aero)

    def compute(self, inp: StepInput) -> np.ndarray:
        u = np.clip(self._apply_offset(self._law(inp)), -self.u_max, self.u_max)
        self.w_d_prev = inp.omega_RN_R.copy()
        return u


class ControllerBank:
    """One controller of each type for P episodes; the active one computes.

    :meth:`request` schedules a swap that takes effect at the next
    :meth:`compute` (a step boundary). Bumpless transfer:

    * to ``pid`` or ``fuzzy_pid`` from a controller with the same command
      kind (volts): states initialised so the first command equals the old
      controller's last (:meth:`PID.bumpless`, :meth:`FuzzyPID.bumpless`,
      which falls back to a decaying offset where no state achieves it);
    * to ``ga_flc`` or ``geometric`` (no state): a decaying offset
      (``bumpless_time_constant``) makes the first command equal the last;
    * between command kinds (volts <-> N m) there is nothing to match: the new
      controller starts from its own command; the jump is bounded by
      ``|u_last| + u_max`` of the new controller.

    Parameters
    ----------
    values : dict
        The controller node's parameters (``pid.kp``, ``fuzzy_pid.rules``, ...).
    dt : float
    n_episodes : int
    per_episode : dict, optional
        Per-episode overrides ``{"pid.kp": (P, 3), ...}``.
    """

    def __init__(self, values: dict, dt: float, n_episodes: int, per_episode: dict | None = None) -> None:
        self.dt = float(dt)
        self.n = n_episodes
        v = dict(values)
        v.update(per_episode or {})
        lim = v["output_limit"]
        angle = v["error_mode"] == "angle"
        self.controllers = {
            "pid": PID(v["pid.kp"], v["pid.ki"], v["pid.kd"], v["pid.n"], dt, lim, angle),
            "fuzzy_pid": FuzzyPID(
                PID(v["fuzzy_pid.kp"], v["fuzzy_pid.ki"], v["fuzzy_pid.kd"], v["fuzzy_pid.n"], dt, lim, angle),
                v["fuzzy_pid.e_scale"], v["fuzzy_pid.de_scale"], v["fuzzy_pid.u_scale"], v["fuzzy_pid.rules"],
                dt, lim),
            "ga_flc": GAFLC(v["ga_flc.rules"], v["ga_flc.mf_ratios"], v["ga_flc.scales"], lim),
            "geometric": Geometric(v["geometric.k"], v["geometric.l"], _inertia(v["geometric.inertia"]), dt,
                                   v["geometric.torque_limit"], _environment(v)),
        }
        self._set_limits(v)  # the constructors took the gains
        self._set_sensor(v)
        self.active = v["controller_type"]
        self.pending: str | None = None
        self.u_last: np.ndarray | None = None
        self.reset()

    def configure(self, v: dict) -> None:
        """Apply (possibly changed) gains to every controller; states are kept."""
        c = self.controllers
        c["pid"].set_gains(v["pid.kp"], v["pid.ki"], v["pid.kd"], v["pid.n"])
        c["fuzzy_pid"].pid.set_gains(v["fuzzy_pid.kp"], v["fuzzy_pid.ki"], v["fuzzy_pid.kd"], v["fuzzy_pid.n"])
        c["fuzzy_pid"].set_params(v["fuzzy_pid.e_scale"], v["fuzzy_pid.de_scale"], v["fuzzy_pid.u_scale"],
                                  v["fuzzy_pid.rules"])
        c["ga_flc"].set_params(v["ga_flc.rules"], v["ga_flc.mf_ratios"], v["ga_flc.scales"])
        c["geometric"].set_params(v["geometric.k"], v["geometric.l"], _inertia(v["geometric.inertia"]),
                                  _environment(v))
        self._set_limits(v)
        self._set_sensor(v)

    def _set_sensor(self, v: dict) -> None:
        """Sensor noise on the law's inputs (``sensor_noise.*``, scalars or per-episode (P,) arrays)."""
        seeds = np.atleast_1d(np.asarray(v["sensor_noise.seed"])).astype(np.int64)
        att = np.radians(np.atleast_1d(np.asarray(v["sensor_noise.attitude_std_deg"], dtype=float)))
        rate = np.radians(np.atleast_1d(np.asarray(v["sensor_noise.rate_std_deg_s"], dtype=float)))
        m = max(seeds.size, att.size, rate.size)
        self.sensor_seeds, self.sensor_att_std, self.sensor_rate_std = (
            np.ascontiguousarray(np.broadcast_to(a, (m,))) for a in (seeds, att, rate))
        #: the law sees measurements with noise (else the true state, bit for bit)
        self.noisy = bool(np.any(self.sensor_att_std > 0.0) or np.any(self.sensor_rate_std > 0.0))

    def measure(self, q_BN: np.ndarray, omega_BN_B: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """What the law sees at step ``k``: the state with this step's sensor noise (or the state itself).

        Each draw is a pure function of (``sensor_noise.seed``, k, channel)
        (:func:`attitude_sil.core.kernels.measure`), so a node that knows its
        step draws what the batch engine drew for that episode.
        """
        if not self.noisy:
            return q_BN, omega_BN_B
        return measure(np.ascontiguousarray(q_BN, dtype=float), np.ascontiguousarray(omega_BN_B, dtype=float),
                       int(k), self.sensor_seeds, self.sensor_att_std, self.sensor_rate_std)

    def _set_limits(self, v: dict) -> None:
        """The command kind, error mode, output limits and bumpless transfer of every controller."""
        c = self.controllers
        lim = v["output_limit"]
        self.command = v["command"]
        angle = v["error_mode"] == "angle"
        c["pid"].angle_mode = c["fuzzy_pid"].pid.angle_mode = angle
        for name in ("pid", "fuzzy_pid", "ga_flc"):
            c[name].u_max = lim
        c["fuzzy_pid"].pid.u_max = lim
        c["geometric"].u_max = v["geometric.torque_limit"]
        for name in ("fuzzy_pid", "ga_flc", "geometric"):
            c[name].set_transfer(v["bumpless_time_constant"], self.dt)

    def reset(self) -> None:
        """New episode: every controller's state cleared, no swap pending."""
        for ctrl in self.controllers.values():
            ctrl.reset(self.n)
        self.pending = None
        self.u_last = None

    def request(self, controller_type: str) -> None:
        """Swap to ``controller_type`` at the next step."""
        if controller_type not in self.controllers:
            raise ScenarioError(f"unknown controller_type {controller_type!r}")
        self.pending = None if controller_type == self.active else controller_type

    @property
    def kind(self) -> str:
        """``voltage`` or ``torque``: what the active controller commands.

        The PID family commands what ``command`` says (volts for wheel presets,
        torque for torque presets); the geometric law always commands torque.
        """
        return self.kind_of(self.active)

    def kind_of(self, controller_type: str) -> str:
        return "torque" if controller_type == "geometric" else self.command

    def compute(self, q_BN: np.ndarray, omega_BN_B: np.ndarray, q_RN: np.ndarray,
                omega_RN_R: np.ndarray, k: int | None = None) -> np.ndarray:
        """Command (P, 3) of the active controller for step ``k`` (V or N m, see :attr:`kind`).

        With sensor noise on (:attr:`noisy`) the law sees :meth:`measure` of
        the state, which needs the step ``k``.
        """
        if self.noisy:
            if k is None:
                raise ScenarioError("sensor noise needs the step index k")
            q_BN, omega_BN_B = self.measure(q_BN, omega_BN_B, k)
        inp = StepInput(np.asarray(q_BN, dtype=float), np.asarray(omega_BN_B, dtype=float),
                        np.asarray(q_RN, dtype=float), np.asarray(omega_RN_R, dtype=float))
        if self.pending is not None:
            old_kind = self.kind
            self.active, self.pending = self.pending, None
            new = self.controllers[self.active]
            new.reset(self.n)
            if self.u_last is not None and self.kind == old_kind:
                new.bumpless(inp, self.u_last)
        u = self.controllers[self.active].compute(inp)
        self.u_last = u
        return u


def _environment(v: dict) -> dict:
    """The geometric law's feed-forward settings from the controller's parameters."""
    env = {k: v[k] for k in ("aero.density", "aero.drag_coefficient", "aero.area", "aero.cp_offset")}
    env["models"] = list(v["geometric.feedforward"])
    env["rate"] = orbit_rate(v["orbit.mu"], v["orbit.radius"])
    env["speed"] = float(np.sqrt(v["orbit.mu"] / v["orbit.radius"]))
    return env


def _inertia(values) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    return np.diag(v) if v.shape[-1] == 3 else v.reshape(v.shape[:-1] + (3, 3))
