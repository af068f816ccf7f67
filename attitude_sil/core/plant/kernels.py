"""Compiled steps of the plant over P episodes in row-major arrays, for the nodes and the stepwise driver.

A step written as numpy calls is hundreds of small calls whose overhead, not
their arithmetic, sets the speed. These kernels do the
same arithmetic as the documented equations in one compiled call. The body
and the wheels copy their rows into lanes and run the stages of
:mod:`attitude_sil.core.plant.lanes`, which the batch engine runs on its
blocks of episodes, so graph and batch stay bit-identical.
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

from attitude_sil.core.plant.lanes import (
    BODY_ROWS,
    TC,
    TE,
    H,
    Q,
    U,
    W,
    body_block,
    lanes_to_rows,
    lanes_to_wheels,
    motor_lanes,
    rk4_body_lanes,
    rows_to_lanes,
    wheel_lanes,
    wheels_to_lanes,
)

__all__ = ["rk4_body", "wheel_step", "WheelParams", "WheelFailure", "measure", "expm_small"]


@njit(cache=True, error_model="numpy")
def rk4_body(q, w, h, inertia, inertia_inv, tau_c, tau_e, dt, substeps):
    """RK4 over one held interval for every episode; returns new (q, w, h) arrays.

    Shapes: q (P, 4), w and h (P, 3), inertia and inertia_inv (P, 3, 3),
    tau_c and tau_e (P, 3). The quaternion is renormalised at the end. The
    rows go into a block and through :func:`attitude_sil.core.plant.lanes.rk4_body_lanes`,
    the batch engine's own code.
    """
    m = q.shape[0]
    b = body_block(q, w, inertia, inertia_inv, 0, m)
    rows_to_lanes(h, 0, b, H, m)
    rows_to_lanes(tau_c, 0, b, TC, m)
    rows_to_lanes(tau_e, 0, b, TE, m)
    rk4_body_lanes(m, b, dt, substeps)
    qo, wo, ho = np.empty_like(q), np.empty_like(w), np.empty_like(h)
    lanes_to_rows(b, Q, qo)
    lanes_to_rows(b, W, wo)
    lanes_to_rows(b, H, ho)
    return qo, wo, ho


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
    null: np.ndarray  # (n,) unit null vector of the allocated wheels' axes (zeros: none), for speed management
    null_tau: float  # time constant of the null-space speed loop, s (0: off)
    null_target: float  # target of the wheel speeds' component along ``null``, rad/s
    realloc: np.ndarray  # (n, n, 3) the allocation once wheel f failed: over the others (ideal isolation)
    reallocate: bool  # a failed wheel is dropped from the allocation at its failure's step


class WheelFailure(NamedTuple):
    """Wheel failures per episode (F = 1 for all, or P rows): which wheel (-1: none), from which step, how;
    and which wheel the allocation leaves out (``WheelParams.reallocate``), from which step.

    A stuck drive holds the voltage of the step before the failure, which
    ``e_hold`` keeps (state, updated until the failure); a lost wheel (open
    circuit) coasts; a torque-limited drive makes at most ``value`` N m (its
    current limit lowered), a speed-limited one no longer drives beyond
    ``value`` rad/s; a wheel whose bearing's viscous friction grew ``value``
    times steps with the motor transition ``phi``, ``gamma`` of that friction
    (a large factor seizes it). The wheel isolated is the failed one from its failure's
    step under ideal isolation, or the one the drive's FDIR isolates, from the
    step it does (:mod:`attitude_sil.core.plant.fdir`, which writes it: state).
    """

    wheel: np.ndarray  # (F,) int64
    step: np.ndarray  # (F,) int64
    mode: np.ndarray  # (F,) int64, WHEEL_FAILURE_MODES' code
    value: np.ndarray  # (F,) N m (torque_limit), rad/s (speed_limit) or the friction factor (friction)
    e_hold: np.ndarray  # (F,) V
    isolated: np.ndarray  # (F,) int64, -1: none
    isolated_step: np.ndarray  # (F,) int64
    phi: np.ndarray  # (F or 1, 3, 3) the friction fault's motor transition, x_next = x @ phi + e gamma
    gamma: np.ndarray  # (F or 1, 3)


@njit(cache=True)
def wheel_params_copy(wp):
    """A private copy of every array of a :class:`WheelParams` (threads sharing one would fight over its
    reference count)."""
    return WheelParams(wp.allocation.copy(), wp.axes.copy(), wp.phi_T.copy(), wp.gamma.copy(), wp.k_b.copy(),
                       wp.headroom.copy(), wp.k_i.copy(), wp.r_a.copy(), wp.coast.copy(), wp.j_m, wp.b_m,
                       wp.speed_max, wp.v_max, wp.dt, wp.null.copy(), wp.null_tau, wp.null_target,
                       wp.realloc.copy(), wp.reallocate)


@njit(cache=True, error_model="numpy")
def wheel_step(x, v_cmd, k, torque_mode, wp, fail, w_cmd):
    """Drive limits, exact motor step and mean body torque for every episode at step ``k``.

    Shapes: x (P, n, 3) wheel state (angle, current, speed) at t_k, v_cmd (P, 3)
    body-axis voltage (or, with ``torque_mode``, body torque in N m), or with
    ``w_cmd`` (P, n) each wheel's motor torque command (N m; (0, n): none); ``wp`` a
    :class:`WheelParams`, ``fail`` a :class:`WheelFailure`. Returns (x_next,
    tau_c (P, 3), h_start (P, 3)); see ``wheels.WheelAssembly`` for the rules.
    The rows go into a block and through :func:`attitude_sil.core.plant.lanes.wheel_lanes`,
    the batch engine's own code.
    """
    m = x.shape[0]
    xw, xn, b = np.empty((x.shape[1], 3, m)), np.empty((x.shape[1], 3, m)), np.zeros((BODY_ROWS, m))
    wheels_to_lanes(x, 0, xw)
    rows_to_lanes(v_cmd, 0, b, U, m)
    wcmd = np.ascontiguousarray(w_cmd.T)  # (n, P), episodes last as the lanes are
    wheel_lanes(m, 0, k, xw, xn, b, motor_lanes(wp, 0, m), np.full(m, torque_mode), wp, fail, wcmd)
    x_next, tau_c, h_start = np.empty_like(x), np.empty((m, 3)), np.empty((m, 3))
    lanes_to_wheels(xn, x_next)
    lanes_to_rows(b, TC, tau_c)
    lanes_to_rows(b, H, h_start)
    return x_next, tau_c, h_start


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
