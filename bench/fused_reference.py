"""The ceiling: a hand-fused compiled loop of the HST roll step (benchmark reference, not product code).

The simplest code that computes the same episode as the batch engine on the
``hst_roll_step`` preset with the PID law: RK4 body with wheel-momentum
coupling, four pyramid wheels with drive limits and the exact motor update,
the filtered PID, and the trajectory kept (attitude, rate, command, wheel
torque per step). One function, no allocation inside the step loop, scalars
in registers. ``bench_engine.py`` checks that it gives the engine's numbers
(to 1e-12) before it times it, so the ratio compares equal work.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from attitude_sil.core.control.kernels import error3_row
from attitude_sil.core.sim.build import build_controller, build_guidance, build_plant, build_wheels


@njit(cache=True, inline="always")
def _deriv(q, w, h, inertia, inertia_inv, tc, te, dq, dw, dh):
    # the body's derivatives (paper 000 eq. 4, 10-11), written out on small arrays
    hx = inertia[0, 0] * w[0] + inertia[0, 1] * w[1] + inertia[0, 2] * w[2] + h[0]
    hy = inertia[1, 0] * w[0] + inertia[1, 1] * w[1] + inertia[1, 2] * w[2] + h[1]
    hz = inertia[2, 0] * w[0] + inertia[2, 1] * w[1] + inertia[2, 2] * w[2] + h[2]
    rx = -(w[1] * hz - w[2] * hy) + tc[0] + te[0]
    ry = -(w[2] * hx - w[0] * hz) + tc[1] + te[1]
    rz = -(w[0] * hy - w[1] * hx) + tc[2] + te[2]
    dw[0] = inertia_inv[0, 0] * rx + inertia_inv[0, 1] * ry + inertia_inv[0, 2] * rz
    dw[1] = inertia_inv[1, 0] * rx + inertia_inv[1, 1] * ry + inertia_inv[1, 2] * rz
    dw[2] = inertia_inv[2, 0] * rx + inertia_inv[2, 1] * ry + inertia_inv[2, 2] * rz
    x, y, z, s = q[0], q[1], q[2], q[3]
    dq[0] = 0.5 * (w[2] * y - w[1] * z + w[0] * s)
    dq[1] = 0.5 * (-w[2] * x + w[0] * z + w[1] * s)
    dq[2] = 0.5 * (w[1] * x - w[0] * y + w[2] * s)
    dq[3] = 0.5 * (-w[0] * x - w[1] * y - w[2] * z)
    dh[0] = -tc[0]
    dh[1] = -tc[1]
    dh[2] = -tc[2]


@njit(cache=True, inline="always")
def _stage(cq, cw, ch, kq, kw, kh, c, tq, tw, th):
    for i in range(4):
        tq[i] = cq[i] + c * kq[i]
    for i in range(3):
        tw[i] = cw[i] + c * kw[i]
        th[i] = ch[i] + c * kh[i]


@njit(cache=True)
def _episode(p, n_steps, dt, q0, q_r, inertia, inertia_inv, kp, ki, kd, nf, af, u_max,
             alloc, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max,
             o_q, o_w, o_u, o_tc, stride):
    nw = axes.shape[1]
    q = q0[p].copy()
    w = np.zeros(3)
    h = np.zeros(3)
    x = np.zeros((nw, 3))
    xn = np.zeros((nw, 3))
    integral = np.zeros(3)
    filt = np.zeros(3)
    u = np.zeros(3)
    tc = np.zeros(3)
    te = np.zeros(3)
    qr = q_r[p:p + 1]
    qq = np.zeros((1, 4))
    k1q, k2q, k3q, k4q = np.empty(4), np.empty(4), np.empty(4), np.empty(4)
    k1w, k2w, k3w, k4w = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    k1h, k2h, k3h, k4h = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    tq, tw, th = np.empty(4), np.empty(3), np.empty(3)
    half = 0.5 * dt
    sixth = dt / 6.0
    for k in range(n_steps + 1):
        # PID on the quaternion error vector
        qq[0, :] = q
        e = error3_row(qq, qr, 0, False)
        for i in range(3):
            deriv = (1.0 - af[p, i]) / dt * (e[i] - filt[i])
            raw = kp[p, i] * e[i] + ki[p, i] * (integral[i] + 0.5 * e[i] * dt) + kd[p, i] * deriv
            out = min(max(raw, -u_max), u_max)
            if not (out != raw and e[i] * raw > 0.0):
                integral[i] += e[i] * dt
            filt[i] = af[p, i] * filt[i] + (1.0 - af[p, i]) * e[i]
            u[i] = out
        # wheels: allocation, drive limits, exact motor step, mean torque on the body
        for i in range(3):
            h[i] = 0.0
            tc[i] = 0.0
        for j in range(nw):
            speed = x[j, 2]
            v = -(alloc[j, 0] * u[0] + alloc[j, 1] * u[1] + alloc[j, 2] * u[2])
            emf = k_b * speed
            v = min(max(v, emf - headroom), emf + headroom)
            if abs(speed) >= speed_max and (v - emf) * speed > 0.0:
                v = emf
            v = min(max(v, -v_max), v_max)
            for r in range(3):
                xn[j, r] = x[j, 0] * phi_T[0, r] + x[j, 1] * phi_T[1, r] + x[j, 2] * phi_T[2, r] + v * gamma[r]
            for i in range(3):
                h[i] += axes[i, j] * (speed * j_m)
                tc[i] += axes[i, j] * (xn[j, 2] * j_m)
        for i in range(3):
            tc[i] = -(tc[i] - h[i]) / dt
        if k % stride == 0:
            r = k // stride
            o_q[p, r] = q
            o_w[p, r] = w
            o_u[p, r] = u
            o_tc[p, r] = tc
        if k < n_steps:
            _deriv(q, w, h, inertia, inertia_inv, tc, te, k1q, k1w, k1h)
            _stage(q, w, h, k1q, k1w, k1h, half, tq, tw, th)
            _deriv(tq, tw, th, inertia, inertia_inv, tc, te, k2q, k2w, k2h)
            _stage(q, w, h, k2q, k2w, k2h, half, tq, tw, th)
            _deriv(tq, tw, th, inertia, inertia_inv, tc, te, k3q, k3w, k3h)
            _stage(q, w, h, k3q, k3w, k3h, dt, tq, tw, th)
            _deriv(tq, tw, th, inertia, inertia_inv, tc, te, k4q, k4w, k4h)
            for i in range(4):
                q[i] = q[i] + sixth * (k1q[i] + 2.0 * (k2q[i] + k3q[i]) + k4q[i])
            for i in range(3):
                w[i] = w[i] + sixth * (k1w[i] + 2.0 * (k2w[i] + k3w[i]) + k4w[i])
            norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            for i in range(4):
                q[i] = q[i] / norm
        for j in range(nw):
            for r in range(3):
                x[j, r] = xn[j, r]


@njit(cache=True)
def fused_serial(n_steps, dt, q0, q_r, inertia, inertia_inv, kp, ki, kd, nf, af, u_max,
                 alloc, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, o_q, o_w, o_u, o_tc, stride):
    for p in range(q0.shape[0]):
        _episode(p, n_steps, dt, q0, q_r, inertia, inertia_inv, kp, ki, kd, nf, af, u_max,
                 alloc, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, o_q, o_w, o_u, o_tc, stride)


@njit(cache=True, parallel=True)
def fused_parallel(n_steps, dt, q0, q_r, inertia, inertia_inv, kp, ki, kd, nf, af, u_max,
                   alloc, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, o_q, o_w, o_u, o_tc, stride):
    for p in prange(q0.shape[0]):
        _episode(p, n_steps, dt, q0, q_r, inertia, inertia_inv, kp, ki, kd, nf, af, u_max,
                 alloc, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, o_q, o_w, o_u, o_tc, stride)


def fused_setup(scn, n_episodes: int, kp=None, stride: int = 1):
    """The arrays the fused loop takes, for the scenario's HST set-up (built as the engine builds them)."""
    P = n_episodes
    plant = build_plant(scn, P)
    wheels = build_wheels(scn, P)
    guide = build_guidance(scn, P)
    ctrl = build_controller(scn, P, params=None if kp is None else {"pid.kp": kp})
    pid = ctrl.record("pid")
    gains = (pid.kp, pid.ki, pid.kd, pid.n, pid.a)
    asm, mot = wheels.assembly, wheels.assembly.motor
    K = scn.steps()
    kept = K // stride + 1
    out = [np.empty((P, kept, 4)), np.empty((P, kept, 3)), np.empty((P, kept, 3)), np.empty((P, kept, 3))]
    return (K, scn.dt, plant.q0, np.ascontiguousarray(guide.q_final), plant.inertia[0], plant.inertia_inv[0], *gains,
            pid.u_max, asm.allocation, asm.axes_B, asm.phi_T, asm.gamma, mot.rotor_inertia, mot.back_emf_constant,
            mot.resistance * mot.current_max, mot.speed_max, mot.v_max, *out, stride), out


def fused_hst(scn, n_episodes: int, kp=None, parallel: bool = False, stride: int = 1):
    """Run the fused loop on the scenario's HST set-up; returns (q_BN, omega_BN_B, u_cmd, tau_c_B)."""
    args, out = fused_setup(scn, n_episodes, kp, stride)
    (fused_parallel if parallel else fused_serial)(*args)
    return out
