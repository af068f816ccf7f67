"""The step metrics' compiled angle (core/analysis/metric_rows.py) against libm.

``arctan2`` replaces libm's ``atan2`` in the running sums of the graph and the batch engine so that
the engine's loop over a block's episodes stays packed; it must give libm's angle to the last bits
and libm's value exactly wherever an argument is zero, infinite or NaN.
"""

from __future__ import annotations

import math
import re

import numpy as np
from numba import njit

from attitude_sil.core.analysis.metric_rows import arctan2, euler_axis
from attitude_sil.core.plant.quaternion import euler_from_quat, quat_from_euler


@njit(error_model="numpy")
def _angles(ys, xs, out):
    for i in range(ys.shape[0]):
        out[i] = arctan2(ys[i], xs[i])


def _ulps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # distance in units in the last place, across zero too (ordered integers of the bit patterns)
    ia, ib = a.view(np.int64), b.view(np.int64)
    ia = np.where(ia < 0, np.int64(-(2**63)) - ia, ia)
    ib = np.where(ib < 0, np.int64(-(2**63)) - ib, ib)
    return np.abs(ia - ib)


def test_arctan2_is_libms_within_two_ulp_in_every_quadrant_and_magnitude():
    rng = np.random.default_rng(7)
    n = 200_000
    cases = {
        "unit normals": (rng.normal(size=n), rng.normal(size=n)),
        "roll-sized angles": (rng.normal(0.0, 0.3, n), 1.0 - np.abs(rng.normal(0.0, 0.05, n))),
        "every magnitude": (rng.normal(size=n) * 10.0 ** rng.uniform(-300, 300, n),
                            rng.normal(size=n) * 10.0 ** rng.uniform(-300, 300, n)),
    }
    for name, (y, x) in cases.items():
        got = np.empty(n)
        _angles(y, x, got)
        libm = np.array([math.atan2(a, b) for a, b in zip(y, x, strict=True)])
        assert _ulps(got, libm).max() <= 2, name
        # a real approximation: the reduction's three branches and all four quadrants are exercised
        assert np.all(np.abs(got) <= math.pi) and np.ptp(np.sign(got)) == 2


def test_arctan2_gives_libms_value_and_sign_at_zeros_infinities_and_nan():
    special = [0.0, -0.0, 1.0, -1.0, math.inf, -math.inf, math.nan, 1e-300, -5e-324, 1e300]
    for y in special:
        for x in special:
            got = np.empty(1)
            _angles(np.array([y]), np.array([x]), got)
            want = math.atan2(y, x)
            if math.isnan(want):
                assert math.isnan(got[0]), (y, x)
            else:
                assert got[0] == want and math.copysign(1, got[0]) == math.copysign(1, want), (y, x, got[0], want)


def test_euler_axis_is_euler_from_quat_for_roll_pitch_and_yaw():
    rng = np.random.default_rng(3)
    rpy = rng.uniform([-3.1, -1.5, -3.1], [3.1, 1.5, 3.1], (2000, 3))
    q = quat_from_euler(rpy)
    whole = euler_from_quat(q)
    for axis in range(3):
        got = np.array([euler_axis(*qi, axis) for qi in q])
        assert np.allclose(got, whole[:, axis], rtol=0.0, atol=4e-16 * np.pi), axis
        assert np.allclose(got, rpy[:, axis], rtol=0.0, atol=1e-12), axis


def test_a_loop_of_arctan2_is_packed():
    # the reason it exists: libm's atan2 is a call and keeps the engine's per-episode loop scalar
    _angles(np.ones(8), np.ones(8), np.empty(8))
    asm = _angles.inspect_asm(_angles.signatures[0])
    assert re.search(r"\bvdivpd\s+%[yz]mm", asm), "the loop of arctan2 did not vectorise"
