"""Rigid spacecraft body with reaction-wheel momentum, integrated with fixed-step RK4.

State per episode: ``q_BN`` (P, 4), ``omega_BN_B`` (P, 3) rad/s and the wheel
momentum ``h_wheels_B`` (P, 3) N m s. Over one held interval the wheels deliver
a constant mean control torque ``tau_c_B`` (the wheels node computes it as
``-(h(t_k+1) - h(t_k)) / dt``), so inside the plant ``dh/dt = -tau_c`` (paper 000
eq. 3) and the total body+wheel momentum obeys ``dH_B/dt = -ω × H_B + N_e``
exactly in continuous time: the only momentum error left is RK4's truncation.

Dynamics (paper 000 eq. 4)::

    I ω̇ = -ω × (I ω) - ω × h_w + N_c + N_e

kinematics (eq. 10-11) ``q̇ = ½ Ω(ω) q``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from attitude_sil.core.plant.kernels import rk4_body
from attitude_sil.core.plant.quaternion import cross, quat_derivative, quat_to_dcm
from attitude_sil.errors import ScenarioError

__all__ = ["BodyState", "body_derivatives", "rk4_step", "inertial_momentum", "inertia_matrix"]


@dataclass
class BodyState:
    """Batch state of the spacecraft body.

    Attributes
    ----------
    q_BN : ndarray, shape (P, 4)
    omega_BN_B : ndarray, shape (P, 3), rad/s
    h_wheels_B : ndarray, shape (P, 3), N m s
    """

    q_BN: np.ndarray
    omega_BN_B: np.ndarray
    h_wheels_B: np.ndarray

    def copy(self) -> BodyState:
        return BodyState(self.q_BN.copy(), self.omega_BN_B.copy(), self.h_wheels_B.copy())


def _matvec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Batched 3x3 matrix times vector: (P,3,3) x (P,3) -> (P,3)."""
    return (m * v[:, None, :]).sum(axis=-1)


def body_derivatives(
    q_BN: np.ndarray,
    omega_BN_B: np.ndarray,
    h_wheels_B: np.ndarray,
    inertia: np.ndarray,
    inertia_inv: np.ndarray,
    tau_c_B: np.ndarray,
    tau_ext_B: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time derivatives of (q, ω, h) from paper 000 eq. 3, 4 and 10.

    Parameters
    ----------
    q_BN : (P, 4)
    omega_BN_B : (P, 3) rad/s
    h_wheels_B : (P, 3) N m s
    inertia, inertia_inv : (P, 3, 3) kg m^2 and its inverse
    tau_c_B : (P, 3) N m, control torque of the wheels on the body
    tau_ext_B : (P, 3) N m, external (disturbance) torque

    Returns
    -------
    q_dot (P, 4), omega_dot (P, 3) rad/s^2, h_dot (P, 3) N m
    """
    h_total = _matvec(inertia, omega_BN_B) + h_wheels_B
    omega_dot = _matvec(inertia_inv, -cross(omega_BN_B, h_total) + tau_c_B + tau_ext_B)
    return quat_derivative(q_BN, omega_BN_B), omega_dot, -tau_c_B


def rk4_step(
    state: BodyState,
    inertia: np.ndarray,
    inertia_inv: np.ndarray,
    tau_c_B: np.ndarray,
    tau_ext_B: np.ndarray,
    dt: float,
    substeps: int = 1,
) -> BodyState:
    """Advance the body over one held-input interval with classic RK4.

    The arithmetic of :func:`body_derivatives`, compiled
    (:func:`attitude_sil.core.plant.kernels.rk4_body`).

    The torques are held over ``[t, t + dt]``; the interval is split into
    ``substeps`` equal RK4 steps. The quaternion is renormalised at the end.

    Parameters
    ----------
    state : BodyState at t
    inertia, inertia_inv : (P, 3, 3)
    tau_c_B, tau_ext_B : (P, 3) N m, held
    dt : float, s
    substeps : int >= 1

    Returns
    -------
    BodyState at t + dt (new arrays).
    """
    q, w, h = rk4_body(
        np.ascontiguousarray(state.q_BN, dtype=float),
        np.ascontiguousarray(state.omega_BN_B, dtype=float),
        np.ascontiguousarray(state.h_wheels_B, dtype=float),
        np.ascontiguousarray(inertia, dtype=float),
        np.ascontiguousarray(inertia_inv, dtype=float),
        np.ascontiguousarray(tau_c_B, dtype=float),
        np.ascontiguousarray(tau_ext_B, dtype=float),
        float(dt),
        int(substeps),
    )
    return BodyState(q, w, h)


def inertial_momentum(
    q_BN: np.ndarray, omega_BN_B: np.ndarray, h_wheels_B: np.ndarray, inertia: np.ndarray
) -> np.ndarray:
    """Total angular momentum of body plus wheels in the inertial frame, (P, 3) N m s.

    ``H_N = R_NB (I ω + h_w)``; constant when no external torque acts.
    """
    return _matvec(quat_to_dcm(q_BN), _matvec(inertia, omega_BN_B) + h_wheels_B)


def inertia_matrix(values) -> np.ndarray:
    """3 principal values or 9 row-major entries (or (P, 3) / (P, 9)) -> (..., 3, 3) kg m^2.

    Raises ``ValueError`` unless symmetric and positive definite.
    """
    v = np.asarray(values, dtype=float)
    m = v[..., :, None] * np.eye(3) if v.shape[-1] == 3 else v.reshape(v.shape[:-1] + (3, 3))
    mt = np.swapaxes(m, -1, -2)
    if not np.all(np.abs(m - mt) <= 1e-8 + 1e-5 * np.abs(mt)):  # np.allclose's test, without its overhead
        raise ScenarioError("inertia must be symmetric")
    if np.any(np.linalg.eigvalsh(m) <= 0.0):
        raise ScenarioError("inertia must be positive definite")
    return m
