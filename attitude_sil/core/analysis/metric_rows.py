"""The step metrics' scalar pieces, one sample at a time: one home for every driver.

The graph's running metrics (:mod:`attitude_sil.core.analysis.running_metrics`, from
Python) and the batch engine's running sums (:mod:`attitude_sil.core.sim.batch_loop`,
inlined into the compiled loop) call these same compiled functions, so both
read a step the same way as :func:`attitude_sil.core.analysis.metrics.step_metrics`
does on a whole trajectory (``quaternion.euler_from_quat``, ``metrics._first_crossing``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["euler_axis", "first_crossing"]


@njit(cache=True, inline="always")
def euler_axis(x, y, z, w, axis):
    """Roll (0), pitch (1) or yaw (2), rad, of the quaternion (x, y, z, w): ZYX, paper 000 eq. 9."""
    if axis == 0:
        return np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    if axis == 1:
        return np.arcsin(min(max(2.0 * (w * y - z * x), -1.0), 1.0))
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


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
