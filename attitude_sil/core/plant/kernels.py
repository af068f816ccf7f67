"""Compiled inner loops of the lockstep step (numba), one loop over episodes each.

Profiling the batch engine at P = 50 showed ~300 small numpy calls per step,
each ~1 us: call overhead, not arithmetic, set the speed. These kernels do the
same arithmetic as the documented equations in one compiled loop. The nodes
call the same kernels with P = 1, so graph and batch stay bit-identical.
``cache=True`` keeps the compiled code next to the module after the first run.

* :func:`rk4_body` — RK4 of paper 000 eq. 3, 4, 10-11 (see ``rigid_body``);
* :func:`wheel_step` — the reaction-wheel motors over one control period;
* :func:`measure` — the law's view of the state with sensor noise;
* :func:`expm_small` — the motors' transition matrix.

The control laws' own steps live with each law
(:mod:`attitude_sil.core.control.laws`), their shared helpers in
:mod:`attitude_sil.core.control.kernels`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["rk4_body", "wheel_step", "WheelParams", "WheelFailure", "measure", "expm_small"]


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
def rk4_body_row(q, w, h, inertia, inertia_inv, tau_c, tau_e, p, dt, substeps):
    """RK4 over one held interval for episode ``p``, in place, on scalars: no temporaries, no array views.

    Reads row ``p`` of q (P, 4), w, h, tau_c, tau_e (P, 3), inertia and
    inertia_inv (P, 3, 3); writes the state at the interval's end into row
    ``p`` of ``q``, ``w`` and ``h``. The quaternion is renormalised at the end.
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
        q[p, i] = cq[i] / norm
    for i in range(3):
        w[p, i] = cw[i]
        h[p, i] = ch[i]


@njit(cache=True)
def rk4_body(q, w, h, inertia, inertia_inv, tau_c, tau_e, dt, substeps):
    """RK4 over one held interval for every episode; returns new (q, w, h) arrays.

    Shapes: q (P, 4), w and h (P, 3), inertia and inertia_inv (P, 3, 3),
    tau_c and tau_e (P, 3). The quaternion is renormalised at the end.
    """
    qo, wo, ho = q.copy(), w.copy(), h.copy()
    rk4_body_into(qo, wo, ho, inertia, inertia_inv, tau_c, tau_e, dt, substeps)
    return qo, wo, ho


@njit(cache=True, inline="always")
def rk4_body_into(q, w, h, inertia, inertia_inv, tau_c, tau_e, dt, substeps):
    """:func:`rk4_body` in place: ``q``, ``w``, ``h`` become the state at the interval's end."""
    for p in range(q.shape[0]):
        rk4_body_row(q, w, h, inertia, inertia_inv, tau_c, tau_e, p, dt, substeps)


class WheelParams(NamedTuple):
    """The wheel step's constants: the assembly's, and each episode's motor (M = 1 for all, or P rows).

    ``x_next = x @ phi_T + e gamma`` is the motors' exact step over ``dt``
    (:mod:`attitude_sil.core.plant.wheels`); ``coast`` is a lost wheel's speed
    decay and angle gain over one step.
    """

    allocation: np.ndarray  # (n, 3) pseudo-inverse of the axes, eq. 14
    axes: np.ndarray  # (3, n) spin axes in B
    phi_T: np.ndarray  # (M, 3, 3)
    gamma: np.ndarray  # (M, 3)
    k_b: np.ndarray  # (M,) back-EMF constant, V s/rad
    headroom: np.ndarray  # (M,) R_a i_max, V
    k_i: np.ndarray  # (M,) torque constant, N m/A
    r_a: np.ndarray  # (M,) armature resistance, ohm
    coast: np.ndarray  # (2,)
    j_m: float  # rotor inertia, kg m^2
    b_m: float  # viscous friction, N m s/rad
    speed_max: float  # rad/s
    v_max: float  # bus voltage, V
    dt: float  # the held interval, s


class WheelFailure(NamedTuple):
    """Wheel failures per episode (F = 1 for all, or P rows): which wheel (-1: none), from which step, how.

    A stuck drive holds the voltage of the step before the failure, which
    ``e_hold`` keeps (state, updated until the failure); a lost wheel (open
    circuit) coasts.
    """

    wheel: np.ndarray  # (F,) int64
    step: np.ndarray  # (F,) int64
    stuck: np.ndarray  # (F,) bool
    e_hold: np.ndarray  # (F,) V


@njit(cache=True)
def wheel_params_copy(wp):
    """A private copy of every array of a :class:`WheelParams` (threads sharing one would fight over its
    reference count)."""
    return WheelParams(wp.allocation.copy(), wp.axes.copy(), wp.phi_T.copy(), wp.gamma.copy(), wp.k_b.copy(),
                       wp.headroom.copy(), wp.k_i.copy(), wp.r_a.copy(), wp.coast.copy(), wp.j_m, wp.b_m,
                       wp.speed_max, wp.v_max, wp.dt)


@njit(cache=True)
def wheel_step(x, v_cmd, k, torque_mode, wp, fail):
    """Drive limits, exact motor step and mean body torque for every episode at step ``k``.

    Shapes: x (P, n, 3) wheel state (angle, current, speed) at t_k, v_cmd (P, 3)
    body-axis voltage (or, with ``torque_mode``, body torque in N m); ``wp`` a
    :class:`WheelParams`, ``fail`` a :class:`WheelFailure`. Returns (x_next,
    tau_c (P, 3), h_start (P, 3)); see ``wheels.WheelAssembly`` for the rules.
    """
    m = x.shape[0]
    x_next = np.empty_like(x)
    tau_c = np.empty((m, 3))
    h0 = np.empty((m, 3))
    wheel_rows(x, v_cmd, 0, k, np.full(m, torque_mode), wp, fail, x_next, tau_c, h0)
    return x_next, tau_c, h0


@njit(cache=True, inline="always")
def wheel_rows(x, v_cmd, lo, k, torque_mode, wp, fail, x_next, tau_c, h0):
    """:func:`wheel_step` into given arrays (``x_next`` must not be ``x``), row ``p`` in torque mode where
    ``torque_mode[p]``.

    Row ``p`` of x, v_cmd, x_next, tau_c, h0 is episode ``lo + p`` of the
    per-episode constants and failures (the compiled driver's chunks hold
    rows ``p`` of episodes ``lo + p``). The records' arrays are taken out once
    per call: taken per row, each take costs a reference count.
    """
    allocation, axes, phi_T, gamma, k_b, headroom, k_i, r_a, coast, j_m, b_m, speed_max, v_max, dt = wp
    fail_j, fail_k, fail_stuck, e_hold = fail
    nw = x.shape[1]
    for p in range(x.shape[0]):
        pm = lo + p if phi_T.shape[0] > 1 else 0
        pf = lo + p if fail_j.shape[0] > 1 else 0
        kb, ki, head, ra = k_b[pm], k_i[pm], headroom[pm], r_a[pm]
        for i in range(3):
            tau_c[p, i] = 0.0
            h0[p, i] = 0.0
        for j in range(nw):
            speed = x[p, j, 2]
            e = -(allocation[j, 0] * v_cmd[p, 0] + allocation[j, 1] * v_cmd[p, 1] + allocation[j, 2] * v_cmd[p, 2])
            emf = kb * speed
            if torque_mode[p]:
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
