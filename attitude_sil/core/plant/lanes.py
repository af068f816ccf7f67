"""The plant's step on a block of episodes with the episodes as the vector axis: the physics' one home.

A block holds m episodes. Each quantity of the block is one row of a 2-D
array whose columns are the episodes (structure of arrays): row ``Q`` of the
body block is the x part of every episode's attitude, ``Q + 3`` the scalar
part. Each stage of the step is a short loop over the columns with
straight-line arithmetic inside: the shape the compiler turns into packed
instructions (as many doubles per instruction as the CPU's vector width holds). What bench/README.md measured
on the way, and what these functions therefore keep to:

* one 2-D array per block, not a 1-D array per quantity: every array an
  inlined helper takes costs two reference-count calls per call, which at
  m = 1 made the body's RK4 ten times slower;
* few rows written per loop: LLVM vectorises a loop only after checking at
  run time that the rows it writes do not overlap those it reads, and gives
  up when there are too many pairs to check (one loop for the body's
  derivatives stayed scalar; three loops vectorise);
* every stage inlined (``inline="always"``) into the compiled function that
  runs the episodes.

* :func:`rk4_body_lanes`: RK4 of paper 000 eq. 3, 4, 10-11 (``rigid_body``)
  over one held interval;
* :func:`wheel_lanes`: the reaction-wheel motors over one control period:
  the drive limits, the exact motor step and the mean torque on the body
  (``wheels.WheelAssembly``);
* :func:`rows_to_lanes` & co.: copies between a block and the row-major
  (P, width) arrays the rest of the package uses; :func:`column_major`: the
  laws' (m, width) arrays in the batch engine, episodes contiguous.

The batch engine's chunk (:mod:`attitude_sil.core.sim.batch_loop`) keeps the
plant state in a block for a whole episode; the row kernels the nodes and
the stepwise driver call (:mod:`attitude_sil.core.plant.kernels`) copy their
rows into a block and run the same stages, so every driver computes with
this one code, in the same order, and graph == batch holds to the last bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["BODY_ROWS", "MOTOR_ROWS", "ANGLE", "CURRENT", "SPEED",
           "Q", "W", "H", "TC", "TE", "II", "IV", "U", "rk4_body_lanes", "wheel_lanes",
           "motor_lanes", "body_block", "rows_to_lanes", "lanes_to_rows", "mat_to_lanes", "wheels_to_lanes",
           "lanes_to_wheels", "copy_wheels", "column_major"]

# ---------------------------------------------------------------- the body block's rows
#: q_BN (x, y, z, w), omega_BN_B (rad/s), h_wheels_B (N m s), tau_c_B and tau_ext_B (N m)
Q, W, H, TC, TE = 0, 4, 7, 10, 13
#: inertia (kg m^2) and its inverse, row-major; the command (V or N m)
II, IV, U = 16, 25, 34
#: RK4 scratch: the four stages' derivatives, the stage state, I w + h
K1Q, K1W, K2Q, K2W, K3Q, K3W, K4Q, K4W = 37, 41, 44, 48, 51, 55, 58, 62
TQ, TW, TH, BIG_H = 65, 69, 72, 75
BODY_ROWS = 78

# ---------------------------------------------------------------- a wheel's state (n, 3, m), (P, n, 3)
#: the motor state's components: rotor angle rad, armature current A, rotor speed rad/s
ANGLE, CURRENT, SPEED = 0, 1, 2

# ---------------------------------------------------------------- the motor block's rows
#: each episode's motor: phi_T (row-major), gamma, K_b, K_i, R_a i_max, R_a; scratch: the drive voltage,
#: a lost wheel (1.0)
PHI, GAMMA, KB, KI, HEAD, RA, E, LOST = 0, 9, 12, 13, 14, 15, 16, 17
MOTOR_ROWS = 18
#: the modes of a wheel failure (:data:`attitude_sil.core.faults.CATALOGUE`'s wheel modes but friction), by code
#: (``WheelFailure.mode``)
WHEEL_FAILURE_MODES = ("lost", "stuck", "torque_limit", "speed_limit", "friction")
FAIL_LOST, FAIL_STUCK, FAIL_TORQUE_LIMIT, FAIL_SPEED_LIMIT, FAIL_FRICTION = 0, 1, 2, 3, 4


# ---------------------------------------------------------------- copies
@njit(cache=True, inline="always")
def column_major(a, lo, m):
    """Rows lo..lo+m-1 of ``a`` (P, width) as a new (m, width) array in column-major order.

    The layout of the laws' arrays in the batch engine: indexed ``[p, i]`` as
    everywhere, but a column's episodes are contiguous, so a loop over the
    episodes reads and writes them as packed vectors.
    """
    out = np.empty((a.shape[1], m)).T
    for i in range(a.shape[1]):
        for p in range(m):
            out[p, i] = a[lo + p, i]
    return out


@njit(cache=True, inline="always")
def rows_to_lanes(a, lo, block, row, m):
    """Rows lo..lo+m-1 of ``a`` (P, width) into rows ``row..row+width-1`` of ``block``."""
    for i in range(a.shape[1]):
        for p in range(m):
            block[row + i, p] = a[lo + p, i]


@njit(cache=True, inline="always")
def lanes_to_rows(block, row, a):
    """Rows ``row..row+width-1`` of ``block`` into rows 0..m-1 of ``a`` (m, width)."""
    for i in range(a.shape[1]):
        for p in range(a.shape[0]):
            a[p, i] = block[row + i, p]


@njit(cache=True, inline="always")
def mat_to_lanes(a, lo, block, row, m):
    """Rows lo.. of a (P, 3, 3) (or one (1, 3, 3) for all) into 9 rows of ``block`` from ``row``, row-major."""
    one = a.shape[0] == 1
    for i in range(9):
        for p in range(m):
            block[row + i, p] = a[0 if one else lo + p, i // 3, i % 3]


@njit(cache=True, inline="always")
def wheels_to_lanes(x, lo, xw):
    """Rows lo..lo+m-1 of the wheel state x (P, n, 3) into xw (n, 3, m), the episodes last."""
    for j in range(xw.shape[0]):
        for r in range(3):
            for p in range(xw.shape[2]):
                xw[j, r, p] = x[lo + p, j, r]


@njit(cache=True, inline="always")
def lanes_to_wheels(xw, x):
    """xw (n, 3, m) into rows 0..m-1 of x (m, n, 3)."""
    for p in range(xw.shape[2]):
        for j in range(xw.shape[0]):
            for r in range(3):
                x[p, j, r] = xw[j, r, p]


@njit(cache=True, inline="always")
def copy_wheels(src, dst):
    """The wheel states src (n, 3, m) into dst, in plain loops (a slice assignment takes numpy's general path)."""
    for j in range(src.shape[0]):
        for r in range(3):
            for p in range(src.shape[2]):
                dst[j, r, p] = src[j, r, p]


@njit(cache=True, inline="always")
def body_block(q, w, inertia, inertia_inv, lo, m):
    """A new body block (BODY_ROWS, m) holding rows lo..lo+m-1 of q_BN (P, 4), omega_BN_B (P, 3) and the
    inertia and its inverse (P, 3, 3); every other row zero."""
    b = np.zeros((BODY_ROWS, m))
    rows_to_lanes(q, lo, b, Q, m)
    rows_to_lanes(w, lo, b, W, m)
    mat_to_lanes(inertia, lo, b, II, m)
    mat_to_lanes(inertia_inv, lo, b, IV, m)
    return b


@njit(cache=True, inline="always")
def motor_lanes(wp, lo, m):
    """The motor block (MOTOR_ROWS, m): each episode's constants of a ``kernels.WheelParams`` (M = 1 or P)."""
    block = np.zeros((MOTOR_ROWS, m))
    mat_to_lanes(wp.phi_T, lo, block, PHI, m)
    one = wp.phi_T.shape[0] == 1
    for p in range(m):
        pm = 0 if one else lo + p
        block[KB, p], block[KI, p], block[HEAD, p], block[RA, p] = wp.k_b[pm], wp.k_i[pm], wp.headroom[pm], wp.r_a[pm]
        for i in range(3):
            block[GAMMA + i, p] = wp.gamma[pm, i]
    return block


# ---------------------------------------------------------------- the body
@njit(cache=True, inline="always")
def _deriv(m, b, q, w, h, dq, dw):
    # the body's derivatives at the state in rows q, w, h of block b into rows dq, dw:
    # w' = I^-1 (-w x (I w + h) + tau_c + tau_e), q' = 1/2 Omega(w) q (x, y, z, w order); h' = -tau_c is not
    # stored (the stages use -TC). Three loops, each writing few rows (module docstring)
    for p in range(m):
        w0, w1, w2 = b[w, p], b[w + 1, p], b[w + 2, p]
        b[BIG_H, p] = b[II, p] * w0 + b[II + 1, p] * w1 + b[II + 2, p] * w2 + b[h, p]
        b[BIG_H + 1, p] = b[II + 3, p] * w0 + b[II + 4, p] * w1 + b[II + 5, p] * w2 + b[h + 1, p]
        b[BIG_H + 2, p] = b[II + 6, p] * w0 + b[II + 7, p] * w1 + b[II + 8, p] * w2 + b[h + 2, p]
    for p in range(m):
        w0, w1, w2 = b[w, p], b[w + 1, p], b[w + 2, p]
        g0, g1, g2 = b[BIG_H, p], b[BIG_H + 1, p], b[BIG_H + 2, p]
        rx = -(w1 * g2 - w2 * g1) + b[TC, p] + b[TE, p]
        ry = -(w2 * g0 - w0 * g2) + b[TC + 1, p] + b[TE + 1, p]
        rz = -(w0 * g1 - w1 * g0) + b[TC + 2, p] + b[TE + 2, p]
        b[dw, p] = b[IV, p] * rx + b[IV + 1, p] * ry + b[IV + 2, p] * rz
        b[dw + 1, p] = b[IV + 3, p] * rx + b[IV + 4, p] * ry + b[IV + 5, p] * rz
        b[dw + 2, p] = b[IV + 6, p] * rx + b[IV + 7, p] * ry + b[IV + 8, p] * rz
    for p in range(m):
        x, y, z, s = b[q, p], b[q + 1, p], b[q + 2, p], b[q + 3, p]
        w0, w1, w2 = b[w, p], b[w + 1, p], b[w + 2, p]
        b[dq, p] = 0.5 * (w2 * y - w1 * z + w0 * s)
        b[dq + 1, p] = 0.5 * (-w2 * x + w0 * z + w1 * s)
        b[dq + 2, p] = 0.5 * (w1 * x - w0 * y + w2 * s)
        b[dq + 3, p] = 0.5 * (-w0 * x - w1 * y - w2 * z)


@njit(cache=True, inline="always")
def _stage(m, b, kq, kw, a):
    # the RK4 intermediate state (TQ, TW, TH) = (Q, W, H) + a k, one row at a time
    for i in range(4):
        for p in range(m):
            b[TQ + i, p] = b[Q + i, p] + a * b[kq + i, p]
    for i in range(3):
        for p in range(m):
            b[TW + i, p] = b[W + i, p] + a * b[kw + i, p]
        for p in range(m):
            b[TH + i, p] = b[H + i, p] + a * -b[TC + i, p]


@njit(cache=True, inline="always")
def rk4_body_lanes(m, b, dt, substeps):
    """RK4 over one held interval for the m episodes of the body block ``b`` (BODY_ROWS, >= m), in place.

    Reads the attitude q_BN (rows ``Q``), rate omega_BN_B (``W``, rad/s),
    wheel momentum h_wheels_B (``H``, N m s), the torques held over the
    interval (``TC``, ``TE``, N m) and the inertia and its inverse (``II``,
    ``IV``, kg m^2, row-major); writes the state at the interval's end into
    ``Q``, ``W``, ``H``, the quaternion renormalised. ``dt`` (s) is split into
    ``substeps`` equal RK4 steps.
    """
    step = dt / substeps
    half = 0.5 * step
    sixth = step / 6.0
    for _ in range(substeps):
        _deriv(m, b, Q, W, H, K1Q, K1W)
        _stage(m, b, K1Q, K1W, half)
        _deriv(m, b, TQ, TW, TH, K2Q, K2W)
        _stage(m, b, K2Q, K2W, half)
        _deriv(m, b, TQ, TW, TH, K3Q, K3W)
        _stage(m, b, K3Q, K3W, step)
        _deriv(m, b, TQ, TW, TH, K4Q, K4W)
        for i in range(4):
            for p in range(m):
                b[Q + i, p] = b[Q + i, p] + sixth * (b[K1Q + i, p] + 2.0 * (b[K2Q + i, p] + b[K3Q + i, p])
                                                     + b[K4Q + i, p])
        for i in range(3):
            for p in range(m):
                b[W + i, p] = b[W + i, p] + sixth * (b[K1W + i, p] + 2.0 * (b[K2W + i, p] + b[K3W + i, p])
                                                     + b[K4W + i, p])
            for p in range(m):
                d = -b[TC + i, p]  # every stage's h' is -tau_c
                b[H + i, p] = b[H + i, p] + sixth * (d + 2.0 * (d + d) + d)
    for p in range(m):
        q0, q1, q2, q3 = b[Q, p], b[Q + 1, p], b[Q + 2, p], b[Q + 3, p]
        norm = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        b[Q, p] = q0 / norm
        b[Q + 1, p] = q1 / norm
        b[Q + 2, p] = q2 / norm
        b[Q + 3, p] = q3 / norm


# ---------------------------------------------------------------- the wheels
@njit(cache=True, inline="always")
def _null_speed(xw, p, wp):
    # the wheel speeds' component along the unit null vector n of episode p, s = n . omega_w, rad/s
    s = 0.0
    for i in range(xw.shape[0]):
        s += wp.null[i] * xw[i, SPEED, p]
    return s


@njit(cache=True, inline="always")
def _null_volts(s, wp, k_b, k_i, r_a):
    # the null-space speed loop's voltage along n for a voltage command: s is driven to its target s* as a first
    # order of time constant tau (L/R neglected): J s' = K_i i - B s, R i = e - K_b s, e = (K_b + R B / K_i) s*
    # + k_v (s* - s) gives J s' = (K_i (K_b + k_v) / R + B) (s* - s), so k_v = R J / (K_i tau) - K_b - R B / K_i.
    # (A torque command adds J (s* - s) / tau as wheel torque instead: the inverse motor model compensates the
    # back-EMF and the friction.) Along n the wheels make no body torque
    target, friction = wp.null_target, r_a * wp.b_m / k_i
    k_v = r_a * wp.j_m / (k_i * wp.null_tau) - k_b - friction
    return (k_b + friction) * target + k_v * (target - s)


@njit(cache=True, inline="always")
def _drive(m, j, xw, b, mot, torque, wp, fail, lo, k, reallocate, wcmd):
    # wheel j's drive voltage per episode into row E of the motor block: its own motor torque command where
    # ``wcmd`` (n, m) has rows (a per-wheel command: the inverse motor model, no allocation, no null-space loop),
    # else the allocation (eq. 14; with
    # ``reallocate``, over the wheels left once a wheel failed: ideal isolation), the inverse motor model in
    # torque mode, the null-space speed loop (not once a wheel is dropped), the driver's current headroom around
    # the back-EMF, no drive beyond the speed limit, the bus voltage
    b_m, speed_max, v_max = wp.b_m, wp.speed_max, wp.v_max
    n_j, tau_n = wp.null[j], wp.null_tau
    one = fail.isolated.shape[0] == 1
    per_wheel = wcmd.shape[0] > 0
    for p in range(m):
        f = -1  # the isolated wheel the allocation leaves out
        if reallocate:
            pf = 0 if one else lo + p
            if fail.isolated[pf] >= 0 and k >= fail.isolated_step[pf]:
                f = fail.isolated[pf]
        alloc = wp.allocation[j] if f < 0 else wp.realloc[f, j]
        speed = xw[j, SPEED, p]
        v = wcmd[j, p] if per_wheel else -(alloc[0] * b[U, p] + alloc[1] * b[U + 1, p] + alloc[2] * b[U + 2, p])
        emf = mot[KB, p] * speed
        null = tau_n > 0.0 and n_j != 0.0 and f < 0 and not per_wheel
        if torque[p] or per_wheel:  # wheel torque (and the null-space loop's) -> steady current -> volts
            if null:
                v += n_j * wp.j_m * (wp.null_target - _null_speed(xw, p, wp)) / tau_n
            v = mot[RA, p] * (v + b_m * speed) / mot[KI, p] + emf
        elif null:
            v += n_j * _null_volts(_null_speed(xw, p, wp), wp, mot[KB, p], mot[KI, p], mot[RA, p])
        v = min(max(v, emf - mot[HEAD, p]), emf + mot[HEAD, p])
        v = emf if (abs(speed) >= speed_max and (v - emf) * speed > 0.0) else v
        mot[E, p] = min(max(v, -v_max), v_max)


@njit(cache=True, inline="always")
def _fail(m, j, lo, k, fail, mot, xw):
    # a failed wheel j (rare: a plain loop): a stuck drive holds the voltage of the step before the failure, a
    # lost one (open circuit) coasts, a torque-limited one keeps its voltage within R_a limit / K_i of the
    # back-EMF (its current limit lowered), a speed-limited one no longer drives beyond its limit; until the
    # failure, the held voltage follows the drive
    fail_j, fail_k, mode, e_hold = fail.wheel, fail.step, fail.mode, fail.e_hold
    one = fail_j.shape[0] == 1
    for p in range(m):
        pf = 0 if one else lo + p
        mot[LOST, p] = 0.0
        if j == fail_j[pf]:
            emf = mot[KB, p] * xw[j, SPEED, p]
            if k < fail_k[pf]:
                e_hold[pf] = mot[E, p]
            elif mode[pf] == FAIL_STUCK:
                mot[E, p] = e_hold[pf]
            elif mode[pf] == FAIL_LOST:
                mot[LOST, p] = 1.0
            elif mode[pf] == FAIL_TORQUE_LIMIT:
                head = mot[RA, p] * fail.value[pf] / mot[KI, p]
                mot[E, p] = min(max(mot[E, p], emf - head), emf + head)
            elif mode[pf] == FAIL_FRICTION:
                mot[LOST, p] = 2.0  # stepped with the fault's transition (wheel_lanes)
            elif abs(xw[j, SPEED, p]) >= fail.value[pf] and (mot[E, p] - emf) * xw[j, SPEED, p] > 0.0:
                mot[E, p] = emf


@njit(cache=True)
def _friction_step(j, p, pf, xw, xn, mot, fail):
    # wheel j of episode p over the step with the friction fault's exact motor transition (row pf of fail's)
    for r in range(3):
        xn[j, r, p] = (xw[j, ANGLE, p] * fail.phi[pf, 0, r] + xw[j, CURRENT, p] * fail.phi[pf, 1, r]
                       + xw[j, SPEED, p] * fail.phi[pf, 2, r] + mot[E, p] * fail.gamma[pf, r])


@njit(cache=True, inline="always")
def wheel_lanes(m, lo, k, xw, xn, b, mot, torque, wp, fail, wcmd):
    """Drive limits, exact motor step and mean body torque of a block's m episodes at step ``k``.

    Parameters
    ----------
    m, lo : int
        Episodes of the block, and the first one's row in the per-episode failures.
    k : int
        Step (a failure starts at its step).
    xw, xn : (n, 3, >= m) arrays
        Wheel state at t_k per wheel (angle rad, current A, speed rad/s; episodes last), and the state at
        t_k+1 written.
    b : (BODY_ROWS, >= m) array
        The body block: reads the body-axis command (rows ``U``: volts, or N m where ``torque[p]``), writes
        the mean torque on the body over the step (``TC``, N m) and the wheels' momentum at t_k (``H``, N m s).
    mot : (MOTOR_ROWS, >= m) array
        :func:`motor_lanes` of the block (rows ``E``, ``LOST`` are scratch).
    torque : (>= m,) bool array
    wp, fail : kernels.WheelParams, kernels.WheelFailure
        The assembly and the failures (F = 1 or P; ``e_hold`` is updated in place).
    wcmd : (n, >= m) array, or (0, m)
        Each wheel's own motor torque command, N m (``wheel_cmd``: the command rows ``U`` are not read), or
        no rows: the body-axis command.
    """
    axes, j_m, coast0, coast1 = wp.axes, wp.j_m, wp.coast[0], wp.coast[1]
    failing = fail.wheel.shape[0] > 1 or fail.wheel[0] >= 0
    reallocate = wp.reallocate and (fail.isolated.shape[0] > 1 or fail.isolated[0] >= 0)
    for i in range(3):
        for p in range(m):
            b[TC + i, p] = 0.0
            b[H + i, p] = 0.0
    for j in range(xw.shape[0]):
        _drive(m, j, xw, b, mot, torque, wp, fail, lo, k, reallocate, wcmd)
        if failing:
            _fail(m, j, lo, k, fail, mot, xw)
        for r in range(3):  # the exact motor step, one state at a time (few rows written per loop)
            for p in range(m):
                xn[j, r, p] = (xw[j, ANGLE, p] * mot[PHI + r, p] + xw[j, CURRENT, p] * mot[PHI + 3 + r, p]
                               + xw[j, SPEED, p] * mot[PHI + 6 + r, p] + mot[E, p] * mot[GAMMA + r, p])
        if failing:  # open circuit: no current, the wheel coasts down on its viscous friction; or a grown friction
            for p in range(m):
                if mot[LOST, p] == 1.0:
                    speed = xw[j, SPEED, p]
                    xn[j, ANGLE, p] = xw[j, ANGLE, p] + coast1 * speed
                    xn[j, CURRENT, p], xn[j, SPEED, p] = 0.0, coast0 * speed
                elif mot[LOST, p] == 2.0:
                    _friction_step(j, p, 0 if fail.phi.shape[0] == 1 else lo + p, xw, xn, mot, fail)
        for i in range(3):
            x_i = axes[i, j]
            for p in range(m):
                b[H + i, p] += x_i * (xw[j, SPEED, p] * j_m)
                b[TC + i, p] += x_i * (xn[j, SPEED, p] * j_m)
    dt = wp.dt
    for i in range(3):
        for p in range(m):
            b[TC + i, p] = -(b[TC + i, p] - b[H + i, p]) / dt
