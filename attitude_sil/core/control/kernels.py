"""Compiled scalar helpers the control laws share (numba, inlined into each law's step).

The error quaternion and vector of the PID family, the reference rate in B,
the error rate a bumpless entry starts from, the 7-set fuzzy inference rows
and the decaying transfer offset: one home each, used by the built-in laws
in :mod:`attitude_sil.core.control.laws` and open to a plugin law.
Every helper works on row ``p`` of its arrays, so the node (one row), the
stepwise driver and the compiled loop run the same arithmetic.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["error_quat_row", "error3_row", "reference_rate_row", "error_and_rate_row", "infer_row",
           "infer_uniform_row", "infer_vertices_row", "fuzzy_infer", "offset_row", "apply_offsets"]


@njit(cache=True, inline="always")
def error_quat_row(q_BN, q_RN, p):
    # q_BR = q_RN* ⊗ q_BN with a non-negative scalar part
    bx, by, bz, bw = q_BN[p, 0], q_BN[p, 1], q_BN[p, 2], q_BN[p, 3]
    rx, ry, rz, rw = -q_RN[p, 0], -q_RN[p, 1], -q_RN[p, 2], q_RN[p, 3]
    ex = rw * bx + bw * rx + ry * bz - rz * by
    ey = rw * by + bw * ry + rz * bx - rx * bz
    ez = rw * bz + bw * rz + rx * by - ry * bx
    ew = rw * bw - rx * bx - ry * by - rz * bz
    if ew < 0.0:
        return -ex, -ey, -ez, -ew
    return ex, ey, ez, ew


@njit(cache=True, inline="always")
def _segment_uniform(x):
    # _segment for the evenly spaced vertices -1, -2/3, ..., 1: direct index
    if x <= -1.0:
        return 0, 0.0
    if x >= 1.0:
        return 5, 1.0
    s = (x + 1.0) * 3.0
    j = min(int(s), 5)
    return j, s - j


@njit(cache=True, inline="always")
def infer_uniform_row(xr, xc, rules, p):
    # infer_row with evenly spaced input and output sets (output centre of set k is (k - 4) / 3), rules[p]
    i, ti = _segment_uniform(xr)
    j, tj = _segment_uniform(xc)
    c00, c01, c10, c11 = rules[p, i, j], rules[p, i, j + 1], rules[p, i + 1, j], rules[p, i + 1, j + 1]
    return ((1.0 - ti) * ((1.0 - tj) * c00 + tj * c01) + ti * ((1.0 - tj) * c10 + tj * c11) - 4.0) / 3.0


@njit(cache=True, inline="always")
def error3_row(q_BN, q_RN, p, angle_mode):
    # the error vector e = -vec(q_BR) (short way round), or 2 asin(e_i) per axis in angle mode
    ex, ey, ez, _ = error_quat_row(q_BN, q_RN, p)
    if angle_mode:
        return 2.0 * np.arcsin(-ex), 2.0 * np.arcsin(-ey), 2.0 * np.arcsin(-ez)
    return -ex, -ey, -ez


@njit(cache=True, inline="always")
def _segment(x, v, p, a):
    # clip to [-1, 1], find the segment [v_j, v_j+1] of the vertices v[p, a] holding x; returns (j, t)
    if x <= v[p, a, 0]:
        return 0, 0.0
    if x >= v[p, a, 6]:
        return 5, 1.0
    j = 0
    for k in range(1, 6):  # a fixed-length scan compiles to branch-light code (2x faster than a while)
        if x > v[p, a, k]:
            j = k
    return j, (x - v[p, a, j]) / (v[p, a, j + 1] - v[p, a, j])


@njit(cache=True)
def fuzzy_infer(x_row, x_col, v_row, v_col, rules, centres):
    """Two-input, 7-set fuzzy inference for every episode and axis (see ``fuzzy.infer``).

    Shapes: x_row, x_col (P, 3) normalised inputs; v_row, v_col (P, 3, 7)
    vertices; rules (P, 7, 7) int, 1..7, rows indexed by x_row; centres
    (P, 3, 7) output-set centres. Returns (P, 3) in [-1, 1].
    """
    m = x_row.shape[0]
    out = np.empty((m, 3))
    for p in range(m):
        for a in range(3):
            i, ti = _segment(x_row[p, a], v_row, p, a)
            j, tj = _segment(x_col[p, a], v_col, p, a)
            mi0, mi1 = 1.0 - ti, ti
            mj0, mj1 = 1.0 - tj, tj
            c = centres[p, a]
            r = rules[p]
            out[p, a] = (mi0 * (mj0 * c[r[i, j] - 1] + mj1 * c[r[i, j + 1] - 1])
                         + mi1 * (mj0 * c[r[i + 1, j] - 1] + mj1 * c[r[i + 1, j + 1] - 1]))
    return out


@njit(cache=True, inline="always")
def infer_row(xr, xc, v, r, p):
    # episode p's inference: rows of v[p, 0], columns of v[p, 1], output centres v[p, 2], rules r[p]
    i, ti = _segment(xr, v, p, 0)
    j, tj = _segment(xc, v, p, 1)
    return ((1.0 - ti) * ((1.0 - tj) * v[p, 2, r[p, i, j] - 1] + tj * v[p, 2, r[p, i, j + 1] - 1])
            + ti * ((1.0 - tj) * v[p, 2, r[p, i + 1, j] - 1] + tj * v[p, 2, r[p, i + 1, j + 1] - 1]))


@njit(cache=True, inline="always")
def reference_rate_row(x, y, z, w, w_d, p):
    # Q^T w_d = R(conj(q_BR)) w_d for q_BR = (x, y, z, w): v + 2 w (r x v) + 2 r x (r x v) with r = -vec(q_BR)
    vx, vy, vz = w_d[p, 0], w_d[p, 1], w_d[p, 2]
    if vx == 0.0 and vy == 0.0 and vz == 0.0:
        return 0.0, 0.0, 0.0
    rx, ry, rz = -x, -y, -z
    cx, cy, cz = ry * vz - rz * vy, rz * vx - rx * vz, rx * vy - ry * vx
    ccx, ccy, ccz = ry * cz - rz * cy, rz * cx - rx * cz, rx * cy - ry * cx
    return vx + 2.0 * (w * cx + ccx), vy + 2.0 * (w * cy + ccy), vz + 2.0 * (w * cz + ccz)


@njit(cache=True, inline="always")
def error_and_rate_row(q_BN, omega, q_RN, w_d, p, angle_mode):
    """The PID family's error of episode ``p`` and its time derivative, two 3-tuples.

    ``e = -vec(q_BR)`` (or ``2 asin(e)`` per axis in angle mode) and, with
    ``ω_e = ω - Q^T ω_d``, ``de/dt = -½ (w ω_e + v × ω_e)`` for ``q_BR = (v, w)``
    (the angle's rate is ``2 ė / sqrt(1 - e²)``, floored at 1e-12 under the root).
    """
    x, y, z, s = error_quat_row(q_BN, q_RN, p)
    nu = reference_rate_row(x, y, z, s, w_d, p)
    wx, wy, wz = omega[p, 0] - nu[0], omega[p, 1] - nu[1], omega[p, 2] - nu[2]
    e = (-x, -y, -z)
    de = (-0.5 * (s * wx + (y * wz - z * wy)), -0.5 * (s * wy + (z * wx - x * wz)),
          -0.5 * (s * wz + (x * wy - y * wx)))
    if not angle_mode:
        return e, de
    ea, da = np.empty(3), np.empty(3)
    for i in range(3):
        c = min(max(e[i], -1.0), 1.0)
        ea[i] = 2.0 * np.arcsin(c)
        da[i] = 2.0 * de[i] / np.sqrt(max(1.0 - e[i] * e[i], 1e-12))
    return (ea[0], ea[1], ea[2]), (da[0], da[1], da[2])


@njit(cache=True, inline="always")
def infer_vertices_row(xr, xc, v, rules, p):
    # fuzzy_infer's arithmetic for one element, with the vertices v[0, 0] (v (1, 1, 7)) for rows, columns and
    # output, and the rules of episode p
    i, ti = _segment(xr, v, 0, 0)
    j, tj = _segment(xc, v, 0, 0)
    c, r = v[0, 0], rules
    return ((1.0 - ti) * ((1.0 - tj) * c[r[p, i, j] - 1] + tj * c[r[p, i, j + 1] - 1])
            + ti * ((1.0 - tj) * c[r[p, i + 1, j] - 1] + tj * c[r[p, i + 1, j + 1] - 1]))


@njit(cache=True, inline="always")
def offset_row(u, p, offset, has_offset, decay):
    """Add row ``p``'s decaying bumpless offset to ``u[p]`` (see ``controllers._Stateless``).

    The offset decays by ``decay`` per step and ends, for this episode alone,
    once all three components are below 1e-15.
    """
    if not has_offset[p]:
        return
    small = True
    for i in range(3):
        u[p, i] = u[p, i] + offset[p, i]
        offset[p, i] = offset[p, i] * decay
        small = small and abs(offset[p, i]) < 1e-15
    if small:
        has_offset[p] = False
        for i in range(3):
            offset[p, i] = 0.0


@njit(cache=True)
def apply_offsets(u, offset, has_offset, decay):
    """:func:`offset_row` for every episode, in place on ``u`` (P, 3)."""
    for p in range(u.shape[0]):
        offset_row(u, p, offset, has_offset, decay)
