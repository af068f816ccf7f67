"""The compiled sensing kernels (issue 44, item 1) against the numpy models they compile.

The sensors preset flown on the truth for 3 s, four episodes of their own seeds and gyro biases, with a
tracker outage and the preset's 0.1 s latency: the numpy :class:`SensorSuite` and :class:`Mekf`, stepped as
the stepwise driver steps them, against :mod:`attitude_sil.core.sensing.kernels` row by row on the same
truth. The readings and reports are the same arithmetic in the same order (equal to 1e-15 rad/s and 1e-15
in a quaternion); the filter, whose 6x6 products sum in another order, stays within 1e-12 of it, through
every roll-back for a late report and the outage.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.sensing.kernels import (
    gyro_record,
    gyro_row,
    mekf_record,
    mekf_row,
    tracker_record,
    tracker_row,
)
from attitude_sil.core.sim.build import build_sensing
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario

P = 4


def _scenario():
    scn = load_scenario(default_config_dir() / "hst_roll_step_sensors.yaml").with_values("scenario", feedback="truth")
    return scn.with_values("sensors", **{"star_tracker.outages_s": [1.0, 1.5]})


def test_the_kernels_read_report_and_estimate_as_the_numpy_models():
    scn = _scenario()
    seeds = np.arange(P) + 11
    bias = np.array([[1.0, -0.5, 0.2], [0.0, 0.3, -1.0], [2.0, 0.0, 0.0], [-0.7, 0.7, 0.1]])  # deg/h
    truth = simulate(scn, P, duration=3.0)
    ref = build_sensing(scn, P, seeds, gyro_bias_deg_h=bias)
    mine = build_sensing(scn, P, seeds, gyro_bias_deg_h=bias)
    gp, gs = gyro_record(mine.suite.gyro)
    tp, ts = tracker_record(mine.suite.star_tracker)
    mp, ms = mekf_record(mine.mekf)
    w, qm = np.empty((P, 3)), np.empty((P, 4))
    reports = blind = 0
    for k in range(truth.q_BN.shape[1]):
        q, omega = truth.q_BN[:, k], truth.omega_BN_B[:, k]
        sample = ref.suite.sample(q, omega, k)
        est = ref.mekf.step(k, sample.omega_meas_B, sample.star_tracker)
        for p in range(P):
            gyro_row(p, k, q, omega, gp, gs, w)
            j, valid = tracker_row(p, k, q, tp, ts, qm)
            mekf_row(p, k, w, j, valid, qm, mp, ms)
        np.testing.assert_allclose(w, sample.omega_meas_B, rtol=0, atol=1e-15)
        r = sample.star_tracker
        assert (j, valid) == ((-1, False) if r is None else (r.exposure_step, r.valid)), k
        if r is not None and r.valid:
            np.testing.assert_allclose(qm, r.q_BN, rtol=0, atol=1e-15)
            reports += 1
        blind += r is not None and not r.valid
        np.testing.assert_allclose(ms.q, est.q_BN, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ms.b, est.gyro_bias, rtol=0, atol=1e-15)
        np.testing.assert_allclose(ms.cov, est.cov, rtol=1e-12, atol=1e-24)
    assert reports == 25 and blind == 5  # 30 exposures reported by 3 s, five of them in the outage


def test_a_report_older_than_the_filter_keeps_is_dropped():
    mp, ms = mekf_record(build_sensing(_scenario(), 1, np.array([3])).mekf)  # keeps 10 steps (the latency)
    w, qm = np.zeros((1, 3)), np.array([[0.0, 0.0, np.sin(5e-4), np.cos(5e-4)]])
    for k in range(20):
        mekf_row(0, k, w, -1, False, qm, mp, ms)
    mekf_row(0, 20, w, 9, True, qm, mp, ms)  # 11 steps back: dropped
    assert ms.dropped[0] == 1 and np.array_equal(ms.q[0], [0.0, 0.0, 0.0, 1.0])
    mekf_row(0, 21, w, 11, True, qm, mp, ms)  # 10 back: taken
    assert ms.dropped[0] == 1 and ms.q[0, 2] > 1e-4
