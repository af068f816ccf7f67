"""``geometric``: the almost-global attitude tracking law on SO(3) (paper 001 eq. 7), torque out.

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
step); ``M_env`` is the modelled environmental moment fed forward
(``geometric.feedforward``: gravity gradient and aerodynamic, computed from
Q with the reference taken as LVLH). Output saturated at ``±torque_limit``
per axis. :func:`torque_reference` is the same law in numpy, the tests'
reference.

No state but the last reference rate: a swap to it gets the generic decaying
offset (:mod:`attitude_sil.core.control.law`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.control.kernels import error_quat_row
from attitude_sil.core.control.law import Law, lanes
from attitude_sil.core.paramspec import ParamSpec, distinct, double, double_array, inertia_rule
from attitude_sil.core.plant.disturbance import aerodynamic_torque, gravity_gradient_torque, orbit_rate
from attitude_sil.core.plant.quaternion import cross, quat_to_dcm
from attitude_sil.core.plant.rigid_body import inertia_matrix

__all__ = ["LAW", "Params", "geometric_row", "torque_reference", "skew_vee"]

_HST_INERTIA = [31.046, 77.217, 78.754]


class Params(NamedTuple):
    """The geometric law's record."""

    k: np.ndarray  # (n, 3) diagonal of K, N m
    l: np.ndarray  # (n, 3) diagonal of L, N m s  # noqa: E741 - the paper's name
    inertia: np.ndarray  # (n, 3, 3) the law's model of J, kg m^2
    u_max: float  # torque limit, N m
    gg_rate: float  # orbit rate for the gravity-gradient feed-forward, rad/s
    aero_coeff: float  # 0.5 rho C_d A V^2 of the aerodynamic feed-forward, N
    cp_offset: np.ndarray  # (n, 3) centre-of-pressure offset, m
    use_gg: bool
    use_aero: bool


@njit(cache=True, inline="always")
def _jv(J, p, a, b, c):
    # J[p] @ (a, b, c) on scalars
    return (J[p, 0, 0] * a + J[p, 0, 1] * b + J[p, 0, 2] * c,
            J[p, 1, 0] * a + J[p, 1, 1] * b + J[p, 1, 2] * c,
            J[p, 2, 0] * a + J[p, 2, 1] * b + J[p, 2, 2] * c)


@njit(cache=True, inline="always")
def geometric_row(q_BN, omega, q_RN, w_d, w_d_prev, has_prev, p, par, dt, out):
    """The law for episode ``p`` alone, on scalars (no temporaries), saturated, into ``out[p]``."""
    k, l, inertia, cp_offset = par.k, par.l, par.inertia, par.cp_offset  # noqa: E741
    x, y, z, w = error_quat_row(q_BN, q_RN, p)  # q_BR: Q = R(q_BR) = R_d^T R
    q00, q01, q02 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    q10, q11, q12 = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    q20, q21, q22 = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
    a0, a1, a2 = w_d[p, 0], w_d[p, 1], w_d[p, 2]
    nu = (q00 * a0 + q10 * a1 + q20 * a2, q01 * a0 + q11 * a1 + q21 * a2, q02 * a0 + q12 * a1 + q22 * a2)
    # ω̇_d by the backward difference, zero at the first step: computed either way and chosen per element, so
    # that on the episode axis the choice is a select (a branch over a tuple keeps the loop scalar)
    d0, d1, d2 = (a0 - w_d_prev[p, 0]) / dt, (a1 - w_d_prev[p, 1]) / dt, (a2 - w_d_prev[p, 2]) / dt
    wdd = (q00 * d0 + q10 * d1 + q20 * d2 if has_prev else 0.0, q01 * d0 + q11 * d1 + q21 * d2 if has_prev else 0.0,
           q02 * d0 + q12 * d1 + q22 * d2 if has_prev else 0.0)
    jnu = _jv(inertia, p, nu[0], nu[1], nu[2])
    jwdd = _jv(inertia, p, wdd[0], wdd[1], wdd[2])
    s_k = (k[p, 2] * q21 - k[p, 1] * q12, k[p, 0] * q02 - k[p, 2] * q20, k[p, 1] * q10 - k[p, 0] * q01)
    cx = nu[1] * jnu[2] - nu[2] * jnu[1]
    cy = nu[2] * jnu[0] - nu[0] * jnu[2]
    cz = nu[0] * jnu[1] - nu[1] * jnu[0]
    t0 = -l[p, 0] * (omega[p, 0] - nu[0]) - s_k[0] + jwdd[0] + cx
    t1 = -l[p, 1] * (omega[p, 1] - nu[1]) - s_k[1] + jwdd[1] + cy
    t2 = -l[p, 2] * (omega[p, 2] - nu[2]) - s_k[2] + jwdd[2] + cz
    e0, e1, e2 = 0.0, 0.0, 0.0
    if par.use_gg:
        n0, n1, n2 = -q20, -q21, -q22  # -l3 in B: column 3 of R_BL = Q^T
        jn = _jv(inertia, p, n0, n1, n2)
        c = 3.0 * par.gg_rate * par.gg_rate
        e0 += c * (n1 * jn[2] - n2 * jn[1])
        e1 += c * (n2 * jn[0] - n0 * jn[2])
        e2 += c * (n0 * jn[1] - n1 * jn[0])
    if par.use_aero:
        v0, v1, v2 = q00, q01, q02  # l1 in B
        coeff = par.aero_coeff
        e0 += coeff * (v1 * cp_offset[p, 2] - v2 * cp_offset[p, 1])
        e1 += coeff * (v2 * cp_offset[p, 0] - v0 * cp_offset[p, 2])
        e2 += coeff * (v0 * cp_offset[p, 1] - v1 * cp_offset[p, 0])
    u_max = par.u_max
    out[p, 0] = min(max(t0 - e0, -u_max), u_max)
    out[p, 1] = min(max(t1 - e1, -u_max), u_max)
    out[p, 2] = min(max(t2 - e2, -u_max), u_max)


@njit(cache=True, inline="always")
def step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u):
    """The law's step: the torque, then the reference rate kept for the next step's ω̇_d."""
    geometric_row(q_BN, omega_BN_B, q_RN, omega_RN_R, st.w_d_prev, st.has_prev[p, 0], p, par, dt, u)
    for i in range(3):
        st.w_d_prev[p, i] = omega_RN_R[p, i]
    st.has_prev[p, 0] = True


def _record(values, n: int, dt: float) -> Params:
    models = list(values["feedforward"])
    rate = orbit_rate(values["orbit.mu"], values["orbit.radius"])
    speed = float(np.sqrt(values["orbit.mu"] / values["orbit.radius"]))
    coeff = 0.5 * values["aero.density"] * values["aero.drag_coefficient"] * values["aero.area"] * speed ** 2
    return Params(lanes(values["k"], n), lanes(values["l"], n), lanes(inertia_matrix(values["inertia"]), n, (3, 3)),
                  float(values["torque_limit"]), float(rate),
                  float(coeff), lanes(values["aero.cp_offset"], n), "gravity_gradient" in models,
                  "aerodynamic" in models)


def skew_vee(m: np.ndarray) -> np.ndarray:
    """vee of the skew part's generator: (M_32, M_13, M_21) of (P, 3, 3) M."""
    return np.stack((m[..., 2, 1], m[..., 0, 2], m[..., 1, 0]), axis=-1)


def torque_reference(values, q_BN, omega_BN_B, q_RN, omega_RN_R, w_d_prev=None, dt: float = 0.01) -> np.ndarray:
    """The unsaturated law in numpy, (P, 3) N m, from the module docstring's equations (the tests' reference).

    ``values`` holds the law's short parameter names and the orbit/aero ones;
    ``w_d_prev`` is the previous reference rate (None: ω̇_d = 0).
    """
    Q = np.swapaxes(quat_to_dcm(q_RN), -1, -2) @ quat_to_dcm(q_BN)  # R_d^T R (eq. 5)
    nu = np.einsum("pji,pj->pi", Q, omega_RN_R)
    w_e = omega_BN_B - nu
    w_d_dot = np.zeros_like(omega_RN_R) if w_d_prev is None else (omega_RN_R - w_d_prev) / dt
    K = np.asarray(values["k"], dtype=float)[..., :, None] * np.eye(3)
    s_k = skew_vee(K @ Q - np.swapaxes(Q, -1, -2) @ K)
    J = np.broadcast_to(inertia_matrix(values["inertia"]), Q.shape)
    jv = np.einsum("pij,pj->pi", J, nu)
    ff = np.einsum("pij,pj->pi", J, np.einsum("pji,pj->pi", Q, w_d_dot)) + cross(nu, jv)
    tau = -np.asarray(values["l"], dtype=float) * w_e - s_k + ff
    models = list(values.get("feedforward", []))
    R_BL = np.swapaxes(Q, -1, -2)
    if "gravity_gradient" in models:
        tau -= gravity_gradient_torque(R_BL, J, orbit_rate(values["orbit.mu"], values["orbit.radius"]))
    if "aerodynamic" in models:
        speed = float(np.sqrt(values["orbit.mu"] / values["orbit.radius"]))
        tau -= aerodynamic_torque(R_BL, values["aero.density"], values["aero.drag_coefficient"], values["aero.area"],
                                  speed, np.asarray(values["aero.cp_offset"]))
    return tau


LAW = Law(
    name="geometric",
    summary="almost-global tracking law on SO(3) with feed-forward (paper 001 eq. 7), N m",
    params=(
        double_array("k", [62.5, 16.5, 14.5], "diagonal of K, N m (distinct, > 0)", lengths=(3,), min=0.0,
                     min_exclusive=True, runtime=True, rule=distinct),
        double_array("l", [56.0, 139.0, 142.0], "diagonal of L, N m s", lengths=(3,), min=0.0,
                     min_exclusive=True, runtime=True),
        double_array("inertia", _HST_INERTIA, "the law's model of the inertia J, kg m^2 (3 or 9 values)",
                     lengths=(3, 9), runtime=True, rule=inertia_rule),
        double("torque_limit", 0.7, "torque saturation per body axis, N m", min=0.0, min_exclusive=True,
               runtime=True),
        ParamSpec("feedforward", "string_array", [],
                  "modelled environmental moments fed forward (paper 001 eq. 7): gravity_gradient, aerodynamic; "
                  "computed from Q, so the reference must be LVLH", choices=("gravity_gradient", "aerodynamic"),
                  runtime=True),
    ),
    state={"w_d_prev": (3, np.float64), "has_prev": (1, np.bool_)},
    record=_record,
    step=step,
    output="torque",
)
