"""Compiled inner loops of the lockstep step (numba), one loop over episodes each.

Profiling the batch engine at P = 50 showed ~300 small numpy calls per step,
each ~1 us: call overhead, not arithmetic, set the speed. These kernels do the
same arithmetic as the documented equations in one compiled loop. The nodes
call the same kernels with P = 1, so graph and batch stay bit-identical.
``cache=True`` keeps the compiled code next to the module after the first run.

* :func:`rk4_body` — RK4 of paper 000 eq. 3, 4, 10-11 (see ``rigid_body``);
* :func:`pid_step` — quaternion-error PID with filtered derivative and
  conditional-integration anti-windup (see ``controllers.PID``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["rk4_body", "pid_step"]


@njit(cache=True, inline="always")
def _deriv(q, w, h, ii, iv, tc, te):
    # the body's derivatives on scalars: q (4-tuple), w, h, tc, te (3-tuples), ii and iv (9-tuples, row-major)
    # H = I w + h
    hx = ii[0] * w[0] + ii[1] * w[1] + ii[2] * w[2] + h[0]
    hy = ii[3] * w[0] + ii[4] * w[1] + ii[5] * w[2] + h[1]
    hz = ii[6] * w[0] + ii[7] * w[1] + ii[8] * w[2] + h[2]
    # rhs = -w x H + tau_c + tau_e
    rx = -(w[1] * hz - w[2] * hy) + tc[0] + te[0]
    ry = -(w[2] * hx - w[0] * hz) + tc[1] + te[1]
    rz = -(w[0] * hy - w[1] * hx) + tc[2] + te[2]
    dw = (iv[0] * rx + iv[1] * ry + iv[2] * rz,
          iv[3] * rx + iv[4] * ry + iv[5] * rz,
          iv[6] * rx + iv[7] * ry + iv[8] * rz)
    # q' = 1/2 Omega(w) q, eq. 10-11, (x, y, z, w) order
    x, y, z, s = q
    dq = (0.5 * (w[2] * y - w[1] * z + w[0] * s),
          0.5 * (-w[2] * x + w[0] * z + w[1] * s),
          0.5 * (w[1] * x - w[0] * y + w[2] * s),
          0.5 * (-w[0] * x - w[1] * y - w[2] * z))
    return dq, dw, (-tc[0], -tc[1], -tc[2])


@njit(cache=True, inline="always")
def _stage4(c, k, a):
    # RK4 intermediate state c + a k of a 4-tuple
    return (c[0] + a * k[0], c[1] + a * k[1], c[2] + a * k[2], c[3] + a * k[3])


@njit(cache=True, inline="always")
def _stage3(c, k, a):
    return (c[0] + a * k[0], c[1] + a * k[1], c[2] + a * k[2])


@njit(cache=True, inline="always")
def _combine4(c, k1, k2, k3, k4, sixth):
    return (c[0] + sixth * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]),
            c[1] + sixth * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]),
            c[2] + sixth * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]),
            c[3] + sixth * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3]))


@njit(cache=True, inline="always")
def _combine3(c, k1, k2, k3, k4, sixth):
    return (c[0] + sixth * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]),
            c[1] + sixth * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]),
            c[2] + sixth * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]))


@njit(cache=True, inline="always")
def _row3(a, p):
    return a[p, 0], a[p, 1], a[p, 2]


@njit(cache=True, inline="always")
def _mat9(a, p):
    return (a[p, 0, 0], a[p, 0, 1], a[p, 0, 2], a[p, 1, 0], a[p, 1, 1], a[p, 1, 2], a[p, 2, 0], a[p, 2, 1], a[p, 2, 2])


@njit(cache=True, inline="always")
def rk4_body_row(q, w, h, inertia, inertia_inv, tau_c, tau_e, p, dt, substeps, qo, wo, ho):
    """RK4 over one held interval for episode ``p``, on scalars: no temporaries, no array views.

    Reads row ``p`` of q (P, 4), w, h, tau_c, tau_e (P, 3), inertia and
    inertia_inv (P, 3, 3); writes row ``p`` of ``qo``, ``wo``, ``ho`` (which
    may be the inputs). The quaternion is renormalised at the end.
    """
    step = dt / substeps
    half = 0.5 * step
    sixth = step / 6.0
    ii, iv = _mat9(inertia, p), _mat9(inertia_inv, p)
    tc, te = _row3(tau_c, p), _row3(tau_e, p)
    cq = (q[p, 0], q[p, 1], q[p, 2], q[p, 3])
    cw, ch = _row3(w, p), _row3(h, p)
    for _ in range(substeps):
        k1q, k1w, k1h = _deriv(cq, cw, ch, ii, iv, tc, te)
        k2q, k2w, k2h = _deriv(_stage4(cq, k1q, half), _stage3(cw, k1w, half), _stage3(ch, k1h, half), ii, iv, tc, te)
        k3q, k3w, k3h = _deriv(_stage4(cq, k2q, half), _stage3(cw, k2w, half), _stage3(ch, k2h, half), ii, iv, tc, te)
        k4q, k4w, k4h = _deriv(_stage4(cq, k3q, step), _stage3(cw, k3w, step), _stage3(ch, k3h, step), ii, iv, tc, te)
        cq = _combine4(cq, k1q, k2q, k3q, k4q, sixth)
        cw = _combine3(cw, k1w, k2w, k3w, k4w, sixth)
        ch = _combine3(ch, k1h, k2h, k3h, k4h, sixth)
    norm = np.sqrt(cq[0] * cq[0] + cq[1] * cq[1] + cq[2] * cq[2] + cq[3] * cq[3])
    for i in range(4):
        qo[p, i] = cq[i] / norm
    for i in range(3):
        wo[p, i] = cw[i]
        ho[p, i] = ch[i]


@njit(cache=True)
def rk4_body(q, w, h, inertia, inertia_inv, tau_c, tau_e, dt, substeps):
    """RK4 over one held interval for every episode; returns new (q, w, h) arrays.

    Shapes: q (P, 4), w and h (P, 3), inertia and inertia_inv (P, 3, 3),
    tau_c and tau_e (P, 3). The quaternion is renormalised at the end.
    """
    qo = np.empty_like(q)
    wo = np.empty_like(w)
    ho = np.empty_like(h)
    rk4_body_into(q, w, h, inertia, inertia_inv, tau_c, tau_e, dt, substeps, qo, wo, ho)
    return qo, wo, ho


@njit(cache=True, inline="always")
def rk4_body_into(q, w, h, inertia, inertia_inv, tau_c, tau_e, dt, substeps, qo, wo, ho):
    """:func:`rk4_body` into given arrays; ``qo``, ``wo``, ``ho`` may be ``q``, ``w``, ``h`` (in place)."""
    for p in range(q.shape[0]):
        rk4_body_row(q, w, h, inertia, inertia_inv, tau_c, tau_e, p, dt, substeps, qo, wo, ho)


@njit(cache=True, inline="always")
def _error_quat(q_BN, q_RN, p):
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
def _infer_uniform(xr, xc, rules, p):
    # _infer1 with evenly spaced input and output sets (output centre of set k is (k - 4) / 3), rules[p]
    i, ti = _segment_uniform(xr)
    j, tj = _segment_uniform(xc)
    c00, c01, c10, c11 = rules[p, i, j], rules[p, i, j + 1], rules[p, i + 1, j], rules[p, i + 1, j + 1]
    return ((1.0 - ti) * ((1.0 - tj) * c00 + tj * c01) + ti * ((1.0 - tj) * c10 + tj * c11) - 4.0) / 3.0


@njit(cache=True, inline="always")
def _error3(q_BN, q_RN, p, angle_mode):
    # the error vector e = -vec(q_BR) (short way round), or 2 asin(e_i) per axis in angle mode
    ex, ey, ez, _ = _error_quat(q_BN, q_RN, p)
    if angle_mode:
        return 2.0 * np.arcsin(-ex), 2.0 * np.arcsin(-ey), 2.0 * np.arcsin(-ez)
    return -ex, -ey, -ez


@njit(cache=True)
def pid_step(q_BN, q_RN, kp, ki, kd, n, a, integral, filt, dt, u_max, angle_mode):
    """One PID step for every episode and axis; updates ``integral`` and ``filt`` in place.

    Error vector e = -vec(q_RN* ⊗ q_BN), sign chosen so the scalar part is
    non-negative; with ``angle_mode`` each component becomes ``2 asin(e_i)``,
    the rotation angle about that axis. Returns the saturated command (P, 3).
    """
    u = np.empty((q_BN.shape[0], 3))
    pid_step_into(q_BN, q_RN, kp, ki, kd, n, a, integral, filt, dt, u_max, angle_mode, u)
    return u


@njit(cache=True, inline="always")
def pid_step_into(q_BN, q_RN, kp, ki, kd, n, a, integral, filt, dt, u_max, angle_mode, u):
    """:func:`pid_step` writing the command into ``u`` (P, 3)."""
    for p in range(q_BN.shape[0]):
        pid_row(q_BN, q_RN, p, kp, ki, kd, n, a, integral, filt, dt, u_max, angle_mode, u)


@njit(cache=True, inline="always")
def pid_row(q_BN, q_RN, p, kp, ki, kd, n, a, integral, filt, dt, u_max, angle_mode, u):
    """:func:`pid_step_into` for episode ``p`` alone (row ``p`` of every array)."""
    e = _error3(q_BN, q_RN, p, angle_mode)
    for i in range(3):
        deriv = n[p, i] * (e[i] - filt[p, i])
        raw = kp[p, i] * e[i] + ki[p, i] * integral[p, i] + kd[p, i] * deriv
        out = min(max(raw, -u_max), u_max)
        if not (out != raw and e[i] * raw > 0.0):
            integral[p, i] += e[i] * dt
        filt[p, i] = a[p, i] * filt[p, i] + (1.0 - a[p, i]) * e[i]
        u[p, i] = out


@njit(cache=True)
def wheel_step(x, v_cmd, k, allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, dt,
               torque_mode, k_i, r_a, b_m, fail_j, fail_k, fail_stuck, e_hold, coast):
    """Drive limits, exact motor step and mean body torque for every episode at step ``k``.

    Shapes: x (P, n, 3) wheel state (angle, current, speed) at t_k, v_cmd (P, 3)
    body-axis voltage (or, with ``torque_mode``, body torque in N m), allocation
    (n, 3) pseudo-inverse, axes (3, n). Motor constants per episode (M = 1 for
    all, or P): phi_T (M, 3, 3) and gamma (M, 3) the exact one-step transition,
    k_b, headroom (R_a i_max), k_i, r_a (M,). Wheel failures per episode (F = 1 for
    all, or P): fail_j (F,) the failed wheel (-1: none), fail_k (F,) the step it
    fails at, fail_stuck (F,) its drive holds the voltage of the step before
    (else it is lost: open circuit, it coasts), e_hold (F,) that voltage
    (state, updated until the failure); coast (2,) the coasting wheel's speed
    decay and angle gain over one step. Returns (x_next, tau_c (P, 3),
    h_start (P, 3)); see ``wheels.WheelAssembly`` for the rules.
    """
    m = x.shape[0]
    x_next = np.empty_like(x)
    tau_c = np.empty((m, 3))
    h0 = np.empty((m, 3))
    wheel_step_into(x, v_cmd, k, allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, dt,
                    torque_mode, k_i, r_a, b_m, fail_j, fail_k, fail_stuck, e_hold, coast, x_next, tau_c, h0)
    return x_next, tau_c, h0


@njit(cache=True, inline="always")
def wheel_step_into(x, v_cmd, k, allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, dt,
                    torque_mode, k_i, r_a, b_m, fail_j, fail_k, fail_stuck, e_hold, coast, x_next, tau_c, h0):
    """:func:`wheel_step` into given arrays (``x_next`` must not be ``x``)."""
    for p in range(x.shape[0]):
        wheel_row(x, v_cmd, p, p, k, allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, dt,
                  torque_mode, k_i, r_a, b_m, fail_j, fail_k, fail_stuck, e_hold, coast, x_next, tau_c, h0)


@njit(cache=True, inline="always")
def wheel_row(x, v_cmd, p, e_idx, k, allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, dt,
              torque_mode, k_i, r_a, b_m, fail_j, fail_k, fail_stuck, e_hold, coast, x_next, tau_c, h0):
    """:func:`wheel_step_into` for row ``p`` of x, v_cmd, x_next, tau_c, h0 alone.

    ``e_idx`` is the episode's row in the per-episode constants and failures
    (the compiled driver's chunks hold rows ``p`` of episodes ``lo + p``).
    """
    nw = x.shape[1]
    pm = e_idx if phi_T.shape[0] > 1 else 0
    pf = e_idx if fail_j.shape[0] > 1 else 0
    kb, ki, head, ra = k_b[pm], k_i[pm], headroom[pm], r_a[pm]
    for i in range(3):
        tau_c[p, i] = 0.0
        h0[p, i] = 0.0
    for j in range(nw):
        speed = x[p, j, 2]
        e = -(allocation[j, 0] * v_cmd[p, 0] + allocation[j, 1] * v_cmd[p, 1] + allocation[j, 2] * v_cmd[p, 2])
        emf = kb * speed
        if torque_mode:
            # inverse motor model: wheel torque -> steady current -> voltage
            e = ra * (e + b_m * speed) / ki + emf
        e = min(max(e, emf - head), emf + head)
        if abs(speed) >= speed_max and (e - emf) * speed > 0.0:
            e = emf
        e = min(max(e, -v_max), v_max)
        lost = False
        if j == fail_j[pf]:
            if k < fail_k[pf]:
                e_hold[pf] = e
            elif fail_stuck[pf]:
                e = e_hold[pf]  # the drive is stuck at its last voltage
            else:
                lost = True
        if lost:  # open circuit: no current, the wheel coasts down on its viscous friction
            x_next[p, j, 0] = x[p, j, 0] + coast[1] * speed
            x_next[p, j, 1] = 0.0
            x_next[p, j, 2] = coast[0] * speed
        else:
            for r in range(3):
                x_next[p, j, r] = (x[p, j, 0] * phi_T[pm, 0, r] + x[p, j, 1] * phi_T[pm, 1, r]
                                   + x[p, j, 2] * phi_T[pm, 2, r] + e * gamma[pm, r])
        for i in range(3):
            h0[p, i] += axes[i, j] * (speed * j_m)
            tau_c[p, i] += axes[i, j] * (x_next[p, j, 2] * j_m)
    for i in range(3):
        tau_c[p, i] = -(tau_c[p, i] - h0[p, i]) / dt


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
def _infer1(xr, xc, v, r, p):
    # episode p's inference: rows of v[p, 0], columns of v[p, 1], output centres v[p, 2], rules r[p]
    i, ti = _segment(xr, v, p, 0)
    j, tj = _segment(xc, v, p, 1)
    return ((1.0 - ti) * ((1.0 - tj) * v[p, 2, r[p, i, j] - 1] + tj * v[p, 2, r[p, i, j + 1] - 1])
            + ti * ((1.0 - tj) * v[p, 2, r[p, i + 1, j] - 1] + tj * v[p, 2, r[p, i + 1, j + 1] - 1]))


@njit(cache=True)
def fuzzy_pid_step(q_BN, q_RN, e_prev, has_prev, kp, ki, kd, n, a, integral, filt, e_scale, de_scale, u_scale,
                   rules, v, dt, u_max, angle_mode):
    """Hybrid fuzzy PID (see ``controllers.FuzzyPID``) for every episode and axis, in one loop.

    Updates ``e_prev``, ``integral`` and ``filt`` in place; returns the mixed
    command (P, 3) before the final saturation. The sets are the evenly spaced
    ones (``v``, kept in the signature for the record: -1, -2/3, ..., 1), which
    lets the segment of an input be computed rather than searched.
    """
    out = np.empty((q_BN.shape[0], 3))
    fuzzy_pid_step_into(q_BN, q_RN, e_prev, has_prev, kp, ki, kd, n, a, integral, filt, e_scale, de_scale, u_scale,
                        rules, v, dt, u_max, angle_mode, out)
    return out


@njit(cache=True, inline="always")
def fuzzy_pid_step_into(q_BN, q_RN, e_prev, has_prev, kp, ki, kd, n, a, integral, filt, e_scale, de_scale,
                        u_scale, rules, v, dt, u_max, angle_mode, out):
    """:func:`fuzzy_pid_step` writing the mixed command into ``out`` (P, 3)."""
    for p in range(q_BN.shape[0]):
        fuzzy_pid_row(q_BN, q_RN, p, e_prev, has_prev, kp, ki, kd, n, a, integral, filt, e_scale, de_scale,
                      u_scale, rules, v, dt, u_max, angle_mode, out)


@njit(cache=True, inline="always")
def _mix(u_p, u_f, f):
    # paper 003's mixing block with the magnitude rule (controllers.FuzzyPID.mix), one element
    if abs(u_f) > abs(u_p) + 1e-12:
        return f * u_p + (1.0 - f) * u_f
    if abs(u_p) > abs(u_f) + 1e-12:
        return (1.0 - f) * u_p + f * u_f
    return u_p


@njit(cache=True, inline="always")
def fuzzy_pid_row(q_BN, q_RN, p, e_prev, has_prev, kp, ki, kd, n, a, integral, filt, e_scale, de_scale,
                  u_scale, rules, v, dt, u_max, angle_mode, out):
    """:func:`fuzzy_pid_step_into` for episode ``p`` alone (row ``p`` of every array)."""
    e3 = _error3(q_BN, q_RN, p, angle_mode)
    for i in range(3):
        e = e3[i]
        de = (e - e_prev[p, i]) / dt if has_prev else 0.0
        xe = e / e_scale[p, i]
        u_f = u_scale[p, i] * _infer_uniform(de / de_scale[p, i], xe, rules, p)
        # PID part, as pid_step
        deriv = n[p, i] * (e - filt[p, i])
        raw = kp[p, i] * e + ki[p, i] * integral[p, i] + kd[p, i] * deriv
        u_p = min(max(raw, -u_max), u_max)
        if not (u_p != raw and e * raw > 0.0):
            integral[p, i] += e * dt
        filt[p, i] = a[p, i] * filt[p, i] + (1.0 - a[p, i]) * e
        # mixing block, f(e) = e_n^2
        en = min(max(xe, -1.0), 1.0)
        out[p, i] = _mix(u_p, u_f, en * en)
        e_prev[p, i] = e


@njit(cache=True)
def ga_flc_step(q_BN, omega, q_RN, omega_RN_R, rules, vertices, scales, u_max):
    """GA-FLC law (see ``controllers.GAFLC``) for every episode and axis; returns (P, 3) saturated.

    ``vertices`` (P, 3, 7): angle, rate and output vertices; ``scales`` (P, 3):
    K_theta, K_q, K_e.
    """
    out = np.empty((q_BN.shape[0], 3))
    ga_flc_step_into(q_BN, omega, q_RN, omega_RN_R, rules, vertices, scales, u_max, out)
    return out


@njit(cache=True, inline="always")
def ga_flc_step_into(q_BN, omega, q_RN, omega_RN_R, rules, vertices, scales, u_max, out):
    """:func:`ga_flc_step` writing the saturated command into ``out`` (P, 3)."""
    for p in range(q_BN.shape[0]):
        ga_flc_row(q_BN, omega, q_RN, omega_RN_R, p, rules, vertices, scales, u_max, out)


@njit(cache=True, inline="always")
def _reference_rate_row(x, y, z, w, w_d, p):
    # Q^T w_d = R(conj(q_BR)) w_d for q_BR = (x, y, z, w): v + 2 w (r x v) + 2 r x (r x v) with r = -vec(q_BR)
    vx, vy, vz = w_d[p, 0], w_d[p, 1], w_d[p, 2]
    if vx == 0.0 and vy == 0.0 and vz == 0.0:
        return 0.0, 0.0, 0.0
    rx, ry, rz = -x, -y, -z
    cx, cy, cz = ry * vz - rz * vy, rz * vx - rx * vz, rx * vy - ry * vx
    ccx, ccy, ccz = ry * cz - rz * cy, rz * cx - rx * cz, rx * cy - ry * cx
    return vx + 2.0 * (w * cx + ccx), vy + 2.0 * (w * cy + ccy), vz + 2.0 * (w * cz + ccz)


@njit(cache=True, inline="always")
def ga_flc_row(q_BN, omega, q_RN, omega_RN_R, p, rules, vertices, scales, u_max, out):
    """:func:`ga_flc_step_into` for episode ``p`` alone (row ``p`` of every array)."""
    x, y, z, w = _error_quat(q_BN, q_RN, p)
    nu = _reference_rate_row(x, y, z, w, omega_RN_R, p)
    vec = (x, y, z)
    for i in range(3):
        # errors, reference minus measurement (paper 004 Fig. 2 feeds the FLC the error)
        theta = -2.0 * np.arcsin(min(max(vec[i], -1.0), 1.0))
        rate = nu[i] - omega[p, i]
        u = scales[p, 2] * _infer1(scales[p, 0] * theta, scales[p, 1] * rate, vertices, rules, p)
        out[p, i] = min(max(u, -u_max), u_max)


@njit(cache=True)
def geometric_step(q_BN, omega, q_RN, w_d, w_d_prev, has_prev, k, l, inertia, dt, u_max,  # noqa: E741
                   gg_rate, aero_coeff, cp_offset, use_gg, use_aero):
    """Geometric tracking law (see ``controllers.Geometric``) for every episode, saturated.

    Shapes: quaternions (P, 4); omega, w_d, w_d_prev, k, l (P, 3); inertia (P, 3, 3);
    cp_offset (3,). ``aero_coeff`` is 0.5 rho C_d A V^2. Returns (P, 3) N m.
    """
    out = np.empty((q_BN.shape[0], 3))
    for p in range(q_BN.shape[0]):
        geometric_row(q_BN, omega, q_RN, w_d, w_d_prev, has_prev, p, k, l, inertia, dt, u_max, gg_rate,
                      aero_coeff, cp_offset, use_gg, use_aero, out)
    return out


@njit(cache=True, inline="always")
def _jv(J, p, a, b, c):
    # J[p] @ (a, b, c) on scalars
    return (J[p, 0, 0] * a + J[p, 0, 1] * b + J[p, 0, 2] * c,
            J[p, 1, 0] * a + J[p, 1, 1] * b + J[p, 1, 2] * c,
            J[p, 2, 0] * a + J[p, 2, 1] * b + J[p, 2, 2] * c)


@njit(cache=True, inline="always")
def geometric_row(q_BN, omega, q_RN, w_d, w_d_prev, has_prev, p, k, l, inertia, dt, u_max,  # noqa: E741
                  gg_rate, aero_coeff, cp_offset, use_gg, use_aero, out):
    """:func:`geometric_step` for episode ``p`` alone, on scalars (no temporaries), into ``out[p]``."""
    x, y, z, w = _error_quat(q_BN, q_RN, p)  # q_BR: Q = R(q_BR) = R_d^T R
    q00, q01, q02 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    q10, q11, q12 = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    q20, q21, q22 = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
    a0, a1, a2 = w_d[p, 0], w_d[p, 1], w_d[p, 2]
    nu = (q00 * a0 + q10 * a1 + q20 * a2, q01 * a0 + q11 * a1 + q21 * a2, q02 * a0 + q12 * a1 + q22 * a2)
    if has_prev:
        d0, d1, d2 = (a0 - w_d_prev[p, 0]) / dt, (a1 - w_d_prev[p, 1]) / dt, (a2 - w_d_prev[p, 2]) / dt
        wdd = (q00 * d0 + q10 * d1 + q20 * d2, q01 * d0 + q11 * d1 + q21 * d2, q02 * d0 + q12 * d1 + q22 * d2)
    else:
        wdd = (0.0, 0.0, 0.0)
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
    if use_gg:
        n0, n1, n2 = -q20, -q21, -q22  # -l3 in B: column 3 of R_BL = Q^T
        jn = _jv(inertia, p, n0, n1, n2)
        c = 3.0 * gg_rate * gg_rate
        e0 += c * (n1 * jn[2] - n2 * jn[1])
        e1 += c * (n2 * jn[0] - n0 * jn[2])
        e2 += c * (n0 * jn[1] - n1 * jn[0])
    if use_aero:
        v0, v1, v2 = q00, q01, q02  # l1 in B
        e0 += aero_coeff * (v1 * cp_offset[2] - v2 * cp_offset[1])
        e1 += aero_coeff * (v2 * cp_offset[0] - v0 * cp_offset[2])
        e2 += aero_coeff * (v0 * cp_offset[1] - v1 * cp_offset[0])
    out[p, 0] = min(max(t0 - e0, -u_max), u_max)
    out[p, 1] = min(max(t1 - e1, -u_max), u_max)
    out[p, 2] = min(max(t2 - e2, -u_max), u_max)


# ---------------------------------------------------------------- bumpless transfer
# What ControllerBank does at a swap, per episode, as kernels: the nodes (P = 1), the stepwise driver and
# the compiled driver all call these, so a swap gives the same numbers in each.

@njit(cache=True, inline="always")
def error_and_rate_row(q_BN, omega, q_RN, w_d, p, angle_mode):
    """The PID family's error of episode ``p`` and its time derivative, two 3-tuples.

    ``e = -vec(q_BR)`` (or ``2 asin(e)`` per axis in angle mode) and, with
    ``ω_e = ω - Q^T ω_d``, ``de/dt = -½ (w ω_e + v × ω_e)`` for ``q_BR = (v, w)``
    (the angle's rate is ``2 ė / sqrt(1 - e²)``, floored at 1e-12 under the root).
    """
    x, y, z, s = _error_quat(q_BN, q_RN, p)
    nu = _reference_rate_row(x, y, z, s, w_d, p)
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
def pid_bumpless_row(e, de, p, kp, ki, kd, n, integral, filt, u_max, u_last):
    """Set PID state row ``p`` so its next command is ``clip(u_last)`` (a 3-tuple; see ``controllers.PID.bumpless``)."""
    for i in range(3):
        target = min(max(u_last[i], -u_max), u_max)
        filt[p, i] = e[i] - de[i] / n[p, i]
        rest = target - kp[p, i] * e[i] - kd[p, i] * de[i]
        integral[p, i] = rest / ki[p, i] if ki[p, i] > 0.0 else 0.0


@njit(cache=True, inline="always")
def _infer_vertices(xr, xc, v, rules, p):
    # fuzzy_infer's arithmetic for one element, with the vertices v[0, 0] (v (1, 1, 7)) for rows, columns and
    # output, and the rules of episode p
    i, ti = _segment(xr, v, 0, 0)
    j, tj = _segment(xc, v, 0, 0)
    c, r = v[0, 0], rules
    return ((1.0 - ti) * ((1.0 - tj) * c[r[p, i, j] - 1] + tj * c[r[p, i, j + 1] - 1])
            + ti * ((1.0 - tj) * c[r[p, i + 1, j] - 1] + tj * c[r[p, i + 1, j + 1] - 1]))


@njit(cache=True, inline="always")
def fuzzy_pid_bumpless_row(e, de, p, e_prev, kp, ki, kd, n, integral, filt, e_scale, de_scale, u_scale, rules, v,
                           dt, u_max, decay, u_last, offset):
    """Fuzzy PID bumpless entry for row ``p`` (see ``controllers.FuzzyPID.bumpless``).

    Sets ``e_prev`` from the measured error rate and the PID state so the mixed
    command equals ``clip(u_last[p])`` wherever some PID output achieves it;
    writes the remainder into ``offset[p]`` and returns True when a decaying
    offset is needed (``decay`` > 0 and some remainder above 1e-12). ``v``
    (1, 1, 7): the evenly spaced vertices (``fuzzy.UNIFORM_VERTICES``).
    """
    u_pid = np.empty(3)
    rest = np.empty(3)
    for i in range(3):
        e_prev[p, i] = e[i] - de[i] * dt  # de starts at the measured rate
    for i in range(3):
        d = (e[i] - e_prev[p, i]) / dt
        x_e = e[i] / e_scale[p, i]
        u_f = u_scale[p, i] * _infer_vertices(d / de_scale[p, i], x_e, v, rules, p)
        en = min(max(x_e, -1.0), 1.0)
        f = en * en
        target = min(max(u_last[p, i], -u_max), u_max)
        p2 = (target - f * u_f) / (1.0 - f) if f != 1.0 else np.inf  # case 2: PID faster
        p1 = (target - (1.0 - f) * u_f) / f if f != 0.0 else np.inf  # case 1: fuzzy faster
        if np.isfinite(p2) and abs(p2) > abs(u_f) + 1e-12:
            up = p2
        elif np.isfinite(p1) and abs(p1) < abs(u_f) - 1e-12:
            up = p1
        else:
            up = target
        u_pid[i] = up
        rest[i] = target - _mix(up, u_f, f)
    pid_bumpless_row(e, de, p, kp, ki, kd, n, integral, filt, u_max, (u_pid[0], u_pid[1], u_pid[2]))
    needed = decay > 0.0 and (abs(rest[0]) > 1e-12 or abs(rest[1]) > 1e-12 or abs(rest[2]) > 1e-12)
    for i in range(3):
        offset[p, i] = rest[i] if needed else 0.0
    return needed


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


@njit(cache=True)
def pid_bumpless(q_BN, omega, q_RN, w_d, angle_mode, kp, ki, kd, n, integral, filt, u_max, u_last):
    """:func:`pid_bumpless_row` for every episode (P rows of each array)."""
    for p in range(q_BN.shape[0]):
        e, de = error_and_rate_row(q_BN, omega, q_RN, w_d, p, angle_mode)
        pid_bumpless_row(e, de, p, kp, ki, kd, n, integral, filt, u_max, (u_last[p, 0], u_last[p, 1], u_last[p, 2]))


@njit(cache=True)
def fuzzy_pid_bumpless(q_BN, omega, q_RN, w_d, angle_mode, e_prev, kp, ki, kd, n, integral, filt, e_scale,
                       de_scale, u_scale, rules, v, dt, u_max, decay, u_last, offset, has_offset):
    """:func:`fuzzy_pid_bumpless_row` for every episode; ``has_offset`` (P,) says where an offset remains."""
    for p in range(q_BN.shape[0]):
        e, de = error_and_rate_row(q_BN, omega, q_RN, w_d, p, angle_mode)
        has_offset[p] = fuzzy_pid_bumpless_row(e, de, p, e_prev, kp, ki, kd, n, integral, filt, e_scale, de_scale,
                                               u_scale, rules, v, dt, u_max, decay, u_last, offset)


# ---------------------------------------------------------------- sensor noise
# A counter-based generator: draw (seed, k, i) is a pure function of its key (splitmix64, then Box-Muller),
# so an episode's noise does not depend on the batch, chunk, thread or process that runs it, and a node that
# knows only its step k draws what the batch engine drew.

@njit(cache=True, inline="always")
def _mix64(z):
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, inline="always")
def normal_draw(seed, k, i):
    """A standard normal number that depends only on (seed, step k, channel i): splitmix64 and Box-Muller."""
    h = _mix64(_mix64(np.uint64(seed)) ^ np.uint64(k * 8 + i))
    h2 = _mix64(h)
    u1 = (float(h >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
    u2 = float(h2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)


@njit(cache=True, inline="always")
def measure_row(q, w, p, e_idx, k, seeds, att_std, rate_std, qm, wm):
    """Row ``p`` of the measured attitude and rate at step ``k`` (episode row ``e_idx`` of the M = 1 or P
    noise settings).

    ``q_meas = q ⊗ [d / 2, 1] / |.|`` with d ~ N(0, att_std^2) per body axis (rad),
    ``w_meas = w + N(0, rate_std^2)`` (rad/s); seeds (M,) int64, att_std and rate_std (M,).
    """
    pe = e_idx if seeds.shape[0] > 1 else 0
    s, sa, sr = seeds[pe], att_std[pe], rate_std[pe]
    dx = 0.5 * sa * normal_draw(s, k, 0)
    dy = 0.5 * sa * normal_draw(s, k, 1)
    dz = 0.5 * sa * normal_draw(s, k, 2)
    n = np.sqrt(1.0 + dx * dx + dy * dy + dz * dz)
    dx, dy, dz, dw = dx / n, dy / n, dz / n, 1.0 / n
    qx, qy, qz, qw = q[p, 0], q[p, 1], q[p, 2], q[p, 3]
    qm[p, 0] = qw * dx + qx * dw + qy * dz - qz * dy
    qm[p, 1] = qw * dy - qx * dz + qy * dw + qz * dx
    qm[p, 2] = qw * dz + qx * dy - qy * dx + qz * dw
    qm[p, 3] = qw * dw - qx * dx - qy * dy - qz * dz
    for i in range(3):
        wm[p, i] = w[p, i] + sr * normal_draw(s, k, 3 + i)


@njit(cache=True)
def measure(q, w, k, seeds, att_std, rate_std):
    """:func:`measure_row` for every episode: (q_meas (P, 4), w_meas (P, 3))."""
    qm = np.empty_like(q)
    wm = np.empty_like(w)
    for p in range(q.shape[0]):
        measure_row(q, w, p, p, k, seeds, att_std, rate_std, qm, wm)
    return qm, wm


# ---------------------------------------------------------------- small matrix exponential
@njit(cache=True, inline="always")
def _matmul_small(a, b):
    n = a.shape[0]
    out = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            aik = a[i, k]
            for j in range(n):
                out[i, j] += aik * b[k, j]
    return out


@njit(cache=True)
def expm_small(a):
    """exp(a) of a small square matrix: scaling and squaring of an 18-term Taylor series.

    The 1-norm is scaled below 1/2, where the series' truncation error is below
    1e-21; plain loops, no BLAS, so it costs microseconds in any process (a
    per-episode motor transition of a Monte Carlo run calls it once).
    """
    n = a.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(a[i, j])
        norm = max(norm, col)
    s = 0
    while norm > 0.5:
        norm *= 0.5
        s += 1
    x = a * (0.5 ** s)
    out = np.eye(n)
    term = np.eye(n)
    for k in range(1, 19):
        term = _matmul_small(term, x) / k
        out = out + term
    for _ in range(s):
        out = _matmul_small(out, out)
    return out
