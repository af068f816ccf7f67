"""The step metrics' scalar pieces, one sample at a time: one home for every driver.

The graph's running metrics (:mod:`attitude_sil.core.analysis.running_metrics`, from
Python) and the batch engine's running sums (:mod:`attitude_sil.core.sim.batch_loop`,
inlined into the compiled loop) call these same compiled functions, so both
read a step the same way as :func:`attitude_sil.core.analysis.metrics.step_metrics`
does on a whole trajectory (``quaternion.euler_from_quat``, ``metrics._first_crossing``):
bit for bit with each other, and within 2 ulp of the trajectory's angle (numpy's
``arctan2``; :func:`arctan2` here is arithmetic, so the engine's loop over its
episodes stays packed).
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
from numba import njit

__all__ = ["Sums", "arctan2", "euler_axis", "first_crossing"]


class Sums(IntEnum):
    """The columns of the batch engine's running sums per episode, by name (the member's value is its column).

    The compiled loop (:mod:`attitude_sil.core.sim.batch_loop`) writes them,
    :func:`attitude_sil.core.analysis.metrics.step_summary` reads them; both
    index by these names, so a column means one thing everywhere.
    """

    time_constant_s = 0  #: first time the response reaches 63.2 % of the step, s after it
    t10_s = 1  #: first time at 10 %, s
    t90_s = 2  #: first time at 90 %, s
    max_fraction = 3  #: the largest fraction of the step reached (overshoot = max(0, this - 1))
    settling_time_s = 4  #: the sample after the last one outside the band, s; 0 never left, NaN never settled
    steady_state_error_rad = 5  #: |error| at the last sample, rad
    iae = 6  #: integral of |error| after the step, rad s (trapezoid)
    ise = 7  #: integral of error^2, rad^2 s
    itae = 8  #: integral of t |error|, rad s^2
    control_effort_Nms = 9  #: integral of |tau_c|, N m s
    finite = 10  #: 1.0 while every rate and command has been finite, else 0.0
    peak_command = 11  #: largest |command| (V or N m); inf after a NaN
    peak_wheel_speed = 12  #: largest |wheel speed|, rad/s; inf after a NaN


#: Cephes' arctangent (``atan.c``, S. L. Moshier): tan(3 pi / 8), the rational approximation's numerator and
#: denominator on [0, 0.66], and the low bits of pi / 2
_T3P8 = 2.41421356237309504880
_ATAN_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
           -1.228866684490136173410e2, -6.485021904942025371773e1)
_ATAN_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
           4.853903996359136964868e2, 1.945506571482613964425e2)
_MOREBITS = 6.123233995736765886130e-17


@njit(cache=True, inline="always", error_model="numpy")
def arctan2(y, x):
    """atan2(y, x), rad, in arithmetic and selects only, so a loop over episodes calling it stays packed.

    libm's ``atan2`` is a call, which keeps the loop around it scalar. This is
    Cephes' ``atan2`` (the quotient y / x reduced to [0, 0.66] and a degree
    4/5 rational function), every branch a select: within 2 ulp of libm
    (24-26 % of results differ, by 1 or 2 ulp, over 6e6 arguments of every
    magnitude) and libm's value, signed zero included, at every zero,
    infinite and NaN argument (``test_metric_rows``).
    """
    t = y / x
    a = abs(t)
    big, mid = a > _T3P8, a > 0.66
    # -1 / a, (a - 1) / (a + 1) or a / 1 (exact): one division for the three
    r = (-1.0 if big else (a - 1.0 if mid else a)) / (a if big else (a + 1.0 if mid else 1.0))
    base = np.pi / 2 if big else (np.pi / 4 if mid else 0.0)
    more = _MOREBITS if big else (0.5 * _MOREBITS if mid else 0.0)
    z = r * r
    p0, p1, p2, p3, p4 = _ATAN_P
    q0, q1, q2, q3, q4 = _ATAN_Q
    num = (((p0 * z + p1) * z + p2) * z + p3) * z + p4
    den = ((((z + q0) * z + q1) * z + q2) * z + q3) * z + q4
    v = math.copysign(base + ((r * (z * num / den) + r) + more), t)
    x_negative = math.copysign(1.0, x) < 0.0
    angle = math.copysign(np.pi, y) + v if x_negative else v
    if a != a and x == x and y == y:  # 0 / 0 or inf / inf: libm's values
        angle = math.copysign((np.pi if x_negative else 0.0) if x == 0.0 else
                              (0.75 * np.pi if x_negative else 0.25 * np.pi), y)
    return angle


@njit(cache=True, inline="always", error_model="numpy")
def euler_axis(x, y, z, w, axis):
    """Roll (0), pitch (1) or yaw (2), rad, of the quaternion (x, y, z, w): ZYX, paper 000 eq. 9.

    Roll and yaw through :func:`arctan2` (no call: a loop of them stays packed).
    """
    if axis == 1:
        return np.arcsin(min(max(2.0 * (w * y - z * x), -1.0), 1.0))
    a, c = (x, z) if axis == 0 else (z, x)  # roll: (2 (w x + y z), 1 - 2 (x^2 + y^2)); yaw: x and z swapped
    return arctan2(2.0 * (w * a + y * c), 1.0 - 2.0 * (a * a + y * y))


@njit(cache=True, inline="always")
def first_crossing(found, level, f, f_prev, ta, ta_prev, first):
    """The time the fraction ``f`` of the step first reaches ``level``, interpolated; ``found`` once known.

    ``f``, ``ta``: this sample's fraction and time after the step (s);
    ``f_prev``, ``ta_prev``: the previous sample's; ``first``: this is the
    first sample after the step (it gives its own time). NaN while not reached.
    """
    if not np.isnan(found) or not f >= level:
        return found
    if first:
        return ta
    frac = (level - f_prev) / (f - f_prev) if f != f_prev else 0.0
    return ta_prev + frac * (ta - ta_prev)
