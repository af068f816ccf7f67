"""Batch quaternion algebra in ROS order (x, y, z, w), Hamilton convention.

Every function takes arrays with a leading episode axis (shape ``(P, 4)`` for
quaternions, ``(P, 3)`` for vectors) and also accepts a single ``(4,)`` /
``(3,)`` array. ``q_BN`` is the orientation of frame B relative to frame N: it
maps body-frame vectors to inertial ones, ``v_N = q_BN ⊗ v_B ⊗ q_BN*``.

References are to paper 000 (Sayin et al., HST): eq. 8 (Euler to quaternion),
eq. 9 (quaternion to Euler), eq. 10-11 (kinematics).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "cross",
    "quat_multiply",
    "quat_conjugate",
    "quat_normalize",
    "quat_from_euler",
    "euler_from_quat",
    "quat_to_dcm",
    "quat_from_dcm",
    "quat_error",
    "error_vector",
    "quat_derivative",
    "attitude_error_B",
    "cross_matrix",
    "rotation_quaternion",
    "rotation_vector",
    "small_rotation",
]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis, shapes ``(..., 3)`` (broadcast against each other).

    Written out by components into one output array: ``np.cross``, and
    ``np.stack`` of the components, cost several times more on the small
    arrays of the lockstep loop.
    """
    a1, a2, a3 = a[..., 0], a[..., 1], a[..., 2]
    b1, b2, b3 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(np.shape(a), np.shape(b)))
    out[..., 0] = a2 * b3 - a3 * b2
    out[..., 1] = a3 * b1 - a1 * b3
    out[..., 2] = a1 * b2 - a2 * b1
    return out


def quat_multiply(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Hamilton product ``q ⊗ p`` of quaternions in (x, y, z, w) order.

    Parameters
    ----------
    q, p : ndarray, shape (..., 4)
        Broadcast against each other (one quaternion times many needs no copies).

    Returns
    -------
    ndarray, shape (..., 4)
    """
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    px, py, pz, pw = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    out = np.empty(np.broadcast_shapes(np.shape(q), np.shape(p)))  # components written in place: no np.stack
    out[..., 0] = qw * px + pw * qx + qy * pz - qz * py
    out[..., 1] = qw * py + pw * qy + qz * px - qx * pz
    out[..., 2] = qw * pz + pw * qz + qx * py - qy * px
    out[..., 3] = qw * pw - qx * px - qy * py - qz * pz
    return out


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate (inverse of a unit quaternion), shape (..., 4)."""
    out = -np.asarray(q, dtype=float)
    out[..., 3] = -out[..., 3]
    return out


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Scale to unit norm, shape (..., 4). Raises ``ValueError`` on a zero quaternion."""
    q = np.asarray(q, dtype=float)
    n = np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
    if np.any(n == 0.0) or not np.all(np.isfinite(n)):
        raise ValueError("quaternion has zero or non-finite norm")
    return q / n


def quat_from_euler(rpy: np.ndarray) -> np.ndarray:
    """Quaternion q_BN from roll, pitch, yaw (rad), ZYX sequence (paper 000 eq. 8).

    Parameters
    ----------
    rpy : ndarray, shape (..., 3)
        Roll (x), pitch (y), yaw (z) in rad.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion (x, y, z, w).
    """
    rpy = np.asarray(rpy, dtype=float)
    hr, hp, hy = rpy[..., 0] / 2, rpy[..., 1] / 2, rpy[..., 2] / 2
    cr, sr = np.cos(hr), np.sin(hr)
    cp, sp = np.cos(hp), np.sin(hp)
    cy, sy = np.cos(hy), np.sin(hy)
    return np.stack(
        (
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ),
        axis=-1,
    )


def euler_from_quat(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (rad) of q_BN, ZYX sequence (paper 000 eq. 9).

    Parameters
    ----------
    q : ndarray, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 3)
        Roll in (-pi, pi], pitch in [-pi/2, pi/2], yaw in (-pi, pi].
    """
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack((roll, pitch, yaw), axis=-1)


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """Rotation matrix R_NB (maps B components to N components), shape (..., 3, 3)."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def quat_from_dcm(r: np.ndarray) -> np.ndarray:
    """The quaternion (..., 4) x y z w, scalar part >= 0, whose :func:`quat_to_dcm` is ``r`` (..., 3, 3)
    (Shepperd's method: from the largest of the four squares, row by row)."""
    r = np.asarray(r, dtype=float)
    r00, r11, r22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    tr = r00 + r11 + r22
    i = np.argmax(np.stack([tr, r00, r11, r22], axis=-1), axis=-1)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):  # the cases not taken may take roots of negatives
        w = 0.5 * np.sqrt(1.0 + tr)
        x = 0.5 * np.sqrt(1.0 + r00 - r11 - r22)
        y = 0.5 * np.sqrt(1.0 - r00 + r11 - r22)
        z = 0.5 * np.sqrt(1.0 - r00 - r11 + r22)
        cases = [
            [(r[..., 2, 1] - r[..., 1, 2]) / (4 * w), (r[..., 0, 2] - r[..., 2, 0]) / (4 * w),
             (r[..., 1, 0] - r[..., 0, 1]) / (4 * w), w],
            [x, (r[..., 0, 1] + r[..., 1, 0]) / (4 * x), (r[..., 0, 2] + r[..., 2, 0]) / (4 * x),
             (r[..., 2, 1] - r[..., 1, 2]) / (4 * x)],
            [(r[..., 0, 1] + r[..., 1, 0]) / (4 * y), y, (r[..., 1, 2] + r[..., 2, 1]) / (4 * y),
             (r[..., 0, 2] - r[..., 2, 0]) / (4 * y)],
            [(r[..., 0, 2] + r[..., 2, 0]) / (4 * z), (r[..., 1, 2] + r[..., 2, 1]) / (4 * z), z,
             (r[..., 1, 0] - r[..., 0, 1]) / (4 * z)],
        ]
    q = np.select([i == 0, i == 1, i == 2], [np.stack(c, axis=-1) for c in cases[:3]], np.stack(cases[3], axis=-1))
    return np.where(q[..., 3:] < 0.0, -q, q)


def quat_error(q_BN: np.ndarray, q_RN: np.ndarray) -> np.ndarray:
    """Error quaternion q_BR = q_RN* ⊗ q_BN: the body's attitude relative to the reference.

    Returned with a non-negative scalar part (the short way round).

    Parameters
    ----------
    q_BN, q_RN : ndarray, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 4)
    """
    q_BR = quat_multiply(quat_conjugate(q_RN), q_BN)
    sign = np.where(q_BR[..., 3:4] < 0.0, -1.0, 1.0)
    return q_BR * sign


def error_vector(q_BN: np.ndarray, q_RN: np.ndarray) -> np.ndarray:
    """Quaternion error vector the controllers act on, shape (..., 3).

    ``e = -vec(q_BR)`` with q_BR from :func:`quat_error`: for small angles
    ``e ≈ (setpoint - attitude) / 2`` per body axis, so a positive entry asks
    for a positive torque about that axis (paper 000, section 2.B: "a
    quaternion error vector ... used as input to the controller").
    """
    return -quat_error(q_BN, q_RN)[..., :3]


def attitude_error_B(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The small rotation (..., 3) rad taking ``q_ref`` to ``q`` in the body frame: 2 vec(q_ref* ⊗ q), short way.

    Per body axis, about ``q - q_ref`` for small angles: with q_ref the setpoint and q the attitude it is the
    pointing error (APE), with q_ref the truth and q the estimate the knowledge error (AKE).
    """
    d = quat_multiply(quat_conjugate(q_ref), q)
    return 2.0 * np.where(d[..., 3:4] < 0.0, -d[..., :3], d[..., :3])


def cross_matrix(v: np.ndarray) -> np.ndarray:
    """[v x]: the matrix (..., 3, 3) of the cross product with v (..., 3), ``cross_matrix(a) @ b = a x b``."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def rotation_quaternion(theta: np.ndarray) -> np.ndarray:
    """exp(theta / 2): the unit quaternion (..., 4) of rotation vector theta (..., 3) rad, exact."""
    theta = np.asarray(theta, dtype=float)
    angle = np.sqrt(np.sum(theta * theta, axis=-1, keepdims=True))
    half = 0.5 * angle
    # sin(a/2)/a, by its series below 1e-4 rad (error < 1e-17)
    small = angle < 1e-4
    safe = np.where(small, 1.0, angle)
    s = np.where(small, 0.5 - angle * angle / 48.0, np.sin(half) / safe)
    return np.concatenate([theta * s, np.cos(half)], axis=-1)


def rotation_vector(q: np.ndarray) -> np.ndarray:
    """The rotation vector (..., 3) rad of unit quaternions (..., 4), the short way (inverse of
    :func:`rotation_quaternion`)."""
    q = np.where(np.asarray(q)[..., 3:4] < 0.0, -np.asarray(q), np.asarray(q))
    v = q[..., :3]
    s = np.sqrt(np.sum(v * v, axis=-1, keepdims=True))
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    small = s < 1e-12
    return v * np.where(small, 2.0 / np.maximum(q[..., 3:4], 1e-300), angle / np.where(small, 1.0, s))


def small_rotation(d: np.ndarray) -> np.ndarray:
    """The unit quaternion (..., 4) of a small rotation vector d (..., 3) rad: [d / 2, 1] normalised (the
    multiplicative filter's error convention; :func:`rotation_quaternion` is the exact map)."""
    half = 0.5 * np.asarray(d, dtype=float)
    return quat_normalize(np.concatenate([half, np.ones(half.shape[:-1] + (1,))], axis=-1))


def quat_derivative(q: np.ndarray, omega_B: np.ndarray) -> np.ndarray:
    """Kinematics dq/dt = 1/2 Ω(ω) q (paper 000 eq. 10-11), i.e. 1/2 q ⊗ (ω, 0).

    Parameters
    ----------
    q : ndarray, shape (..., 4)
        q_BN, (x, y, z, w).
    omega_B : ndarray, shape (..., 3)
        omega_BN in B, rad/s.

    Returns
    -------
    ndarray, shape (..., 4)
    """
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    w1, w2, w3 = omega_B[..., 0], omega_B[..., 1], omega_B[..., 2]
    return 0.5 * np.stack(
        (
            w3 * y - w2 * z + w1 * w,
            -w3 * x + w1 * z + w2 * w,
            w2 * x - w1 * y + w3 * w,
            -w1 * x - w2 * y - w3 * z,
        ),
        axis=-1,
    )


#: how far from unit norm a received quaternion may be and still be renormalised (beyond: refused)
UNIT_NORM_TOLERANCE = 1e-3


def unit_or_none(q: np.ndarray, tolerance: float = UNIT_NORM_TOLERANCE) -> np.ndarray | None:
    """A received quaternion (..., 4) renormalised if its norm is within ``tolerance`` of 1, else None (NaN too).

    Quaternions that come over a topic carry rounding (renormalised here, so a
    law never sees a scaled attitude: a norm of 10 scales the error vector and
    the command tenfold); one further off is not an attitude and is refused.
    Norms within 1e-12 of 1 pass unchanged.
    """
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.abs(norm - 1.0) <= tolerance):
        return None
    return q if np.all(np.abs(norm - 1.0) <= 1e-12) else q / norm
