"""Issue 25's first measurement: the fused HST episode with the episodes as the vector axis (not product code).

``fused_reference.py`` runs one episode per loop iteration, its state in
registers: the compiler has nothing to put in a vector register but one
episode's three axes. Here the same arithmetic, in the same order, runs on a
block of ``LANES`` episodes held as separate 1-D arrays (structure of arrays),
each stage of the step its own short loop over the lanes: the PID, each wheel,
each RK4 stage's derivatives and sums, the renormalisation. Loops of that
shape are what this CPU's compiler turns into packed (4-wide) instructions;
a loop that calls a scalar step per lane is not (the probe of
``../shared/probes`` measured 0.65-0.85x for that).

``bench_engine.py simd`` checks the lanes against the fused loop (final
attitude and rate of every episode) before it times both, so the ratio
compares equal work. What it answers: how much faster the engine's own step
gets in this shape, on the real HST models (pyramid wheels with drive limits
and the exact motor update, RK4 body, the PID as the package runs it), before
the engine is rebuilt around it.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: episodes per block: the block's ~60 lane arrays of 64 doubles stay in L1 (30 KiB)
LANES = 64


@njit(cache=True, error_model="numpy", inline="always")
def _deriv_lanes(n, q0, q1, q2, q3, w0, w1, w2, h0, h1, h2, J, Ji, tc0, tc1, tc2, dq, dw):
    # the body's derivatives (paper 000 eq. 4, 10-11) for n lanes, fused_reference._deriv's arithmetic
    for p in range(n):
        hx = J[0, 0] * w0[p] + J[0, 1] * w1[p] + J[0, 2] * w2[p] + h0[p]
        hy = J[1, 0] * w0[p] + J[1, 1] * w1[p] + J[1, 2] * w2[p] + h1[p]
        hz = J[2, 0] * w0[p] + J[2, 1] * w1[p] + J[2, 2] * w2[p] + h2[p]
        rx = -(w1[p] * hz - w2[p] * hy) + tc0[p] + 0.0
        ry = -(w2[p] * hx - w0[p] * hz) + tc1[p] + 0.0
        rz = -(w0[p] * hy - w1[p] * hx) + tc2[p] + 0.0
        dw[0, p] = Ji[0, 0] * rx + Ji[0, 1] * ry + Ji[0, 2] * rz
        dw[1, p] = Ji[1, 0] * rx + Ji[1, 1] * ry + Ji[1, 2] * rz
        dw[2, p] = Ji[2, 0] * rx + Ji[2, 1] * ry + Ji[2, 2] * rz
        x, y, z, s = q0[p], q1[p], q2[p], q3[p]
        dq[0, p] = 0.5 * (w2[p] * y - w1[p] * z + w0[p] * s)
        dq[1, p] = 0.5 * (-w2[p] * x + w0[p] * z + w1[p] * s)
        dq[2, p] = 0.5 * (w1[p] * x - w0[p] * y + w2[p] * s)
        dq[3, p] = 0.5 * (-w0[p] * x - w1[p] * y - w2[p] * z)


@njit(cache=True, error_model="numpy")
def _block(g0, n, n_steps, dt, q_init, q_r, J, Ji, kp, ki, kd, af, u_max, alloc, axes, phi_T, gamma, j_m, k_b,
           headroom, speed_max, v_max, out_q, out_w):
    nw = axes.shape[1]
    q = np.empty((4, n))
    for i in range(4):
        for p in range(n):
            q[i, p] = q_init[g0 + p, i]
    w = np.zeros((3, n))
    h = np.zeros((3, n))
    x = np.zeros((nw, 3, n))
    xn = np.zeros((nw, 3, n))
    integ = np.zeros((3, n))
    filt = np.zeros((3, n))
    u = np.zeros((3, n))
    tc = np.zeros((3, n))
    e = np.empty((3, n))
    gk = np.empty((4, 3, n))  # per-lane gains: kp, ki, kd, a
    for i in range(3):
        for p in range(n):
            gk[0, i, p] = kp[g0 + p, i]
            gk[1, i, p] = ki[g0 + p, i]
            gk[2, i, p] = kd[g0 + p, i]
            gk[3, i, p] = af[g0 + p, i]
    r = np.empty((4, n))
    for i in range(4):
        for p in range(n):
            r[i, p] = q_r[g0 + p, i]
    kq = np.empty((4, 4, n))
    kw = np.empty((4, 3, n))
    tq = np.empty((4, n))
    tw = np.empty((3, n))
    th = np.empty((3, n))
    half = 0.5 * dt
    sixth = dt / 6.0
    for k in range(n_steps + 1):
        # the quaternion error, short way round (error3_row), then the PID per axis
        for p in range(n):
            bx, by, bz, bw = q[0, p], q[1, p], q[2, p], q[3, p]
            rx, ry, rz, rw = -r[0, p], -r[1, p], -r[2, p], r[3, p]
            ex = rw * bx + bw * rx + ry * bz - rz * by
            ey = rw * by + bw * ry + rz * bx - rx * bz
            ez = rw * bz + bw * rz + rx * by - ry * bx
            ew = rw * bw - rx * bx - ry * by - rz * bz
            sgn = -1.0 if ew < 0.0 else 1.0
            e[0, p] = -(sgn * ex)
            e[1, p] = -(sgn * ey)
            e[2, p] = -(sgn * ez)
        for i in range(3):
            for p in range(n):
                ei = e[i, p]
                a = gk[3, i, p]
                deriv = (1.0 - a) / dt * (ei - filt[i, p])
                raw = gk[0, i, p] * ei + gk[1, i, p] * (integ[i, p] + 0.5 * ei * dt) + gk[2, i, p] * deriv
                out = min(max(raw, -u_max), u_max)
                hold = out != raw and ei * raw > 0.0
                integ[i, p] = integ[i, p] if hold else integ[i, p] + ei * dt
                filt[i, p] = a * filt[i, p] + (1.0 - a) * ei
                u[i, p] = out
        # wheels: allocation, drive limits, exact motor step, mean torque on the body
        for i in range(3):
            for p in range(n):
                h[i, p] = 0.0
                tc[i, p] = 0.0
        for j in range(nw):
            for p in range(n):
                speed = x[j, 2, p]
                v = -(alloc[j, 0] * u[0, p] + alloc[j, 1] * u[1, p] + alloc[j, 2] * u[2, p])
                emf = k_b * speed
                v = min(max(v, emf - headroom), emf + headroom)
                v = emf if (abs(speed) >= speed_max and (v - emf) * speed > 0.0) else v
                v = min(max(v, -v_max), v_max)
                for c in range(3):
                    xn[j, c, p] = (x[j, 0, p] * phi_T[0, c] + x[j, 1, p] * phi_T[1, c] + x[j, 2, p] * phi_T[2, c]
                                   + v * gamma[c])
                for i in range(3):
                    h[i, p] += axes[i, j] * (speed * j_m)
                    tc[i, p] += axes[i, j] * (xn[j, 2, p] * j_m)
        for i in range(3):
            for p in range(n):
                tc[i, p] = -(tc[i, p] - h[i, p]) / dt
        if k < n_steps:
            for s, c in enumerate((0.0, half, half, dt)):
                if s == 0:
                    _deriv_lanes(n, q[0], q[1], q[2], q[3], w[0], w[1], w[2], h[0], h[1], h[2], J, Ji,
                                 tc[0], tc[1], tc[2], kq[0], kw[0])
                else:
                    for i in range(4):
                        for p in range(n):
                            tq[i, p] = q[i, p] + c * kq[s - 1, i, p]
                    for i in range(3):
                        for p in range(n):
                            tw[i, p] = w[i, p] + c * kw[s - 1, i, p]
                            th[i, p] = h[i, p] + c * -tc[i, p]
                    _deriv_lanes(n, tq[0], tq[1], tq[2], tq[3], tw[0], tw[1], tw[2], th[0], th[1], th[2], J, Ji,
                                 tc[0], tc[1], tc[2], kq[s], kw[s])
            for i in range(4):
                for p in range(n):
                    q[i, p] = q[i, p] + sixth * (kq[0, i, p] + 2.0 * (kq[1, i, p] + kq[2, i, p]) + kq[3, i, p])
            for i in range(3):
                for p in range(n):
                    w[i, p] = w[i, p] + sixth * (kw[0, i, p] + 2.0 * (kw[1, i, p] + kw[2, i, p]) + kw[3, i, p])
            for p in range(n):
                norm = np.sqrt(q[0, p] * q[0, p] + q[1, p] * q[1, p] + q[2, p] * q[2, p] + q[3, p] * q[3, p])
                q[0, p] = q[0, p] / norm
                q[1, p] = q[1, p] / norm
                q[2, p] = q[2, p] / norm
                q[3, p] = q[3, p] / norm
        for j in range(nw):
            for c in range(3):
                for p in range(n):
                    x[j, c, p] = xn[j, c, p]
    for p in range(n):
        for i in range(4):
            out_q[g0 + p, i] = q[i, p]
        for i in range(3):
            out_w[g0 + p, i] = w[i, p]


@njit(cache=True, parallel=True)
def lanes_run(n_steps, dt, q_init, q_r, J, Ji, kp, ki, kd, af, u_max, alloc, axes, phi_T, gamma, j_m, k_b,
              headroom, speed_max, v_max, out_q, out_w):
    """Every episode, LANES at a time (blocks across threads); final attitude and rate into out_q, out_w."""
    P = q_init.shape[0]
    n_blocks = (P + LANES - 1) // LANES
    for b in prange(n_blocks):
        g0 = b * LANES
        _block(g0, min(LANES, P - g0), n_steps, dt, q_init, q_r, J, Ji, kp, ki, kd, af, u_max, alloc, axes,
               phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, out_q, out_w)


def lanes_args(fused_args: tuple) -> tuple:
    """``lanes_run``'s arguments from ``fused_reference.fused_setup``'s, with fresh final-state outputs."""
    (K, dt, q0, q_r, J, Ji, kp, ki, kd, _nf, af, u_max, alloc, axes, phi_T, gamma, j_m, k_b, headroom,
     speed_max, v_max, *_rest) = fused_args
    P = q0.shape[0]
    return (K, dt, q0, q_r, J, Ji, kp, ki, kd, af, u_max, alloc, axes, phi_T, gamma, j_m, k_b, headroom,
            speed_max, v_max, np.empty((P, 4)), np.empty((P, 3)))
