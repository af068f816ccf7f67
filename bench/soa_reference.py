"""Issue 25's first measurement: the fused HST episode with the episodes as the vector axis (not product code).

``fused_reference.py`` runs one episode per loop iteration, its state in
registers: the compiler has nothing to put in a vector register but one
episode's three axes. Here the same arithmetic, in the same order, runs on a
block of ``LANES`` episodes held as separate 1-D arrays (structure of arrays),
each stage of the step its own short loop over the lanes: the PID, each wheel,
each RK4 stage's derivatives and sums, the renormalisation. Every lane
quantity is its own 1-D allocation, allocated in the block: the four
derivative evaluations share one inlined helper that takes its arrays in
tuples (measured as fast as the loops written out four times, bit for bit the
same); a helper that is not inlined leaves LLVM unable to prove that what a
loop writes does not alias what it reads, and the loop stays scalar
(bench/README.md has the measurements). Loops of that
shape are what this CPU's compiler turns into packed (4-wide) instructions;
a loop that calls a scalar step per lane is not (a probe of a toy step, made
outside this repository, measured 0.65-0.85x for that).

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

#: episodes per block: the block's ~80 lane arrays of 64 doubles stay in L1 (40 KiB)
LANES = 64



@njit(cache=True, inline="always")
def _deriv(n, q, w, h, c, jm, km, dq, dw):
    # the body's derivatives on the lanes: q, dq 4-tuples, w, h, c (tau_c), dw 3-tuples of lane arrays; jm, km
    # the inertia and its inverse, 9-tuples of scalars (row-major)
    q0, q1, q2, q3 = q
    w0, w1, w2 = w
    h0, h1, h2 = h
    c0, c1, c2 = c
    J00, J01, J02, J10, J11, J12, J20, J21, J22 = jm
    K00, K01, K02, K10, K11, K12, K20, K21, K22 = km
    a0, a1, a2, a3 = dq
    b0, b1, b2 = dw
    for p in range(n):
        hx = J00 * w0[p] + J01 * w1[p] + J02 * w2[p] + h0[p]
        hy = J10 * w0[p] + J11 * w1[p] + J12 * w2[p] + h1[p]
        hz = J20 * w0[p] + J21 * w1[p] + J22 * w2[p] + h2[p]
        rx = -(w1[p] * hz - w2[p] * hy) + c0[p] + 0.0
        ry = -(w2[p] * hx - w0[p] * hz) + c1[p] + 0.0
        rz = -(w0[p] * hy - w1[p] * hx) + c2[p] + 0.0
        b0[p] = K00 * rx + K01 * ry + K02 * rz
        b1[p] = K10 * rx + K11 * ry + K12 * rz
        b2[p] = K20 * rx + K21 * ry + K22 * rz
        x, y, z, s = q0[p], q1[p], q2[p], q3[p]
        a0[p] = 0.5 * (w2[p] * y - w1[p] * z + w0[p] * s)
        a1[p] = 0.5 * (-w2[p] * x + w0[p] * z + w1[p] * s)
        a2[p] = 0.5 * (w1[p] * x - w0[p] * y + w2[p] * s)
        a3[p] = 0.5 * (-w0[p] * x - w1[p] * y - w2[p] * z)


@njit(cache=True, error_model="numpy")
def _block(g0, n, n_steps, dt, q_init, q_r, J, Ji, kp, ki, kd, af, u_max, alloc, axes, phi_T, gamma, j_m, k_b,
           headroom, speed_max, v_max, out_q, out_w):
    nw = axes.shape[1]
    q0 = np.zeros(n)
    q1 = np.zeros(n)
    q2 = np.zeros(n)
    q3 = np.zeros(n)
    w0 = np.zeros(n)
    w1 = np.zeros(n)
    w2 = np.zeros(n)
    h0 = np.zeros(n)
    h1 = np.zeros(n)
    h2 = np.zeros(n)
    i0 = np.zeros(n)
    i1 = np.zeros(n)
    i2 = np.zeros(n)
    f0 = np.zeros(n)
    f1 = np.zeros(n)
    f2 = np.zeros(n)
    u0 = np.zeros(n)
    u1 = np.zeros(n)
    u2 = np.zeros(n)
    c0 = np.zeros(n)
    c1 = np.zeros(n)
    c2 = np.zeros(n)
    r0 = np.zeros(n)
    r1 = np.zeros(n)
    r2 = np.zeros(n)
    r3 = np.zeros(n)
    e0 = np.zeros(n)
    e1 = np.zeros(n)
    e2 = np.zeros(n)
    tq0 = np.zeros(n)
    tq1 = np.zeros(n)
    tq2 = np.zeros(n)
    tq3 = np.zeros(n)
    tw0 = np.zeros(n)
    tw1 = np.zeros(n)
    tw2 = np.zeros(n)
    th0 = np.zeros(n)
    th1 = np.zeros(n)
    th2 = np.zeros(n)
    aq0 = np.zeros(n)
    aq1 = np.zeros(n)
    aq2 = np.zeros(n)
    aq3 = np.zeros(n)
    aw0 = np.zeros(n)
    aw1 = np.zeros(n)
    aw2 = np.zeros(n)
    bq0 = np.zeros(n)
    bq1 = np.zeros(n)
    bq2 = np.zeros(n)
    bq3 = np.zeros(n)
    bw0 = np.zeros(n)
    bw1 = np.zeros(n)
    bw2 = np.zeros(n)
    cq0 = np.zeros(n)
    cq1 = np.zeros(n)
    cq2 = np.zeros(n)
    cq3 = np.zeros(n)
    cw0 = np.zeros(n)
    cw1 = np.zeros(n)
    cw2 = np.zeros(n)
    dq0 = np.zeros(n)
    dq1 = np.zeros(n)
    dq2 = np.zeros(n)
    dq3 = np.zeros(n)
    dw0 = np.zeros(n)
    dw1 = np.zeros(n)
    dw2 = np.zeros(n)
    gp0 = np.zeros(n)
    gi0 = np.zeros(n)
    gd0 = np.zeros(n)
    ga0 = np.zeros(n)
    gp1 = np.zeros(n)
    gi1 = np.zeros(n)
    gd1 = np.zeros(n)
    ga1 = np.zeros(n)
    gp2 = np.zeros(n)
    gi2 = np.zeros(n)
    gd2 = np.zeros(n)
    ga2 = np.zeros(n)
    J00, J01, J02 = J[0, 0], J[0, 1], J[0, 2]
    J10, J11, J12 = J[1, 0], J[1, 1], J[1, 2]
    J20, J21, J22 = J[2, 0], J[2, 1], J[2, 2]
    K00, K01, K02 = Ji[0, 0], Ji[0, 1], Ji[0, 2]  # J^-1
    K10, K11, K12 = Ji[1, 0], Ji[1, 1], Ji[1, 2]
    K20, K21, K22 = Ji[2, 0], Ji[2, 1], Ji[2, 2]
    Jm = (J00, J01, J02, J10, J11, J12, J20, J21, J22)
    Km = (K00, K01, K02, K10, K11, K12, K20, K21, K22)
    for p in range(n):
        q0[p], q1[p], q2[p], q3[p] = q_init[g0 + p, 0], q_init[g0 + p, 1], q_init[g0 + p, 2], q_init[g0 + p, 3]
        r0[p], r1[p], r2[p], r3[p] = q_r[g0 + p, 0], q_r[g0 + p, 1], q_r[g0 + p, 2], q_r[g0 + p, 3]
        gp0[p], gi0[p], gd0[p], ga0[p] = kp[g0 + p, 0], ki[g0 + p, 0], kd[g0 + p, 0], af[g0 + p, 0]
        gp1[p], gi1[p], gd1[p], ga1[p] = kp[g0 + p, 1], ki[g0 + p, 1], kd[g0 + p, 1], af[g0 + p, 1]
        gp2[p], gi2[p], gd2[p], ga2[p] = kp[g0 + p, 2], ki[g0 + p, 2], kd[g0 + p, 2], af[g0 + p, 2]
    xw = np.zeros((nw, 3, n))
    xwn = np.zeros((nw, 3, n))
    half = 0.5 * dt
    sixth = dt / 6.0
    for k in range(n_steps + 1):
        for p in range(n):
            bx, by, bz, bw = q0[p], q1[p], q2[p], q3[p]
            rx, ry, rz, rw = -r0[p], -r1[p], -r2[p], r3[p]
            ex = rw * bx + bw * rx + ry * bz - rz * by
            ey = rw * by + bw * ry + rz * bx - rx * bz
            ez = rw * bz + bw * rz + rx * by - ry * bx
            ew = rw * bw - rx * bx - ry * by - rz * bz
            sgn = -1.0 if ew < 0.0 else 1.0
            e0[p] = -(sgn * ex)
            e1[p] = -(sgn * ey)
            e2[p] = -(sgn * ez)
        for p in range(n):
            ei = e0[p]
            a = ga0[p]
            deriv = (1.0 - a) / dt * (ei - f0[p])
            raw = gp0[p] * ei + gi0[p] * (i0[p] + 0.5 * ei * dt) + gd0[p] * deriv
            out = min(max(raw, -u_max), u_max)
            hold = out != raw and ei * raw > 0.0
            i0[p] = i0[p] if hold else i0[p] + ei * dt
            f0[p] = a * f0[p] + (1.0 - a) * ei
            u0[p] = out
        for p in range(n):
            ei = e1[p]
            a = ga1[p]
            deriv = (1.0 - a) / dt * (ei - f1[p])
            raw = gp1[p] * ei + gi1[p] * (i1[p] + 0.5 * ei * dt) + gd1[p] * deriv
            out = min(max(raw, -u_max), u_max)
            hold = out != raw and ei * raw > 0.0
            i1[p] = i1[p] if hold else i1[p] + ei * dt
            f1[p] = a * f1[p] + (1.0 - a) * ei
            u1[p] = out
        for p in range(n):
            ei = e2[p]
            a = ga2[p]
            deriv = (1.0 - a) / dt * (ei - f2[p])
            raw = gp2[p] * ei + gi2[p] * (i2[p] + 0.5 * ei * dt) + gd2[p] * deriv
            out = min(max(raw, -u_max), u_max)
            hold = out != raw and ei * raw > 0.0
            i2[p] = i2[p] if hold else i2[p] + ei * dt
            f2[p] = a * f2[p] + (1.0 - a) * ei
            u2[p] = out

        for p in range(n):
            h0[p] = 0.0
            h1[p] = 0.0
            h2[p] = 0.0
            c0[p] = 0.0
            c1[p] = 0.0
            c2[p] = 0.0
        for j in range(nw):
            a0, a1, a2 = alloc[j, 0], alloc[j, 1], alloc[j, 2]
            x0, x1, x2 = axes[0, j], axes[1, j], axes[2, j]
            for p in range(n):
                speed = xw[j, 2, p]
                v = -(a0 * u0[p] + a1 * u1[p] + a2 * u2[p])
                emf = k_b * speed
                v = min(max(v, emf - headroom), emf + headroom)
                v = emf if (abs(speed) >= speed_max and (v - emf) * speed > 0.0) else v
                v = min(max(v, -v_max), v_max)
                xa = xw[j, 0, p]
                xb = xw[j, 1, p]
                xwn[j, 0, p] = xa * phi_T[0, 0] + xb * phi_T[1, 0] + speed * phi_T[2, 0] + v * gamma[0]
                xwn[j, 1, p] = xa * phi_T[0, 1] + xb * phi_T[1, 1] + speed * phi_T[2, 1] + v * gamma[1]
                sn = xa * phi_T[0, 2] + xb * phi_T[1, 2] + speed * phi_T[2, 2] + v * gamma[2]
                xwn[j, 2, p] = sn
                h0[p] += x0 * (speed * j_m)
                c0[p] += x0 * (sn * j_m)
                h1[p] += x1 * (speed * j_m)
                c1[p] += x1 * (sn * j_m)
                h2[p] += x2 * (speed * j_m)
                c2[p] += x2 * (sn * j_m)
        for p in range(n):
            c0[p] = -(c0[p] - h0[p]) / dt
            c1[p] = -(c1[p] - h1[p]) / dt
            c2[p] = -(c2[p] - h2[p]) / dt
        if k < n_steps:
            _deriv(n, (q0, q1, q2, q3), (w0, w1, w2), (h0, h1, h2), (c0, c1, c2), Jm, Km,
                   (aq0, aq1, aq2, aq3), (aw0, aw1, aw2))
            for p in range(n):
                tq0[p] = q0[p] + half * aq0[p]
                tq1[p] = q1[p] + half * aq1[p]
                tq2[p] = q2[p] + half * aq2[p]
                tq3[p] = q3[p] + half * aq3[p]
                tw0[p] = w0[p] + half * aw0[p]
                tw1[p] = w1[p] + half * aw1[p]
                tw2[p] = w2[p] + half * aw2[p]
                th0[p] = h0[p] + half * -c0[p]
                th1[p] = h1[p] + half * -c1[p]
                th2[p] = h2[p] + half * -c2[p]
            _deriv(n, (tq0, tq1, tq2, tq3), (tw0, tw1, tw2), (th0, th1, th2), (c0, c1, c2), Jm, Km,
                   (bq0, bq1, bq2, bq3), (bw0, bw1, bw2))
            for p in range(n):
                tq0[p] = q0[p] + half * bq0[p]
                tq1[p] = q1[p] + half * bq1[p]
                tq2[p] = q2[p] + half * bq2[p]
                tq3[p] = q3[p] + half * bq3[p]
                tw0[p] = w0[p] + half * bw0[p]
                tw1[p] = w1[p] + half * bw1[p]
                tw2[p] = w2[p] + half * bw2[p]
                th0[p] = h0[p] + half * -c0[p]
                th1[p] = h1[p] + half * -c1[p]
                th2[p] = h2[p] + half * -c2[p]
            _deriv(n, (tq0, tq1, tq2, tq3), (tw0, tw1, tw2), (th0, th1, th2), (c0, c1, c2), Jm, Km,
                   (cq0, cq1, cq2, cq3), (cw0, cw1, cw2))
            for p in range(n):
                tq0[p] = q0[p] + dt * cq0[p]
                tq1[p] = q1[p] + dt * cq1[p]
                tq2[p] = q2[p] + dt * cq2[p]
                tq3[p] = q3[p] + dt * cq3[p]
                tw0[p] = w0[p] + dt * cw0[p]
                tw1[p] = w1[p] + dt * cw1[p]
                tw2[p] = w2[p] + dt * cw2[p]
                th0[p] = h0[p] + dt * -c0[p]
                th1[p] = h1[p] + dt * -c1[p]
                th2[p] = h2[p] + dt * -c2[p]
            _deriv(n, (tq0, tq1, tq2, tq3), (tw0, tw1, tw2), (th0, th1, th2), (c0, c1, c2), Jm, Km,
                   (dq0, dq1, dq2, dq3), (dw0, dw1, dw2))
            for p in range(n):
                q0[p] = q0[p] + sixth * (aq0[p] + 2.0 * (bq0[p] + cq0[p]) + dq0[p])
            for p in range(n):
                q1[p] = q1[p] + sixth * (aq1[p] + 2.0 * (bq1[p] + cq1[p]) + dq1[p])
            for p in range(n):
                q2[p] = q2[p] + sixth * (aq2[p] + 2.0 * (bq2[p] + cq2[p]) + dq2[p])
            for p in range(n):
                q3[p] = q3[p] + sixth * (aq3[p] + 2.0 * (bq3[p] + cq3[p]) + dq3[p])
            for p in range(n):
                w0[p] = w0[p] + sixth * (aw0[p] + 2.0 * (bw0[p] + cw0[p]) + dw0[p])
            for p in range(n):
                w1[p] = w1[p] + sixth * (aw1[p] + 2.0 * (bw1[p] + cw1[p]) + dw1[p])
            for p in range(n):
                w2[p] = w2[p] + sixth * (aw2[p] + 2.0 * (bw2[p] + cw2[p]) + dw2[p])

            for p in range(n):
                norm = np.sqrt(q0[p] * q0[p] + q1[p] * q1[p] + q2[p] * q2[p] + q3[p] * q3[p])
                q0[p] = q0[p] / norm
                q1[p] = q1[p] / norm
                q2[p] = q2[p] / norm
                q3[p] = q3[p] / norm
        xw, xwn = xwn, xw
    for p in range(n):
        out_q[g0 + p, 0], out_q[g0 + p, 1], out_q[g0 + p, 2], out_q[g0 + p, 3] = q0[p], q1[p], q2[p], q3[p]
        out_w[g0 + p, 0], out_w[g0 + p, 1], out_w[g0 + p, 2] = w0[p], w1[p], w2[p]


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
