"""The batch engine's compiled loop: every step of a chunk of episodes, in stages over its episodes.

:mod:`attitude_sil.core.sim.batch` compiles :func:`chunk` (and
:func:`chunk_one` for a chunk of one episode) for its set of laws
(:data:`CHUNK_JIT`) and runs it. Each step runs the stages swaps, commands, wheels
and body over the chunk's episodes, each episode's arithmetic in the order
of the stepwise driver. The command stage
(:func:`attitude_sil.core.control.dispatch.command_stage`) runs each law's
compiled loop, called at its address, on the episodes whose code is that
law's; :func:`~attitude_sil.core.control.dispatch.reset_row` and
:func:`~attitude_sil.core.control.dispatch.enter_at` do the bumpless swap
(:mod:`attitude_sil.core.control.law`). The laws' records come in as one
tuple ``recs`` of ``(par, st)`` pairs in code order. The plant's state lives
in blocks (:mod:`attitude_sil.core.plant.lanes`: the episodes as the vector
axis, a row per quantity), where the wheels' and the body's stages run as
packed instructions; the laws, the swaps and the metrics read row-major
copies (m, width) made once per step.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from numba import njit

from attitude_sil.core.analysis.metric_rows import Sums, euler_axis, first_crossing
from attitude_sil.core.control.dispatch import command_stage, enter_at, reset_row
from attitude_sil.core.control.laws.bdot import bdot_row
from attitude_sil.core.control.momentum import dumping_row, torque_dipole_row
from attitude_sil.core.environment.ephemeris import body_field
from attitude_sil.core.faults import NEVER
from attitude_sil.core.plant.command_faults import CommandFault, command_fault_row
from attitude_sil.core.plant.disturbance import orbit_torques
from attitude_sil.core.plant.kernels import WheelFailure, measure_row, wheel_params_copy
from attitude_sil.core.plant.lanes import (
    ANGLE,
    CURRENT,
    SPEED,
    TC,
    TE,
    H,
    Q,
    U,
    W,
    body_block,
    column_major,
    copy_wheels,
    lanes_to_rows,
    motor_lanes,
    rk4_body_lanes,
    rows_to_lanes,
    wheel_lanes,
    wheels_to_lanes,
)
from attitude_sil.core.plant.magnetorquers import rods_torque_row

#: number of running-sum columns
N_SUMS = len(Sums)


class Previous(IntEnum):
    """The rows of the running sums' previous sample (3, m)."""

    fraction = 0  #: the response as a fraction of the step
    time = 1  #: time after the step, s
    error = 2  #: error, rad


@njit(cache=True, inline="always")
def _swap_row(k, p, swap, law, view, recs, sim, xfer, u, at):
    # ControllerBank.compute with a swap pending, for row p: reset, then the bumpless entry (the law's
    # enter_<code>, at its address). view: the law's inputs (q, w, q_r, w_r); xfer: the transfer's
    # (u_last, offset, has_off)
    has_off = xfer[2]
    same_kind = sim.law_torque[law[p]] == sim.law_torque[swap] or sim.command_torque
    law[p] = swap
    reset_row(swap, p, recs)
    has_off[p] = False
    if k > 0 and same_kind:
        enter_at(swap, at, view, p, recs, sim.dt, sim.decay, xfer, u)


@njit(cache=True, inline="always")
def _next_swap(sw_k, sw_law, s_next, k):
    # the law code a swap of step k goes to (-1: none), and the index of the next swap after k
    swap = -1
    while s_next < sw_k.shape[0] and sw_k[s_next] <= k:
        if sw_k[s_next] == k:
            swap = sw_law[s_next]
        s_next += 1
    return swap, s_next


@njit(cache=True, inline="always")
def _ext_torque(tau_e, m, t_ns, step_ns, tau_constant, tau_step, noise, row0, k):
    # the disturbance torque of step k: constant, step and the noise (rows from row0; no rows: no noise)
    for p in range(m):
        for i in range(3):
            tau_e[p, i] = 0.0 + tau_constant[i]
            if t_ns >= step_ns:
                tau_e[p, i] += tau_step[i]
            if noise.shape[0] > 0:
                tau_e[p, i] += noise[row0 + p, k, i]


@njit(cache=True)  # not inlined: compiled once, not again in the loop of every set of laws
def _magnetic_stage(m, lo, k, sim, q, h, u, law, mag):
    # the magnetorquers' loop of step k (models.MagneticLoop.step), after the wheels' stage: the field in B,
    # B-dot's difference (every step, whichever law is active), the dipole of the law in charge, the rods'
    # torque; mag: (previous field direction, field, B-dot's dipole, dipole, rods, made, torque) (m, .) rows
    prev, b_B, m_bd, m_cmd, rod_d, made, tau_m = mag
    b0, b1, b2 = sim.b_N[k, 0], sim.b_N[k, 1], sim.b_N[k, 2]
    for p in range(m):
        body_field(q, p, b0, b1, b2, b_B, p)
        bdot_row(b_B, p, prev, k > 0, sim.k_bdot[lo + p], sim.dt, m_bd)
        if law[p] == sim.bdot_code:
            for i in range(3):
                m_cmd[p, i] = m_bd[p, i]
        elif sim.torque_rods:
            torque_dipole_row(u, b_B, p, m_cmd)
        elif sim.dumping:
            dumping_row(h, b_B, p, sim.k_dump[lo + p], sim.h_target[lo + p], m_cmd)
        else:
            for i in range(3):
                m_cmd[p, i] = 0.0
        rods_torque_row(m_cmd, b_B, p, sim.rod_axes, sim.rod_alloc, sim.rod_max, rod_d, made, tau_m)


@njit(cache=True, inline="always")
def _keep_rows(dst, r, lo, m, src):
    # rows 0..m-1 of src (m, width) into step r of episodes lo.. of dst (P, kept, width); no rows: not kept
    if dst.shape[0] == 0:
        return
    for p in range(m):
        for i in range(src.shape[1]):
            dst[lo + p, r, i] = src[p, i]


@njit(cache=True, inline="always")
def _keep_wheels(o_ws, o_wa, o_we, r, lo, xw, k_i):
    # the wheels' speed, angle and effort of step r from the lanes xw (n, 3, m) (an output with no rows is not kept)
    for p in range(xw.shape[2]):
        e = lo + p
        for j in range(xw.shape[0]):
            if o_wa.shape[0] > 0:
                o_wa[e, r, j] = xw[j, ANGLE, p]
            if o_ws.shape[0] > 0:
                o_ws[e, r, j] = xw[j, SPEED, p]
            if o_we.shape[0] > 0:
                o_we[e, r, j] = k_i[e if k_i.shape[0] > 1 else 0] * xw[j, CURRENT, p]


@njit(cache=True, inline="always")
def _plant_start(sim, lo, m):
    # the plant's blocks for episodes lo..lo+m-1 at step 0: the body block (state, inertia), the wheel states
    # now and next (n, 3, m)
    b = body_block(sim.q0, sim.w0, sim.inertia, sim.inertia_inv, lo, m)
    nw = sim.x0.shape[1]
    xw, xn = np.empty((nw, 3, m)), np.empty((nw, 3, m))
    wheels_to_lanes(sim.x0, lo, xw)
    return b, xw, xn


#: how :mod:`attitude_sil.core.sim.batch` compiles :func:`chunk` and :func:`chunk_one`, once per set of laws
#: (each in a cache folder of its own: :func:`attitude_sil.core.cache.numba_cache_in` says why)
CHUNK_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}


def chunk(lo, hi, sim, recs, noise, noise_lo, out, sums, at):
    """Episodes ``lo..hi-1`` from step 0 to K, the stepwise driver's order of calls, kept every ``stride``.

    ``sim`` (batch.SimArrays): the models' arrays; ``recs``: each law's ``(par, st)``, its parameter and
    state records for these episodes (rows 0..hi-lo-1); ``noise`` (rows from episode ``noise_lo``, K + 1, 3): the noise
    torque, or no rows; ``out`` (batch.Outputs): the kept trajectory arrays (no rows: not kept); ``sums``
    (batch.SumsSpec): the running sums' axis, start and final values, band and output (no rows: none). Each
    episode runs its own law (``sim.law0``) and takes the swaps ``sim.sw_law[s]`` before the command of
    step ``sim.sw_k[s]`` (sorted), with the controller bank's bumpless transfer. ``at`` (3, n_laws): the
    addresses of each law's compiled loops (``compiled.law_addresses``).
    """
    _chunk(lo, hi, hi - lo, sim, recs, noise, noise_lo, out, sums, at)


def chunk_one(lo, hi, sim, recs, noise, noise_lo, out, sums, at):
    """:func:`chunk` for one episode (``hi == lo + 1``): the block's width is a constant there, so LLVM
    drops every stage's loop over the episodes (a loop of one would pay its vector preamble every step)."""
    _chunk(lo, lo + 1, 1, sim, recs, noise, noise_lo, out, sums, at)


@njit(cache=True, inline="always")
def _chunk(lo, hi, m, sim, recs, noise, noise_lo, out, sums, at):
    # chunk's body, m = hi - lo episodes
    # what the laws read, (m, 4) and (m, 3) in column-major order (a law's one-law loop runs on packed lanes)
    q, w = column_major(sim.q0, lo, m), column_major(sim.w0, lo, m)
    qi, qf = column_major(sim.q_initial, lo, m), column_major(sim.q_final, lo, m)
    omega_r = column_major(sim.omega_ref, lo, m)
    law = sim.law0[lo:hi].copy()
    present = np.zeros(len(recs), dtype=np.bool_)  # the laws some episode of the chunk runs
    for p in range(m):
        present[law[p]] = True
    offset, has_off, u_last = np.zeros((m, 3)), np.zeros(m, dtype=np.bool_), np.zeros((m, 3))
    xfer = (u_last, offset, has_off)  # the bumpless transfer's arrays
    # private copies of the shared read-only arrays: threads sharing one array would fight over its reference count
    wp, f = wheel_params_copy(sim.wheel), sim.failure
    fail = WheelFailure(f.wheel.copy(), f.step.copy(), f.mode.copy(), f.value.copy(), f.e_hold.copy(),
                        f.isolated.copy(), f.isolated_step.copy(), f.phi.copy(), f.gamma.copy())
    cf, cf_on, u_out = _command_fault_start(sim.cmd_fault, lo, hi, m)
    no_wcmd = np.empty((0, m))  # the laws command the body axes: no per-wheel command
    tau_constant, tau_step = sim.tau_constant.copy(), sim.tau_step.copy()
    s_seeds, s_att, s_rate = sim.s_seeds.copy(), sim.s_att.copy(), sim.s_rate.copy()
    sw_k, sw_law = sim.sw_k.copy(), sim.sw_law.copy()
    qm, wm, u = np.empty((4, m)).T, np.empty((3, m)).T, np.empty((3, m)).T  # column-major too, written before read
    tau_e = np.zeros((m, 3))
    torque = np.empty(m, dtype=np.bool_)  # the rows whose command is a torque
    tau_c, h0 = np.empty((m, 3)), np.empty((m, 3))
    b, xw, xn = _plant_start(sim, lo, m)
    mot = motor_lanes(wp, lo, m)
    orbit_on, inertia_d, cp, mag, tau_all = _environment_start(sim, lo, hi, m)
    keep = _any_kept(out)
    sums_out, with_sums = sums.out, sums.out.shape[0] > 0
    response = (sums.axis, sums.band, sums.y0, sums.r)  # out of the record once (a take per step costs refcounts)
    sums_state = _sums_start(m)
    n_after = s_next = 0
    for k in range(sim.n_steps + 1):
        t_ns = k * sim.dt_ns
        q_r = qf if t_ns * 1e-9 >= sim.step_time - 1e-12 else qi
        swap, s_next = _next_swap(sw_k, sw_law, s_next, k)
        _ext_torque(tau_e, m, t_ns, sim.step_ns, tau_constant, tau_step, noise, lo - noise_lo, k)
        if orbit_on:  # DisturbanceModel.torque's orbit models, on this step's frame and gains
            orbit_torques(q, sim.orbit_q_LN[k], inertia_d, sim.orbit_gg[k], sim.orbit_aero[k], cp, sim.gg_on,
                          sim.aero_on, tau_e)
        if sim.noisy:  # the law sees the measurements (ControllerBank.measure)
            for p in range(m):
                measure_row(q, w, p, lo + p, k, s_seeds, s_att, s_rate, qm, wm)
        qs, ws = (qm, wm) if sim.noisy else (q, w)
        if swap >= 0:  # ControllerBank.compute with a swap pending
            present[swap] = True
            for p in range(m):
                if law[p] != swap:
                    _swap_row(k, p, swap, law, (qs, ws, q_r, omega_r), recs, sim, xfer, u, at)
        command_stage(law, present, (qs, ws, q_r, omega_r), recs, sim.dt, u, xfer, sim.decay, at)
        for p in range(m):
            torque[p] = sim.command_torque or sim.law_torque[law[p]]
            for i in range(3):
                u_last[p, i] = u[p, i]
        rows_to_lanes(_command_faults(cf, cf_on, u, u_out, m, lo, k), 0, b, U, m)
        wheel_lanes(m, lo, k, xw, xn, b, mot, torque, wp, fail, no_wcmd)
        if sim.mag:  # the rods, from the wheels' momentum at t_k
            lanes_to_rows(b, H, h0)
            _magnetic_stage(m, lo, k, sim, q, h0, u, law, mag)
        if keep and k % sim.stride == 0:
            lanes_to_rows(b, TC, tau_c)
            lanes_to_rows(b, H, h0)
            _keep_all(out, k // sim.stride, lo, (q, q_r, w, h0, u, tau_c, tau_e), xw, wp.k_i, mag)
        if with_sums:
            t = k * sim.dt
            _accumulate_checks(sums_state[0], m, k, t, sim.n_steps, sim.dt, b, xw)
            if t >= sim.step_time - 1e-12:
                _accumulate_response(sums_state, m, t - sim.step_time, n_after, b, response, lo)
                n_after += 1
        if k < sim.n_steps:  # h (the wheel momentum at t_k, kept above) becomes the body's h at t_k+1
            rows_to_lanes(_body_torque(sim.mag, m, tau_e, mag[6], tau_all), 0, b, TE, m)
            rk4_body_lanes(m, b, sim.dt, sim.substeps)
            lanes_to_rows(b, Q, q)
            lanes_to_rows(b, W, w)
        copy_wheels(xn, xw)  # copied, not swapped: a loop over a swapped pair of arrays stays scalar (bench/README.md)
    if with_sums:
        _sums_end(sums_state, n_after, sums_out, lo)


@njit(cache=True, inline="always")
def _command_fault_start(c, lo, hi, m):
    # the controller output's faults of episodes lo..hi-1: private copies (the rings rows lo..hi-1), whether any
    # flies, and the applied command's rows (column-major, as the law's)
    one = c.gain.shape[0] == 1
    a, z = (0, 1) if one else (lo, hi)
    cf = CommandFault(c.gain[a:z].copy(), c.gain_from[a:z].copy(), c.gain_to[a:z].copy(), c.delay[a:z].copy(),
                      c.delay_from[a:z].copy(), c.delay_to[a:z].copy(), c.ring[lo:hi].copy(), c.held[lo:hi].copy())
    on = not one or c.gain_from[0] != NEVER or c.delay_from[0] != NEVER
    return cf, on, np.empty((3, m)).T


@njit(cache=True, inline="always")
def _command_faults(cf, on, u, u_out, m, lo, k):
    # the command the wheels take at step k: the law's, or with the output faults of cf (command_faults) applied
    if not on:
        return u
    one = cf.gain.shape[0] == 1
    for p in range(m):
        command_fault_row(u, p, 0 if one else p, k, cf, u_out)
    return u_out


@njit(cache=True, inline="always")
def _environment_start(sim, lo, hi, m):
    # whether the orbit's disturbances fly, the episodes' inertia for them and the centre of pressure (private
    # copies), _magnetic_stage's rows, and the rows of the disturbances' torque plus the rods'
    mag = (np.zeros((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty((m, sim.rod_axes.shape[0])),
           np.empty((m, 3)), np.zeros((m, 3)))
    return sim.gg_on or sim.aero_on, sim.dist_inertia[lo:hi].copy(), sim.cp_offset.copy(), mag, np.empty((m, 3))


@njit(cache=True, inline="always")
def _body_torque(mag_on, m, tau_e, tau_m, tau_all):
    # the torque the plant adds to the control torque: the disturbances' and, where they fly, the rods'
    if not mag_on:
        return tau_e
    for p in range(m):
        for i in range(3):
            tau_all[p, i] = tau_e[p, i] + tau_m[p, i]
    return tau_all


@njit(cache=True, inline="always")
def _any_kept(out):
    # whether any trajectory output is kept (has rows)
    keep = False
    for o in out:
        keep = keep or o.shape[0] > 0
    return keep


@njit(cache=True, inline="always")
def _keep_all(out, r, lo, rows, xw, k_i, mag):
    # step r of every kept output: the rows (q, q_r, w, h, u, tau_c, tau_e) (m, width), the wheels' lanes, and
    # the magnetorquers' field in B, dipole and torque (_magnetic_stage's rows)
    o_q, o_w, o_qr, o_h, o_u, o_tc, o_te, o_ws, o_wa, o_we = out[:10]
    q, q_r, w, h0, u, tau_c, tau_e = rows
    m = q.shape[0]
    _keep_rows(o_q, r, lo, m, q)
    _keep_rows(o_qr, r, lo, m, q_r)
    _keep_rows(o_w, r, lo, m, w)
    _keep_rows(o_h, r, lo, m, h0)
    _keep_rows(o_u, r, lo, m, u)
    _keep_rows(o_tc, r, lo, m, tau_c)
    _keep_rows(o_te, r, lo, m, tau_e)
    _keep_wheels(o_ws, o_wa, o_we, r, lo, xw, k_i)
    _keep_rows(out.b, r, lo, m, mag[1])
    _keep_rows(out.mc, r, lo, m, mag[3])
    _keep_rows(out.mt, r, lo, m, mag[6])


@njit(cache=True, inline="always")
def _sums_start(m):
    # the running sums (SUMMARY_COLUMNS, m), episodes last, before step 0; the last step outside the band; the
    # previous sample (fraction of the step, time after it, error) (3, m); the sample's angle (m,)
    acc = np.zeros((N_SUMS, m))
    for p in range(m):
        acc[Sums.time_constant_s, p] = acc[Sums.t10_s, p] = acc[Sums.t90_s, p] = np.nan
        acc[Sums.max_fraction, p] = -np.inf
        acc[Sums.finite, p] = 1.0
    return acc, np.full(m, -1), np.zeros((3, m)), np.empty(m)


@njit(cache=True, inline="always")
def _sums_end(state, n_after, sums_out, lo):
    # settling (never left the band: 0; outside at the end: never settled) and the final error, into the output
    acc, last_out, prev, _ = state
    for p in range(acc.shape[1]):
        if last_out[p] < 0:
            acc[Sums.settling_time_s, p] = 0.0
        elif last_out[p] == n_after - 1:
            acc[Sums.settling_time_s, p] = np.nan
        acc[Sums.steady_state_error_rad, p] = abs(prev[Previous.error, p])
        for c in range(N_SUMS):
            sums_out[lo + p, c] = acc[c, p]


@njit(cache=True, inline="always")
def _accumulate_checks(acc, m, k, t, n_steps, dt, b, xw):
    # one step's finiteness, peaks and control effort (SUMMARY_COLUMNS), as metrics.summarize computes them, from
    # the body block b (rate, command, wheel torque) and the wheel states xw (n, 3, m); a loop over the episodes
    for p in range(m):
        for i in range(3):
            w_i, u_i = b[W + i, p], b[U + i, p]
            if not (np.isfinite(w_i) and np.isfinite(u_i)):
                acc[Sums.finite, p] = 0.0
            acc[Sums.peak_command, p] = max(acc[Sums.peak_command, p], abs(u_i)) if not np.isnan(u_i) else np.inf
    for j in range(xw.shape[0]):
        for p in range(m):
            speed = xw[j, SPEED, p]
            peak = acc[Sums.peak_wheel_speed, p]
            acc[Sums.peak_wheel_speed, p] = max(peak, abs(speed)) if not np.isnan(speed) else np.inf
    if k < n_steps:
        for p in range(m):
            tc0, tc1, tc2 = b[TC, p], b[TC + 1, p], b[TC + 2, p]
            acc[Sums.control_effort_Nms, p] += np.sqrt(tc0 ** 2 + tc1 ** 2 + tc2 ** 2) * ((k + 1) * dt - t)


@njit(cache=True, inline="always")
def _accumulate_response(state, m, ta, n_after, b, response, lo):
    # one sample (time ta after the step) of the step response sums, as metrics.summarize computes them: the
    # angle of every episode first (roll and yaw in arithmetic, packed; pitch a libm call each), then the sums
    acc, last_out, prev, y = state
    axis, band, y0, r_fin = response
    if axis == 1:
        for p in range(m):
            y[p] = euler_axis(b[Q, p], b[Q + 1, p], b[Q + 2, p], b[Q + 3, p], 1)
    else:  # the loop knows axis != 1: no call in it
        for p in range(m):
            y[p] = euler_axis(b[Q, p], b[Q + 1, p], b[Q + 2, p], b[Q + 3, p], axis)
    first = n_after == 0
    for p in range(m):
        span = r_fin[lo + p] - y0[lo + p]
        f = (y[p] - y0[lo + p]) / (1.0 if span == 0.0 else span)
        f_prev, ta_prev, err_prev = prev[Previous.fraction, p], prev[Previous.time, p], prev[Previous.error, p]
        tc = first_crossing(acc[Sums.time_constant_s, p], 0.632, f, f_prev, ta, ta_prev, first)
        acc[Sums.time_constant_s, p] = tc
        acc[Sums.t10_s, p] = first_crossing(acc[Sums.t10_s, p], 0.1, f, f_prev, ta, ta_prev, first)
        acc[Sums.t90_s, p] = first_crossing(acc[Sums.t90_s, p], 0.9, f, f_prev, ta, ta_prev, first)
        acc[Sums.max_fraction, p] = max(acc[Sums.max_fraction, p], f)
        if abs(y[p] - r_fin[lo + p]) > band * abs(span):
            last_out[p] = n_after
        elif last_out[p] == n_after - 1 and last_out[p] >= 0:
            # settled: the first sample after the last one outside the band, unless it leaves again
            acc[Sums.settling_time_s, p] = ta
        err = r_fin[lo + p] - y[p]
        if not first:
            d = ta - ta_prev
            acc[Sums.iae, p] += 0.5 * (abs(err) + abs(err_prev)) * d
            acc[Sums.ise, p] += 0.5 * (err ** 2 + err_prev ** 2) * d
            acc[Sums.itae, p] += 0.5 * (ta * abs(err) + ta_prev * abs(err_prev)) * d
        prev[Previous.fraction, p], prev[Previous.time, p], prev[Previous.error, p] = f, ta, err
