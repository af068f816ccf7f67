"""Whole episodes in compiled code: the batch engine's second driver of the step kernels.

The nodes call the compiled step kernels of :mod:`attitude_sil.core.kernels`
once per message, through the objects of :mod:`attitude_sil.core.engine`; the
stepwise :func:`~attitude_sil.core.engine.simulate` loop calls the same objects
once per step from Python. This module is the third caller: one compiled loop
over every step of a chunk of episodes, calling the *same* kernels with the
*same* arrays, so its numbers are the stepwise driver's to the last bit (and
the graph's, which the graph == batch tests check at 1e-9). Chunks of episodes
run on every core (``numba.prange``); an episode's arithmetic does not depend
on which chunk or thread ran it, so the result is identical for any number of
threads.

What the compiled driver covers (the tuning and Monte Carlo workhorse: the HST
and CubeSat presets and their kind): the ``rigid_body`` plant, the
``reaction_wheels`` actuator, ``step`` guidance, the ``constant`` and ``step``
disturbance models (or none), and the ``pid``, ``fuzzy_pid`` and ``ga_flc``
laws without a swap. :func:`attitude_sil.core.engine.compiled_plan` says
whether a run fits and, if not, why; everything else runs in the stepwise
driver, which handles every model.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from .fuzzy import UNIFORM_VERTICES
from .kernels import fuzzy_pid_step_into, ga_flc_step_into, pid_step_into, rk4_body_scratch, wheel_step_into
from .trajectory import Trajectory

__all__ = ["COMPILED_LAWS", "COMPILED_DISTURBANCES", "run_compiled"]

#: laws the compiled driver runs (the geometric law and swaps take the stepwise driver)
COMPILED_LAWS = {"pid": 0, "fuzzy_pid": 1, "ga_flc": 2}

#: disturbance models the compiled driver evaluates in the loop
COMPILED_DISTURBANCES = frozenset({"constant", "step"})


@njit(cache=True)
def _chunk(law, lo, hi, n_steps, stride, dt, dt_ns, substeps, step_time,
           q0, w0, x0, q_initial, q_final, inertia, inertia_inv,
           kp, ki, kd, nf, af, u_max, angle_mode,
           e_scale, de_scale, u_scale, fz_rules, v_uniform,
           g_rules, g_vertices, g_scales,
           allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, torque_mode, k_i, r_a, b_m,
           tau_constant, tau_step, step_ns,
           o_q, o_w, o_qr, o_h, o_u, o_tc, o_te, o_ws, o_wa, o_we):
    """Episodes ``lo..hi-1`` from step 0 to K, the stepwise driver's order of calls, kept every ``stride``."""
    q = q0[lo:hi].copy()
    w = w0[lo:hi].copy()
    x = x0[lo:hi].copy()
    m = hi - lo
    qi = q_initial[lo:hi].copy()
    qf = q_final[lo:hi].copy()
    ii = inertia[lo:hi].copy()
    iv = inertia_inv[lo:hi].copy()
    kp_, ki_, kd_, n_, a_ = kp[lo:hi].copy(), ki[lo:hi].copy(), kd[lo:hi].copy(), nf[lo:hi].copy(), af[lo:hi].copy()
    integral = np.zeros((m, 3))
    filt = np.zeros((m, 3))
    e_prev = np.zeros((m, 3))
    es, ds, us, fr = e_scale[lo:hi].copy(), de_scale[lo:hi].copy(), u_scale[lo:hi].copy(), fz_rules[lo:hi].copy()
    gr, gv, gs = g_rules[lo:hi].copy(), g_vertices[lo:hi].copy(), g_scales[lo:hi].copy()
    # private copies of the shared read-only arrays: kernel calls touch their reference counts,
    # which threads sharing one array would fight over (measured: no speed-up on two cores without)
    allocation, axes, phi_T, gamma = allocation.copy(), axes.copy(), phi_T.copy(), gamma.copy()
    tau_constant, tau_step, v_uniform = tau_constant.copy(), tau_step.copy(), v_uniform.copy()
    omega_r = np.zeros((m, 3))
    tau_e = np.zeros((m, 3))
    u = np.empty((m, 3))
    tau_c = np.empty((m, 3))
    h0 = np.empty((m, 3))
    x_next = np.empty_like(x)
    h_out = np.empty((m, 3))
    scratch = np.empty((18, 4))
    nw = x.shape[1]
    for k in range(n_steps + 1):
        t_ns = k * dt_ns
        t = t_ns * 1e-9
        q_r = qf if t >= step_time - 1e-12 else qi
        for p in range(m):
            for i in range(3):
                tau_e[p, i] = 0.0 + tau_constant[i]
                if t_ns >= step_ns:
                    tau_e[p, i] += tau_step[i]
        if law == 0:
            pid_step_into(q, q_r, kp_, ki_, kd_, n_, a_, integral, filt, dt, u_max, angle_mode, u)
        elif law == 1:
            fuzzy_pid_step_into(q, q_r, e_prev, k > 0, kp_, ki_, kd_, n_, a_, integral, filt, es, ds, us, fr,
                                v_uniform, dt, u_max, angle_mode, u)
            for p in range(m):
                for i in range(3):
                    u[p, i] = min(max(u[p, i], -u_max), u_max)
        else:
            ga_flc_step_into(q, w, q_r, omega_r, gr, gv, gs, u_max, u)
        wheel_step_into(x, u, allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, dt,
                        torque_mode, k_i, r_a, b_m, x_next, tau_c, h0)
        if k % stride == 0:
            r = k // stride
            for p in range(m):
                e = lo + p
                for i in range(4):
                    o_q[r, e, i] = q[p, i]
                    o_qr[r, e, i] = q_r[p, i]
                for i in range(3):
                    o_w[r, e, i] = w[p, i]
                    o_h[r, e, i] = h0[p, i]
                    o_u[r, e, i] = u[p, i]
                    o_tc[r, e, i] = tau_c[p, i]
                    o_te[r, e, i] = tau_e[p, i]
                for j in range(nw):
                    o_wa[r, e, j] = x[p, j, 0]
                    o_ws[r, e, j] = x[p, j, 2]
                    o_we[r, e, j] = k_i * x[p, j, 1]
        if k < n_steps:
            rk4_body_scratch(q, w, h0, ii, iv, tau_c, tau_e, dt, substeps, q, w, h_out, scratch)
        x, x_next = x_next, x


@njit(cache=True, parallel=True)
def _chunks(bounds, law, n_steps, stride, dt, dt_ns, substeps, step_time,
            q0, w0, x0, q_initial, q_final, inertia, inertia_inv,
            kp, ki, kd, nf, af, u_max, angle_mode,
            e_scale, de_scale, u_scale, fz_rules, v_uniform,
            g_rules, g_vertices, g_scales,
            allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, torque_mode, k_i, r_a, b_m,
            tau_constant, tau_step, step_ns,
            o_q, o_w, o_qr, o_h, o_u, o_tc, o_te, o_ws, o_wa, o_we):
    for c in prange(bounds.shape[0] - 1):
        _chunk(law, bounds[c], bounds[c + 1], n_steps, stride, dt, dt_ns, substeps, step_time,
               q0, w0, x0, q_initial, q_final, inertia, inertia_inv,
               kp, ki, kd, nf, af, u_max, angle_mode,
               e_scale, de_scale, u_scale, fz_rules, v_uniform,
               g_rules, g_vertices, g_scales,
               allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, torque_mode, k_i, r_a, b_m,
               tau_constant, tau_step, step_ns,
               o_q, o_w, o_qr, o_h, o_u, o_tc, o_te, o_ws, o_wa, o_we)


def _c(a, shape=None) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    return np.ascontiguousarray(a if shape is None else np.broadcast_to(a, shape))


def run_compiled(plant, wheels, dist, guide, ctrl, n_steps: int, dt: float, stride: int = 1, threads: int | None = None,
                 chunk: int = 64) -> Trajectory:
    """Run built models (fresh, as the stepwise driver gets them) in the compiled loop.

    Parameters
    ----------
    plant, wheels, dist, guide, ctrl
        Fresh models from the ``build_*`` functions of :mod:`attitude_sil.core.engine`
        (``Plant``, ``Wheels``, ``DisturbanceModel``, ``Guidance``, ``ControllerBank``)
        that :func:`attitude_sil.core.engine.compiled_plan` accepted.
    n_steps : int
        K: states at k = 0..K.
    dt : float
        Control period, s.
    stride : int
        Keep every ``stride``-th step (k = 0, stride, 2 stride, ...).
    threads : int, optional
        Threads for the chunks (default: numba's, one per core). Any count
        gives the same numbers.
    chunk : int
        Episodes per chunk.

    Returns
    -------
    Trajectory
        With ``t`` the kept steps' times.
    """
    P = plant.n_episodes
    law = COMPILED_LAWS[ctrl.active]
    kept = n_steps // stride + 1
    nw = wheels.assembly.n_wheels
    shape3 = (P, 3)
    pid = ctrl.controllers["fuzzy_pid"].pid if law == 1 else ctrl.controllers["pid"]
    pid.reset(P)
    kp, ki, kd, nf, af = pid._kernel_gains()
    fz = ctrl.controllers["fuzzy_pid"]
    ga = ctrl.controllers["ga_flc"]
    asm = wheels.assembly
    mot = asm.motor
    v = dist.v
    models = set(dist.models)
    tau_constant = _c(v["constant.torque"]) if "constant" in models else np.zeros(3)
    tau_step = _c(v["step.torque"]) if "step" in models else np.zeros(3)
    step_ns = int(round(v["step.time"] * 1e9)) if "step" in models else np.iinfo(np.int64).max
    # time-major (step, episode, .): a step's rows of a chunk are contiguous; returned as (P, K+1, .) views
    out = [np.empty((kept, P, 4)), np.empty((kept, P, 3)), np.empty((kept, P, 4))] + \
        [np.empty((kept, P, 3)) for _ in range(4)] + [np.empty((kept, P, nw)) for _ in range(3)]
    previous = numba.get_num_threads()
    n_threads = previous if threads is None else max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
    size = max(1, min(int(chunk), -(-P // n_threads)))  # every thread gets work, chunks stay cache-sized
    bounds = np.unique(np.append(np.arange(0, P, size), P)).astype(np.int64)
    dt_ns = int(round(dt * 1e9))
    if threads is not None:
        numba.set_num_threads(n_threads)
    try:
        rest = (int(n_steps), int(stride), float(dt), dt_ns, int(plant.substeps), float(guide.step_time),
                _c(plant.q0), _c(plant.omega0), np.ascontiguousarray(wheels.x), _c(guide.q_initial),
                _c(guide.q_final), _c(plant.inertia), _c(plant.inertia_inv),
                kp, ki, kd, nf, af, float(ga.u_max if law == 2 else pid.u_max), bool(pid.angle_mode),
                _c(fz.e_scale, shape3), _c(fz.de_scale, shape3), _c(fz.u_scale, shape3),
                np.ascontiguousarray(np.broadcast_to(fz.rules, (P, 7, 7))), UNIFORM_VERTICES,
                np.ascontiguousarray(np.broadcast_to(ga.rules, (P, 7, 7))),
                _c(ga.vertices, (P, 3, 7)), _c(ga.scales, shape3),
                asm.allocation, asm.axes_B, asm.phi_T, asm.gamma, mot.rotor_inertia, mot.back_emf_constant,
                mot.resistance * mot.current_max, mot.speed_max, mot.v_max, ctrl.kind == "torque",
                mot.torque_constant, mot.resistance,
                mot.viscous_friction, tau_constant, tau_step, step_ns, *out)
        if n_threads > 1 and bounds.shape[0] > 2:
            _chunks(bounds, law, *rest)
        else:  # one thread: the chunks one after another, no thread launch
            for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
                _chunk(law, lo, hi, *rest)
    finally:
        numba.set_num_threads(previous)
    q, w, qr, h, u, tc, te, ws, wa, we = (a.transpose(1, 0, 2) for a in out)
    return Trajectory(t=np.arange(0, n_steps + 1, stride) * dt, q_BN=q, omega_BN_B=w, q_RN=qr, h_wheels_B=h,
                      u_cmd=u, tau_c_B=tc, tau_ext_B=te, wheel_speed=ws, kind=[ctrl.kind] * kept,
                      wheel_angle=wa, wheel_effort=we, omega_RN_R=np.zeros((P, kept, 3)))
