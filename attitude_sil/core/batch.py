"""Whole episodes in compiled code: the batch engine's second driver of the step kernels.

The nodes call the compiled step kernels of :mod:`attitude_sil.core.kernels`
once per message, through the objects of :mod:`attitude_sil.core.engine`; the
stepwise :func:`~attitude_sil.core.engine.simulate` loop calls the same objects
once per step from Python. This module is the third caller: one compiled loop
over every step of a chunk of episodes, calling the *same* kernels with the
*same* arrays, so its numbers are the stepwise driver's to the last bit (and
the graph's, which the graph == batch tests check at 1e-9). Chunks of episodes
run on every core (a thread each: the compiled loop runs without the GIL); an
episode's arithmetic does not depend on which chunk or thread ran it, so the
result is identical for any number of threads.

What the compiled driver covers (the tuning and Monte Carlo workhorse: the HST
and CubeSat presets and their kind): the ``rigid_body`` plant, the
``reaction_wheels`` actuator, ``step`` guidance, the ``constant``, ``step``
and ``noise`` disturbance models (or none), and every law (``pid``,
``fuzzy_pid``, ``ga_flc``, ``geometric``): one per episode if asked, with
scheduled swaps and the controller bank's bumpless transfer, per-episode gains,
motor constants, wheel failures and sensor noise (the Monte Carlo's
dispersions; the same kernels as the nodes'). Noise torques are drawn in numpy
from the stepwise driver's streams, a group of episodes at a time.
:func:`attitude_sil.core.engine.compiled_plan` says whether a run fits and, if
not, why; everything else (the flexible and pitch plants, the torque actuator,
LVLH guidance, the orbit disturbances) runs in the stepwise driver, which
handles every model.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit

from .fuzzy import UNIFORM_VERTICES
from .kernels import (
    error_and_rate_row,
    fuzzy_pid_bumpless_row,
    fuzzy_pid_row,
    ga_flc_row,
    geometric_row,
    measure_row,
    offset_row,
    pid_bumpless_row,
    pid_row,
    rk4_body_into,
    wheel_row,
)
from .trajectory import Trajectory
from .wheels import no_failure

__all__ = ["COMPILED_LAWS", "COMPILED_DISTURBANCES", "SUMMARY_COLUMNS", "TRAJECTORY_FIELDS", "run_compiled"]

#: the laws of the compiled driver and their codes (every controller_type, swaps included)
COMPILED_LAWS = {"pid": 0, "fuzzy_pid": 1, "ga_flc": 2, "geometric": 3}

#: disturbance models the compiled driver evaluates in the loop
COMPILED_DISTURBANCES = frozenset({"constant", "step", "noise"})


#: columns of the running sums the compiled driver keeps per episode (``summary=True``)
SUMMARY_COLUMNS = ("time_constant_s", "t10_s", "t90_s", "max_fraction", "settling_time_s", "steady_state_error_rad",
                   "iae", "ise", "itae", "control_effort_Nms", "finite", "peak_command", "peak_wheel_speed")


@njit(cache=True, inline="always")
def _euler_axis(q, p, axis):
    # roll, pitch or yaw (ZYX, paper 000 eq. 9) of row p, as quaternion.euler_from_quat computes it
    x, y, z, w = q[p, 0], q[p, 1], q[p, 2], q[p, 3]
    if axis == 0:
        return np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    if axis == 1:
        return np.arcsin(min(max(2.0 * (w * y - z * x), -1.0), 1.0))
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@njit(cache=True, inline="always")
def _crossing(found, level, f, f_prev, ta, ta_prev, first):
    # metrics._first_crossing, one sample at a time: the interpolated time frac reaches level, or found
    if not np.isnan(found) or not f >= level:
        return found
    if first:
        return ta
    frac = (level - f_prev) / (f - f_prev) if f != f_prev else 0.0
    return ta_prev + frac * (ta - ta_prev)


@njit(cache=True, inline="always")
def _reset_row(law, p, integral, filt, has_prev_f, has_prev_g, has_off):
    # what ControllerBank.request + compute do to the new law's state at a swap (its reset())
    if law <= 1:  # the PID and the fuzzy PID's PID
        for i in range(3):
            integral[p, i] = 0.0
            filt[p, i] = 0.0
    has_prev_f[p] = False
    has_prev_g[p] = False
    has_off[p] = False


@njit(cache=True, nogil=True)
def _chunk(lo, hi, n_steps, stride, dt, dt_ns, substeps, step_time,
           q0, w0, x0, q_initial, q_final, omega_ref, inertia, inertia_inv,
           law0, sw_k, sw_law, command_torque, decay, u_max, angle_mode,
           kp, ki, kd, nf, af, fkp, fki, fkd, fnf, faf,
           e_scale, de_scale, u_scale, fz_rules, v_uniform,
           g_rules, g_vertices, g_scales,
           gk, gl, gj, g_umax, g_rate, g_coeff, g_cp, g_gg, g_aero,
           allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, k_i, r_a, b_m,
           fail_j, fail_k, fail_stuck, e_hold, coast, noisy, s_seeds, s_att, s_rate,
           tau_constant, tau_step, step_ns, tau_noise, noise_lo,
           o_q, o_w, o_qr, o_h, o_u, o_tc, o_te, o_ws, o_wa, o_we,
           m_axis, m_y0, m_r, m_band, o_sum):
    """Episodes ``lo..hi-1`` from step 0 to K, the stepwise driver's order of calls, kept every ``stride``.

    Each episode runs its own law (``law0``, codes of :data:`COMPILED_LAWS`)
    and takes the swaps ``sw_law[s]`` before the command of step ``sw_k[s]``
    (sorted), with ControllerBank's bumpless transfer, per episode. An output
    array with no rows is not kept; ``o_sum`` (P, len(SUMMARY_COLUMNS)) gets
    the running sums when it has rows (``m_*``: the metrics axis, per-episode
    start and final values, the settling band as a fraction of the step).
    ``tau_noise`` (rows from episode ``noise_lo``, K + 1, 3) is the
    disturbance noise torque, or has no rows.
    """
    q = q0[lo:hi].copy()
    w = w0[lo:hi].copy()
    x = x0[lo:hi].copy()
    m = hi - lo
    qi = q_initial[lo:hi].copy()
    qf = q_final[lo:hi].copy()
    omega_r = omega_ref[lo:hi].copy()
    ii = inertia[lo:hi].copy()
    iv = inertia_inv[lo:hi].copy()
    law = law0[lo:hi].copy()
    kp_, ki_, kd_, n_, a_ = kp[lo:hi].copy(), ki[lo:hi].copy(), kd[lo:hi].copy(), nf[lo:hi].copy(), af[lo:hi].copy()
    fkp_, fki_, fkd_ = fkp[lo:hi].copy(), fki[lo:hi].copy(), fkd[lo:hi].copy()
    fn_, fa_ = fnf[lo:hi].copy(), faf[lo:hi].copy()
    integral = np.zeros((m, 3))
    filt = np.zeros((m, 3))
    e_prev = np.zeros((m, 3))
    has_prev_f = np.zeros(m, dtype=np.bool_)
    w_prev = np.zeros((m, 3))
    has_prev_g = np.zeros(m, dtype=np.bool_)
    offset = np.zeros((m, 3))
    has_off = np.zeros(m, dtype=np.bool_)
    u_last = np.zeros((m, 3))
    es, ds, us, fr = e_scale[lo:hi].copy(), de_scale[lo:hi].copy(), u_scale[lo:hi].copy(), fz_rules[lo:hi].copy()
    gr, gv, gs = g_rules[lo:hi].copy(), g_vertices[lo:hi].copy(), g_scales[lo:hi].copy()
    gk_, gl_, gj_ = gk[lo:hi].copy(), gl[lo:hi].copy(), gj[lo:hi].copy()
    # private copies of the shared read-only arrays: threads sharing one array would fight over its reference count
    allocation, axes, phi_T, gamma = allocation.copy(), axes.copy(), phi_T.copy(), gamma.copy()
    k_b, headroom, k_i, r_a, coast = k_b.copy(), headroom.copy(), k_i.copy(), r_a.copy(), coast.copy()
    fail_j, fail_k, fail_stuck = fail_j.copy(), fail_k.copy(), fail_stuck.copy()
    s_seeds, s_att, s_rate = s_seeds.copy(), s_att.copy(), s_rate.copy()
    sw_k, sw_law, g_cp = sw_k.copy(), sw_law.copy(), g_cp.copy()
    qm = np.empty((m, 4))
    wm = np.empty((m, 3))
    tau_constant, tau_step, v_uniform = tau_constant.copy(), tau_step.copy(), v_uniform.copy()
    with_noise = tau_noise.shape[0] > 0
    tau_e = np.zeros((m, 3))
    u = np.empty((m, 3))
    tau_c = np.empty((m, 3))
    h0 = np.empty((m, 3))
    x_next = np.empty_like(x)
    h_out = np.empty((m, 3))
    nw = x.shape[1]
    keep_q, keep_w, keep_qr, keep_h = o_q.shape[0] > 0, o_w.shape[0] > 0, o_qr.shape[0] > 0, o_h.shape[0] > 0
    keep_u, keep_tc, keep_te = o_u.shape[0] > 0, o_tc.shape[0] > 0, o_te.shape[0] > 0
    keep_ws, keep_wa, keep_we = o_ws.shape[0] > 0, o_wa.shape[0] > 0, o_we.shape[0] > 0
    sums = o_sum.shape[0] > 0
    # running sums (see SUMMARY_COLUMNS) and what each needs of the previous sample
    acc = np.zeros((m, len(SUMMARY_COLUMNS)))
    acc[:, 0:3] = np.nan
    acc[:, 3] = -np.inf
    acc[:, 10] = 1.0
    last_out = np.full(m, -1)
    prev = np.zeros((m, 3))  # fraction of the step, time after it, error
    n_after = 0
    s_next = 0
    for k in range(n_steps + 1):
        t_ns = k * dt_ns
        q_r = qf if t_ns * 1e-9 >= step_time - 1e-12 else qi
        swap = -1
        while s_next < sw_k.shape[0] and sw_k[s_next] <= k:
            if sw_k[s_next] == k:
                swap = sw_law[s_next]
            s_next += 1
        for p in range(m):
            for i in range(3):
                tau_e[p, i] = 0.0 + tau_constant[i]
                if t_ns >= step_ns:
                    tau_e[p, i] += tau_step[i]
                if with_noise:
                    tau_e[p, i] += tau_noise[lo + p - noise_lo, k, i]
        if noisy:  # the law sees the measurements (controllers.ControllerBank.measure)
            for p in range(m):
                measure_row(q, w, p, lo + p, k, s_seeds, s_att, s_rate, qm, wm)
        qs, ws = (qm, wm) if noisy else (q, w)
        for p in range(m):
            if swap >= 0 and law[p] != swap:  # ControllerBank.compute with a swap pending
                same_kind = (law[p] == 3) == (swap == 3) or command_torque
                law[p] = swap
                _reset_row(swap, p, integral, filt, has_prev_f, has_prev_g, has_off)
                if k > 0 and same_kind:
                    if swap <= 1:
                        e, de = error_and_rate_row(qs, ws, q_r, omega_r, p, angle_mode)
                        if swap == 0:
                            pid_bumpless_row(e, de, p, kp_, ki_, kd_, n_, integral, filt, u_max,
                                             (u_last[p, 0], u_last[p, 1], u_last[p, 2]))
                        else:
                            has_off[p] = fuzzy_pid_bumpless_row(e, de, p, e_prev, fkp_, fki_, fkd_, fn_, integral,
                                                                filt, es, ds, us, fr, v_uniform, dt, u_max, decay,
                                                                u_last, offset)
                            has_prev_f[p] = True
                    elif decay > 0.0:  # a stateless law: a decaying offset from the old law's last command
                        if swap == 2:
                            ga_flc_row(qs, ws, q_r, omega_r, p, gr, gv, gs, u_max, u)
                        else:
                            geometric_row(qs, ws, q_r, omega_r, w_prev, False, p, gk_, gl_, gj_, dt, g_umax, g_rate,
                                          g_coeff, g_cp, g_gg, g_aero, u)
                        for i in range(3):
                            offset[p, i] = u_last[p, i] - u[p, i]
                        has_off[p] = True
            lp = law[p]
            if lp == 0:
                pid_row(qs, q_r, p, kp_, ki_, kd_, n_, a_, integral, filt, dt, u_max, angle_mode, u)
            elif lp == 1:
                fuzzy_pid_row(qs, q_r, p, e_prev, has_prev_f[p], fkp_, fki_, fkd_, fn_, fa_, integral, filt, es, ds,
                              us, fr, v_uniform, dt, u_max, angle_mode, u)
                has_prev_f[p] = True
            elif lp == 2:
                ga_flc_row(qs, ws, q_r, omega_r, p, gr, gv, gs, u_max, u)
            else:
                geometric_row(qs, ws, q_r, omega_r, w_prev, has_prev_g[p], p, gk_, gl_, gj_, dt, g_umax, g_rate,
                              g_coeff, g_cp, g_gg, g_aero, u)
                for i in range(3):
                    w_prev[p, i] = omega_r[p, i]
                has_prev_g[p] = True
            if lp >= 1:  # the stateless part of the transfer: the offset, then the law's saturation
                limit = g_umax if lp == 3 else u_max
                if has_off[p]:
                    offset_row(u, p, offset, has_off, decay)
                    for i in range(3):
                        u[p, i] = min(max(u[p, i], -limit), limit)
                elif lp == 1:
                    for i in range(3):
                        u[p, i] = min(max(u[p, i], -limit), limit)
            for i in range(3):
                u_last[p, i] = u[p, i]
            wheel_row(x, u, p, lo + p, k, allocation, axes, phi_T, gamma, j_m, k_b, headroom, speed_max, v_max, dt,
                      command_torque or lp == 3, k_i, r_a, b_m, fail_j, fail_k, fail_stuck, e_hold, coast, x_next,
                      tau_c, h0)
        if k % stride == 0:
            r = k // stride
            for p in range(m):
                e = lo + p
                for i in range(4):
                    if keep_q:
                        o_q[e, r, i] = q[p, i]
                    if keep_qr:
                        o_qr[e, r, i] = q_r[p, i]
                for i in range(3):
                    if keep_w:
                        o_w[e, r, i] = w[p, i]
                    if keep_h:
                        o_h[e, r, i] = h0[p, i]
                    if keep_u:
                        o_u[e, r, i] = u[p, i]
                    if keep_tc:
                        o_tc[e, r, i] = tau_c[p, i]
                    if keep_te:
                        o_te[e, r, i] = tau_e[p, i]
                for j in range(nw):
                    if keep_wa:
                        o_wa[e, r, j] = x[p, j, 0]
                    if keep_ws:
                        o_ws[e, r, j] = x[p, j, 2]
                    if keep_we:
                        o_we[e, r, j] = k_i[e if k_i.shape[0] > 1 else 0] * x[p, j, 1]
        if sums:
            t = k * dt
            after = t >= step_time - 1e-12
            _accumulate(acc, last_out, prev, lo, k, n_steps, t, dt, after, n_after, step_time,
                        q, w, u, tau_c, x, m_axis, m_y0, m_r, m_band)
            n_after += after
        if k < n_steps:
            rk4_body_into(q, w, h0, ii, iv, tau_c, tau_e, dt, substeps, q, w, h_out)
        x, x_next = x_next, x
    if sums:
        for p in range(m):
            if last_out[p] < 0:
                acc[p, 4] = 0.0
            elif last_out[p] == n_after - 1:
                acc[p, 4] = np.nan
            acc[p, 5] = abs(prev[p, 2])
            for c in range(len(SUMMARY_COLUMNS)):
                o_sum[lo + p, c] = acc[p, c]


@njit(cache=True)
def _accumulate(acc, last_out, prev, lo, k, n_steps, t, dt, after, n_after, step_time,
                q, w, u, tau_c, x, axis, m_y0, m_r, m_band):
    # one step of the chunk's running sums (SUMMARY_COLUMNS), as metrics.summarize computes them
    for p in range(q.shape[0]):
        _accumulate_row(acc, last_out, prev, p, lo + p, k, n_steps, t, dt, after, n_after, step_time,
                        q, w, u, tau_c, x, axis, m_y0, m_r, m_band)


@njit(cache=True, inline="always")
def _accumulate_row(acc, last_out, prev, p, e, k, n_steps, t, dt, after, n_after, step_time,
                    q, w, u, tau_c, x, axis, m_y0, m_r, m_band):
    for i in range(3):
        if not (np.isfinite(w[p, i]) and np.isfinite(u[p, i])):
            acc[p, 10] = 0.0
        acc[p, 11] = max(acc[p, 11], abs(u[p, i])) if not np.isnan(u[p, i]) else np.inf
    for j in range(x.shape[1]):
        acc[p, 12] = max(acc[p, 12], abs(x[p, j, 2])) if not np.isnan(x[p, j, 2]) else np.inf
    if k < n_steps:
        acc[p, 9] += np.sqrt(tau_c[p, 0] ** 2 + tau_c[p, 1] ** 2 + tau_c[p, 2] ** 2) * ((k + 1) * dt - t)
    if not after:
        return
    y0, r_fin = m_y0[e], m_r[e]
    span = r_fin - y0
    ta = t - step_time
    y = _euler_axis(q, p, axis)
    f = (y - y0) / (1.0 if span == 0.0 else span)
    first = n_after == 0
    f_prev, ta_prev, err_prev = prev[p, 0], prev[p, 1], prev[p, 2]
    acc[p, 0] = _crossing(acc[p, 0], 0.632, f, f_prev, ta, ta_prev, first)
    acc[p, 1] = _crossing(acc[p, 1], 0.1, f, f_prev, ta, ta_prev, first)
    acc[p, 2] = _crossing(acc[p, 2], 0.9, f, f_prev, ta, ta_prev, first)
    acc[p, 3] = max(acc[p, 3], f)
    if abs(y - r_fin) > m_band * abs(span):
        last_out[p] = n_after
    elif last_out[p] == n_after - 1 and last_out[p] >= 0:
        acc[p, 4] = ta  # settled: the first sample after the last one outside the band, unless it leaves again
    err = r_fin - y
    if not first:
        d = ta - ta_prev
        acc[p, 6] += 0.5 * (abs(err) + abs(err_prev)) * d
        acc[p, 7] += 0.5 * (err ** 2 + err_prev ** 2) * d
        acc[p, 8] += 0.5 * (ta * abs(err) + ta_prev * abs(err_prev)) * d
    prev[p, 0], prev[p, 1], prev[p, 2] = f, ta, err


#: threads of the compiled driver: one per core (numba's count, which NUMBA_NUM_THREADS sets)
_POOL_SIZE = max(1, int(numba.config.NUMBA_NUM_THREADS))
_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(_POOL_SIZE, thread_name_prefix="attitude_sil-batch")
    return _POOL


def _c(a, shape=None) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    return np.ascontiguousarray(a if shape is None else np.broadcast_to(a, shape))


def _writable(a):
    # one numba signature per argument: a read-only or strided array (a broadcast view) would compile the
    # whole loop again for its type, so such arrays go in as contiguous writable copies
    if isinstance(a, np.ndarray) and not (a.flags.writeable and a.flags.c_contiguous):
        return np.array(a, order="C")
    return a


#: the Trajectory arrays the compiled driver can keep (``keep``), in its output order
TRAJECTORY_FIELDS = ("q_BN", "omega_BN_B", "q_RN", "h_wheels_B", "u_cmd", "tau_c_B", "tau_ext_B", "wheel_speed",
                     "wheel_angle", "wheel_effort")


def _kinds(ctrl, laws: np.ndarray, swaps: dict, kept_steps: np.ndarray) -> list[str]:
    """The command kind (``voltage``/``torque``) at each kept step; every episode's is the same."""
    first = ctrl.kind_of(str(laws[0]))
    if not swaps:
        return [first] * len(kept_steps)
    at = sorted(swaps)
    kinds = np.array([first] + [ctrl.kind_of(swaps[k]) for k in at], dtype=object)
    return kinds[np.searchsorted(np.array(at), kept_steps, side="right")].tolist()


def run_compiled(plant, wheels, dist, guide, ctrl, n_steps: int, dt: float, stride: int = 1, threads: int | None = None,
                 chunk: int = 64, keep=TRAJECTORY_FIELDS, sums: tuple | None = None, swaps: dict | None = None,
                 laws=None) -> tuple[Trajectory | None, np.ndarray | None]:
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
    keep : collection of str
        The :data:`TRAJECTORY_FIELDS` (and ``omega_RN_R``) to keep; the others
        are None. Empty keeps no trajectory.
    sums : tuple, optional
        ``(axis, y0 (P,), r (P,), band)``: keep the running sums of
        :data:`SUMMARY_COLUMNS` for a step on that Euler axis from ``y0`` to
        ``r`` (rad) with a settling band of ``band`` times the step.
    swaps : dict, optional
        ``{step k: controller_type}``: swaps before the command of step k,
        with the bank's bumpless transfer.
    laws : sequence of str, optional
        Each episode's ``controller_type`` (default ``ctrl.active`` for all);
        all must command the same kind (volts or N m).

    Returns
    -------
    (Trajectory or None, ndarray (P, len(SUMMARY_COLUMNS)) or None)
        The trajectory with ``t`` the kept steps' times (None if ``keep`` is
        empty), and the running sums (None without ``sums``).
    """
    unknown = set(keep) - set(TRAJECTORY_FIELDS) - {"omega_RN_R"}
    if unknown:
        raise ValueError(f"keep: unknown trajectory fields {sorted(unknown)}")
    P = plant.n_episodes
    swaps = dict(swaps or {})
    laws = np.asarray([ctrl.active] * P if laws is None else laws, dtype=object)
    law0 = np.array([COMPILED_LAWS[str(law)] for law in laws], dtype=np.int64)
    sw = sorted(swaps.items())
    sw_k = np.array([k for k, _ in sw], dtype=np.int64)
    sw_law = np.array([COMPILED_LAWS[law] for _, law in sw], dtype=np.int64)
    kept = n_steps // stride + 1
    nw = wheels.assembly.n_wheels
    shape3 = (P, 3)
    pid = ctrl.controllers["pid"]
    fz = ctrl.controllers["fuzzy_pid"]
    ga = ctrl.controllers["ga_flc"]
    geo = ctrl.controllers["geometric"]
    pid.reset(P)
    fz.pid.reset(P)
    asm = wheels.assembly
    mot = asm.motor
    v = dist.v
    models = set(dist.models)
    tau_constant = _c(v["constant.torque"]) if "constant" in models else np.zeros(3)
    tau_step = _c(v["step.torque"]) if "step" in models else np.zeros(3)
    step_ns = int(round(v["step.time"] * 1e9)) if "step" in models else np.iinfo(np.int64).max
    # episode-major (episode, step, .): each episode's series is contiguous, as the Trajectory holds it
    width = dict(q_BN=4, q_RN=4, wheel_speed=nw, wheel_angle=nw, wheel_effort=nw)
    out = {f: np.empty((P, kept, width.get(f, 3)) if f in keep else (0, 0, width.get(f, 3)))
           for f in TRAJECTORY_FIELDS}
    if sums is None:
        m_axis, m_y0, m_r, m_band, o_sum = 0, np.zeros(P), np.zeros(P), 0.0, np.empty((0, len(SUMMARY_COLUMNS)))
    else:
        m_axis, m_y0, m_r, m_band = int(sums[0]), _c(sums[1], (P,)), _c(sums[2], (P,)), float(sums[3])
        o_sum = np.empty((P, len(SUMMARY_COLUMNS)))
    failure = wheels.failure_arrays() if wheels.failure is not None else no_failure()
    n_threads = _POOL_SIZE if threads is None else max(1, min(int(threads), _POOL_SIZE))
    size = max(1, min(int(chunk), -(-P // n_threads)))  # every thread gets work, chunks stay cache-sized
    bounds = np.unique(np.append(np.arange(0, P, size), P)).astype(np.int64)
    dt_ns = int(round(dt * 1e9))
    g_k, g_l, g_j, g_rate, g_coeff, g_cp, g_gg, g_aero = geo.kernel_params(P)
    omega_ref = _c(guide.omega, shape3)
    head = (int(n_steps), int(stride), float(dt), dt_ns, int(plant.substeps), float(guide.step_time),
            _c(plant.q0), _c(plant.omega0), np.ascontiguousarray(wheels.x), _c(guide.q_initial),
            _c(guide.q_final), omega_ref, _c(plant.inertia), _c(plant.inertia_inv),
            law0, sw_k, sw_law, ctrl.command == "torque", float(fz.decay), float(pid.u_max), bool(pid.angle_mode),
            *pid._kernel_gains(), *fz.pid._kernel_gains(),
            _c(fz.e_scale, shape3), _c(fz.de_scale, shape3), _c(fz.u_scale, shape3),
            np.ascontiguousarray(np.broadcast_to(fz.rules, (P, 7, 7))), UNIFORM_VERTICES.reshape(1, 1, 7),
            np.ascontiguousarray(np.broadcast_to(ga.rules, (P, 7, 7))),
            _c(ga.vertices, (P, 3, 7)), _c(ga.scales, shape3),
            g_k, g_l, g_j, float(geo.u_max), g_rate, g_coeff, _c(g_cp), bool(g_gg), bool(g_aero),
            asm.allocation, asm.axes_B, asm.phi_e, asm.gamma_e, mot.rotor_inertia, asm.k_b_e,
            asm.headroom_e, mot.speed_max, mot.v_max, asm.k_i_e, asm.r_a_e,
            mot.viscous_friction, *failure, asm.coast, ctrl.noisy, ctrl.sensor_seeds, ctrl.sensor_att_std,
            ctrl.sensor_rate_std, tau_constant, tau_step, step_ns)
    head = tuple(_writable(a) for a in head)
    tail = (*out.values(), m_axis, m_y0, m_r, m_band, o_sum)
    # disturbance noise is drawn in numpy (the stepwise driver's streams) for a group of episodes at a time,
    # so its memory is that of the group, not of the run
    groups = [(0, P)]
    if "noise" in models:
        group = max(size * n_threads, 256)
        groups = [(g, min(g + group, P)) for g in range(0, P, group)]
    for g_lo, g_hi in groups:
        noise = (dist.noise_torque(g_lo, g_hi, n_steps) if "noise" in models else np.zeros((0, 0, 3)))
        args = (*head, noise, g_lo, *tail)
        b = bounds[(bounds >= g_lo) & (bounds <= g_hi)]
        b = np.unique(np.concatenate(([g_lo], b, [g_hi]))).astype(np.int64).tolist()
        spans = list(zip(b[:-1], b[1:], strict=True))
        if n_threads > 1 and len(spans) > 1:  # the chunks on threads: _chunk runs without the GIL
            list(_pool().map(lambda span, a=args: _chunk(span[0], span[1], *a), spans))
        else:  # one thread: the chunks one after another, no thread hand-off
            for lo, hi in spans:
                _chunk(lo, hi, *args)
    trajectory = None
    if keep:
        got = {f: (a if f in keep else None) for f, a in out.items()}
        steps = np.arange(0, n_steps + 1, stride)
        omega_rn = np.ascontiguousarray(np.broadcast_to(omega_ref[:, None, :], (P, kept, 3)))
        trajectory = Trajectory(t=steps * dt, kind=_kinds(ctrl, laws, swaps, steps),
                                omega_RN_R=omega_rn if "omega_RN_R" in keep else None, **got)
    return trajectory, (None if sums is None else o_sum)
