"""The sensing loop compiled: the gyro, the star tracker and the MEKF as row kernels over P episodes.

The numba form of :mod:`attitude_sil.core.sensing.models` (:class:`~.models.Gyro`,
:class:`~.models.StarTracker`) and :mod:`attitude_sil.core.sensing.mekf`
(:class:`~.mekf.Mekf`), one episode row at a time, for the batch engine's
compiled loop (issue 44): each kernel does that model's arithmetic for row p,
in its order, on the same counter-based noise streams
(:func:`attitude_sil.core.plant.kernels.normal_draw`, the stream numbers of
:data:`attitude_sil.core.sensing.noise.STREAMS`), so a row equals the numpy
model's episode to rounding (``test/unit/test_sensing_kernels.py``).

What they cover: the gyro's error model without faults, the tracker's
schedule, latency, outages and noise, the filter's propagation, update and
roll-back for a late report, and a report older than the filter keeps
(dropped). Sensor faults (the gyro's modes, a stuck or slow tracker) stay in
the numpy models.

Records: :class:`GyroParams` / :class:`GyroState`, :class:`TrackerParams` /
:class:`TrackerState`, :class:`MekfParams` / :class:`MekfState`, built from the
numpy models by :func:`gyro_record`, :func:`tracker_record` and
:func:`mekf_record`. A state's history rings hold a slot per step (the filter:
its reach + 1 steps; the tracker: its exposures not yet reported).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.plant.kernels import normal_draw
from attitude_sil.core.sensing.noise import STREAM_SHIFT, STREAMS

__all__ = ["GyroParams", "GyroState", "TrackerParams", "TrackerState", "MekfParams", "MekfState", "gyro_record",
           "tracker_record", "mekf_record", "gyro_row", "gyro_reset_row", "tracker_row", "mekf_row",
           "mekf_reset_row"]

_WHITE, _MARKOV, _WALK, _MARKOV0, _TRACKER = (STREAMS[s] * STREAM_SHIFT for s in (
    "gyro_white", "gyro_markov", "gyro_walk", "gyro_markov_init", "star_tracker"))


class GyroParams(NamedTuple):
    """A gyro's error model (:class:`~attitude_sil.core.sensing.models.Gyro`), SI units."""

    C: np.ndarray  # (3, 3) sensor axes: omega_sensor = C omega_true
    bias0: np.ndarray  # (P, 3) constant bias, rad/s
    gm_std: float  # B, the Gauss-Markov bias' steady-state sigma, rad/s
    phi: float  # exp(-dt / tau)
    rw_step: float  # K sqrt(dt), rad/s
    white: float  # N / sqrt(dt), rad/s
    resolution: float  # rad/s, 0: none
    limit: float  # rad/s
    dt: float  # s
    seeds: np.ndarray  # (P,) int64


class GyroState(NamedTuple):
    """Each row's Gauss-Markov and random-walk bias (P, 3) and the attitude of the step before (P, 4)."""

    b_gm: np.ndarray
    b_rw: np.ndarray
    q_last: np.ndarray


@njit(cache=True, inline="always")
def _qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    # Hamilton product (x, y, z, w) of two quaternions given by their components
    return (a3 * b0 + b3 * a0 + a1 * b2 - a2 * b1, a3 * b1 + b3 * a1 + a2 * b0 - a0 * b2,
            a3 * b2 + b3 * a2 + a0 * b1 - a1 * b0, a3 * b3 - a0 * b0 - a1 * b1 - a2 * b2)


@njit(cache=True, inline="always")
def _rotation_vector(x, y, z, w):
    # the rotation vector of a unit quaternion, the short way (quaternion.rotation_vector)
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    s = np.sqrt(x * x + y * y + z * z)
    f = 2.0 / max(w, 1e-300) if s < 1e-12 else 2.0 * np.arctan2(s, w) / s
    return x * f, y * f, z * f


@njit(cache=True)
def gyro_reset_row(p, par, st):
    """Row ``p`` at step 0: the Gauss-Markov bias from its steady state, the random walk at zero."""
    for i in range(3):
        st.b_gm[p, i] = par.gm_std * normal_draw(par.seeds[p] + _MARKOV0, 0, i)
        st.b_rw[p, i] = 0.0


@njit(cache=True)
def gyro_row(p, k, q, omega, par, st, out):
    """Row ``p``'s reading ``out[p]`` (rad/s) at step ``k`` of the true attitude ``q[p]`` and rate ``omega[p]``
    (the mean rate over [t_(k-1), t_k] from the attitudes at both ends; the rate itself at k = 0); then its
    biases move to step k + 1 (:meth:`attitude_sil.core.sensing.models.Gyro.sample`)."""
    if k == 0:
        w0, w1, w2 = omega[p, 0], omega[p, 1], omega[p, 2]
    else:
        a = st.q_last[p]
        d = _qmul(-a[0], -a[1], -a[2], a[3], q[p, 0], q[p, 1], q[p, 2], q[p, 3])
        w0, w1, w2 = _rotation_vector(d[0], d[1], d[2], d[3])
        w0, w1, w2 = w0 / par.dt, w1 / par.dt, w2 / par.dt
    for i in range(4):
        st.q_last[p, i] = q[p, i]
    seed = par.seeds[p]
    for i in range(3):
        v = w0 * par.C[i, 0] + w1 * par.C[i, 1] + w2 * par.C[i, 2]
        v = v + (par.bias0[p, i] + st.b_gm[p, i] + st.b_rw[p, i])
        if par.white > 0.0:
            v = v + par.white * normal_draw(seed + _WHITE, k, i)
        if par.resolution > 0.0:
            v = np.round(v / par.resolution) * par.resolution
        out[p, i] = min(max(v, -par.limit), par.limit)
        if par.gm_std > 0.0:
            st.b_gm[p, i] = par.phi * st.b_gm[p, i] + par.gm_std * np.sqrt(1.0 - par.phi**2) * normal_draw(
                seed + _MARKOV, k, i)
        if par.rw_step > 0.0:
            st.b_rw[p, i] = st.b_rw[p, i] + par.rw_step * normal_draw(seed + _WALK, k, i)


def gyro_record(gyro) -> tuple[GyroParams, GyroState]:
    """The kernels' record of a numpy :class:`~attitude_sil.core.sensing.models.Gyro` at step 0."""
    e, P = gyro.errors, gyro.n_episodes
    par = GyroParams(np.ascontiguousarray(gyro.C), np.ascontiguousarray(np.broadcast_to(e.bias, (P, 3)),
                                                                          dtype=float),
                     float(e.bias_instability), float(gyro.phi), float(e.rrw * np.sqrt(gyro.dt)),
                     float(e.white_std(gyro.dt)) if e.arw > 0.0 else 0.0, float(e.resolution), float(e.range),
                     float(gyro.dt), np.ascontiguousarray(gyro.seeds))
    st = GyroState(np.zeros((P, 3)), np.zeros((P, 3)), np.zeros((P, 4)))
    for p in range(P):
        gyro_reset_row(p, par, st)
    return par, st


class TrackerParams(NamedTuple):
    """A star tracker's schedule, outages and noise (:class:`~attitude_sil.core.sensing.models.StarTracker`)."""

    period: int  # steps between exposures
    latency: int  # steps from exposure to report
    outages: np.ndarray  # (n, 2) exposure-time windows [start, end), s
    sigma: np.ndarray  # (3,) 1-sigma per body axis, rad
    dt: float
    seeds: np.ndarray  # (P,) int64


class TrackerState(NamedTuple):
    """The true attitude of each exposure not yet reported: a ring (P, slots, 4) by exposure number."""

    ring: np.ndarray


@njit(cache=True)
def tracker_row(p, k, q, par, st, q_meas):
    """Row ``p`` at step ``k``: keep the true attitude ``q[p]`` of an exposure; return the report due now as
    its exposure step (-1: none) and whether it holds an attitude (``q_meas[p]``: the measured one) or not
    (an outage)."""
    slots = st.ring.shape[1]
    if k % par.period == 0:
        for i in range(4):
            st.ring[p, (k // par.period) % slots, i] = q[p, i]
    j = k - par.latency
    if j < 0 or j % par.period != 0:
        return -1, False
    t = j * par.dt
    for w in range(par.outages.shape[0]):
        if par.outages[w, 0] - 1e-9 <= t < par.outages[w, 1] - 1e-9:
            return j, False
    d = np.empty(3)
    for i in range(3):
        d[i] = 0.5 * (normal_draw(par.seeds[p] + _TRACKER, j, i) * par.sigma[i])
    n = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + 1.0)
    a = st.ring[p, (j // par.period) % slots]
    m = _qmul(a[0], a[1], a[2], a[3], d[0] / n, d[1] / n, d[2] / n, 1.0 / n)
    n = np.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2] + m[3] * m[3])
    for i in range(4):
        q_meas[p, i] = m[i] / n
    return j, True


def tracker_record(tracker) -> tuple[TrackerParams, TrackerState]:
    """The kernels' record of a numpy :class:`~attitude_sil.core.sensing.models.StarTracker` at step 0 (no
    faults: a stuck or slow tracker stays in the numpy model)."""
    s = tracker.schedule
    par = TrackerParams(int(s.period_steps), int(s.latency_steps),
                        np.array(tracker.errors.outages, dtype=float).reshape(-1, 2), np.asarray(
                            tracker.errors.sigma_B, dtype=float), float(tracker.dt),
                        np.ascontiguousarray(tracker.seeds))
    return par, TrackerState(np.zeros((tracker.seeds.shape[0], s.latency_steps // s.period_steps + 2, 4)))


class MekfParams(NamedTuple):
    """The filter's constants (:class:`~attitude_sil.core.sensing.mekf.Mekf`)."""

    dt: float
    Q: np.ndarray  # (6, 6) process noise of a step
    R: np.ndarray  # (3, 3) the tracker's noise
    reach: int  # steps a report may reach back


class MekfState(NamedTuple):
    """Each row's estimate (q (P, 4), b (P, 3), covariance (P, 6, 6)), the ring of its priors and gyro
    readings over the last reach + 1 steps, and the reports it dropped (P,)."""

    q: np.ndarray
    b: np.ndarray
    cov: np.ndarray
    hq: np.ndarray  # (P, H, 4)
    hb: np.ndarray  # (P, H, 3)
    hcov: np.ndarray  # (P, H, 6, 6)
    hw: np.ndarray  # (P, H, 3)
    dropped: np.ndarray  # (P,) int64, per row (the numpy filter counts a step's report once for its P rows)
    work: np.ndarray  # (3, 6, 6) scratch of an update (one thread's: rows run one after another)
    small: np.ndarray  # (5, 3, 3) scratch of a propagation (likewise)


@njit(cache=True, inline="always")
def _product(a, b, out, transpose_b):
    # out = a @ b (or a @ b.T), 6x6, into a scratch slice: no allocation in the step
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for m in range(6):
                acc += a[i, m] * (b[j, m] if transpose_b else b[m, j])
            out[i, j] = acc


@njit(cache=True)
def _propagate(Qa, Ba, Ca, p, m0, m1, m2, par, sm):
    # Mekf._propagate on row p of the estimate (q Qa (P, 4), b Ba (P, 3), covariance Ca (P, 6, 6)), in place,
    # on the gyro reading (m0, m1, m2): the attitude on the bias-corrected reading, the covariance through the
    # closed-form transition (mekf.transition) plus Q. Indexed, not sliced: a view costs reference counts.
    # Phi = [[F, G], [0, I]] on P = [[A, B], [B^T, D]]: Phi P Phi^T = [[X F^T + Y G^T, Y], [Y^T, D]] with
    # X = F A + G B^T, Y = F B + G D (sm (5, 3, 3): F, G, X, Y, M); then + Q and the symmetric part
    dt = par.dt
    w0, w1, w2 = m0 - Ba[p, 0], m1 - Ba[p, 1], m2 - Ba[p, 2]
    t0, t1, t2 = w0 * dt, w1 * dt, w2 * dt
    angle = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    sc = 0.5 - angle * angle / 48.0 if angle < 1e-4 else np.sin(0.5 * angle) / angle
    r = _qmul(Qa[p, 0], Qa[p, 1], Qa[p, 2], Qa[p, 3], t0 * sc, t1 * sc, t2 * sc, np.cos(0.5 * angle))
    n = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3])
    for i in range(4):
        Qa[p, i] = r[i] / n
    nw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    t = nw * dt
    if t < 1e-3:
        c1 = dt - nw**2 * dt**3 / 6.0
        c2 = dt**2 / 2.0 - nw**2 * dt**4 / 24.0
        c3 = dt**3 / 6.0 - nw**2 * dt**5 / 120.0
    else:
        c1, c2, c3 = np.sin(t) / nw, (1.0 - np.cos(t)) / nw**2, (t - np.sin(t)) / nw**3
    W = ((0.0, -w2, w1), (w2, 0.0, -w0), (-w1, w0, 0.0))
    for i in range(3):
        for j in range(3):
            e = 1.0 if i == j else 0.0
            w2ij = W[i][0] * W[0][j] + W[i][1] * W[1][j] + W[i][2] * W[2][j]
            sm[0, i, j] = e - c1 * W[i][j] + c2 * w2ij
            sm[1, i, j] = -(e * dt - c2 * W[i][j] + c3 * w2ij)
    for i in range(3):
        for j in range(3):
            x = 0.0
            y = 0.0
            for m in range(3):
                x += sm[0, i, m] * Ca[p, m, j] + sm[1, i, m] * Ca[p, 3 + m, j]
                y += sm[0, i, m] * Ca[p, m, 3 + j] + sm[1, i, m] * Ca[p, 3 + m, 3 + j]
            sm[2, i, j] = x
            sm[3, i, j] = y
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for m in range(3):
                acc += sm[2, i, m] * sm[0, j, m] + sm[3, i, m] * sm[1, j, m]
            sm[4, i, j] = acc + par.Q[i, j]
    for i in range(3):
        for j in range(3):
            Ca[p, i, j] = 0.5 * (sm[4, i, j] + sm[4, j, i])
            Ca[p, i, 3 + j] = sm[3, i, j] + par.Q[i, 3 + j]
            Ca[p, 3 + j, i] = Ca[p, i, 3 + j]
            Ca[p, 3 + i, 3 + j] += par.Q[3 + i, 3 + j]


@njit(cache=True, inline="always")
def _keep(st, p, s, w0, w1, w2):
    # the estimate of row p into ring slot s, with the gyro reading it was propagated on
    for i in range(4):
        st.hq[p, s, i] = st.q[p, i]
    for i in range(3):
        st.hb[p, s, i] = st.b[p, i]
    for i in range(6):
        for j in range(6):
            st.hcov[p, s, i, j] = st.cov[p, i, j]
    st.hw[p, s, 0], st.hw[p, s, 1], st.hw[p, s, 2] = w0, w1, w2


@njit(cache=True)
def _update(q, b, cov, q_meas, par, work):
    # Mekf._update on one row, in place: the residual rotation, the Kalman gain (H = [I 0]), Joseph form;
    # ``work`` (3, 6, 6) scratch
    d = _qmul(-q[0], -q[1], -q[2], q[3], q_meas[0], q_meas[1], q_meas[2], q_meas[3])
    sign = -2.0 if d[3] < 0.0 else 2.0
    z0, z1, z2 = sign * d[0], sign * d[1], sign * d[2]
    s00, s01, s02 = cov[0, 0] + par.R[0, 0], cov[0, 1] + par.R[0, 1], cov[0, 2] + par.R[0, 2]
    s11, s12, s22 = cov[1, 1] + par.R[1, 1], cov[1, 2] + par.R[1, 2], cov[2, 2] + par.R[2, 2]
    a00, a01, a02 = s11 * s22 - s12 * s12, s02 * s12 - s01 * s22, s01 * s12 - s02 * s11  # S^-1 det(S), symmetric
    a11, a12, a22 = s00 * s22 - s02 * s02, s01 * s02 - s00 * s12, s00 * s11 - s01 * s01
    det = s00 * a00 + s01 * a01 + s02 * a02
    inv = ((a00 / det, a01 / det, a02 / det), (a01 / det, a11 / det, a12 / det), (a02 / det, a12 / det, a22 / det))
    ikh, kr = work[0], work[1]
    dx = np.zeros(6)
    for i in range(6):
        for j in range(6):
            ikh[i, j] = 1.0 if i == j else 0.0
        for j in range(3):
            kij = cov[i, 0] * inv[0][j] + cov[i, 1] * inv[1][j] + cov[i, 2] * inv[2][j]  # K = P H^T S^-1
            ikh[i, j] -= kij
            kr[i, j] = kij
        dx[i] = kr[i, 0] * z0 + kr[i, 1] * z1 + kr[i, 2] * z2
    _product(ikh, cov, work[2], False)
    _product(work[2], ikh, cov, True)  # (I - K H) P (I - K H)^T
    for i in range(6):  # + K R K^T
        for j in range(6):
            acc = 0.0
            for m in range(3):
                for n in range(3):
                    acc += kr[i, m] * par.R[m, n] * kr[j, n]
            work[2, i, j] = cov[i, j] + acc
    for i in range(6):
        for j in range(6):
            cov[i, j] = 0.5 * (work[2, i, j] + work[2, j, i])
    h0, h1, h2 = 0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2]
    n = np.sqrt(h0 * h0 + h1 * h1 + h2 * h2 + 1.0)
    r = _qmul(q[0], q[1], q[2], q[3], h0 / n, h1 / n, h2 / n, 1.0 / n)
    n = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3])
    for i in range(4):
        q[i] = r[i] / n
    for i in range(3):
        b[i] += dx[3 + i]


@njit(cache=True)
def mekf_reset_row(p, q0, cov0, st):
    """Row ``p`` at step 0: the initial estimate ``q0`` (4,) (normalised), zero bias, covariance ``cov0``."""
    n = np.sqrt(q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] + q0[3] * q0[3])
    for i in range(4):
        st.q[p, i] = q0[i] / n
    st.b[p, :] = 0.0
    st.cov[p] = cov0
    st.dropped[p] = 0


@njit(cache=True)
def mekf_row(p, k, w_meas, j, valid, q_meas, par, st):
    """Row ``p`` at step ``k`` (:meth:`attitude_sil.core.sensing.mekf.Mekf.step`): propagate on the gyro
    reading ``w_meas[p]``, take the report of exposure step ``j`` (-1: none; ``valid``: it holds the attitude
    ``q_meas[p]``), rolling back to it when it is late and within the reach; the estimate is ``st.q[p]``,
    ``st.b[p]``, ``st.cov[p]`` (the rate: ``w_meas[p] - st.b[p]``)."""
    H = st.hq.shape[1]
    if valid and j > k:
        raise ValueError("a star tracker report of an exposure after its step")
    if k > 0:
        _propagate(st.q, st.b, st.cov, p, w_meas[p, 0], w_meas[p, 1], w_meas[p, 2], par, st.small)
    _keep(st, p, k % H, w_meas[p, 0], w_meas[p, 1], w_meas[p, 2])
    if j < 0 or not valid:
        return
    if j < k - par.reach:
        st.dropped[p] += 1
        return
    s = j % H
    st.q[p], st.b[p], st.cov[p] = st.hq[p, s], st.hb[p, s], st.hcov[p, s]
    _update(st.q[p], st.b[p], st.cov[p], q_meas[p], par, st.work)
    _keep(st, p, s, st.hw[p, s, 0], st.hw[p, s, 1], st.hw[p, s, 2])
    for i in range(j + 1, k + 1):
        s = i % H
        _propagate(st.q, st.b, st.cov, p, st.hw[p, s, 0], st.hw[p, s, 1], st.hw[p, s, 2], par, st.small)
        _keep(st, p, s, st.hw[p, s, 0], st.hw[p, s, 1], st.hw[p, s, 2])


def mekf_record(mekf) -> tuple[MekfParams, MekfState]:
    """The kernels' record of a numpy :class:`~attitude_sil.core.sensing.mekf.Mekf` at step 0."""
    P, H = mekf.n, mekf.latency_steps + 1
    par = MekfParams(float(mekf.dt), np.ascontiguousarray(mekf.Q), np.ascontiguousarray(mekf.R),
                     int(mekf.latency_steps))
    st = MekfState(np.zeros((P, 4)), np.zeros((P, 3)), np.zeros((P, 6, 6)), np.zeros((P, H, 4)),
                   np.zeros((P, H, 3)), np.zeros((P, H, 6, 6)), np.zeros((P, H, 3)), np.zeros(P, dtype=np.int64),
                   np.zeros((3, 6, 6)), np.zeros((5, 3, 3)))
    q0 = np.broadcast_to(mekf.s.initial_q_BN, (P, 4))
    cov0 = np.diag([mekf.s.initial_attitude_sigma**2] * 3 + [mekf.s.initial_bias_sigma**2] * 3)
    for p in range(P):
        mekf_reset_row(p, np.ascontiguousarray(q0[p], dtype=float), cov0, st)
    return par, st
