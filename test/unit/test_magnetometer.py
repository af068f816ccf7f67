"""The magnetometer model (core/sensing/models.py): its errors as declared, its noise as its covariance says."""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.core.plant.quaternion import cross_matrix
from attitude_sil.core.sensing.models import Magnetometer, MagnetometerErrors

B = np.array([[2.0e-5, -1.0e-5, 3.5e-5]])  # tesla: a low-orbit field in B


def test_its_sample_covariance_is_its_declared_covariance():
    # 20,000 readings of a constant field: the sample variance of each axis has a relative standard error of
    # sqrt(2 / n) = 1 %, so 5 % is five of them (the bound is 30 %); the axes are uncorrelated
    mag = Magnetometer(MagnetometerErrors(noise=50e-9), np.array([7]))
    readings = np.array([mag.sample(B, k)[0] for k in range(20000)])
    cov = np.cov(readings.T)
    assert np.allclose(np.diag(cov), mag.variance, rtol=0.05)
    assert np.max(np.abs(cov - np.diag(np.diag(cov)))) < 0.05 * mag.variance[0]
    assert np.allclose(readings.mean(axis=0), B[0], rtol=0, atol=5 * 50e-9 / np.sqrt(20000))


def test_scale_misalignment_and_bias_are_applied_as_declared():
    e = MagnetometerErrors(bias=(1e-7, -2e-7, 3e-7), scale_factor=(1e-3, -2e-3, 5e-4), misalignment=(1e-3, 0, -2e-3))
    reading = Magnetometer(e, np.array([0])).sample(B, 3)[0]
    expected = (np.eye(3) + np.diag(e.scale_factor)) @ (np.eye(3) - cross_matrix(np.array(e.misalignment))) @ B[0]
    assert reading == pytest.approx(expected + np.array(e.bias), rel=0, abs=1e-18)


def test_it_quantises_and_saturates():
    mag = Magnetometer(MagnetometerErrors(resolution=1e-7, range=3e-5), np.array([0]))
    reading = mag.sample(B, 0)[0]
    assert reading.tolist() == pytest.approx([2.0e-5, -1.0e-5, 3.0e-5], abs=1e-18)  # z clipped at the range
    assert np.all(np.abs(np.round(reading / 1e-7) * 1e-7 - reading) < 1e-20)


def test_a_reading_depends_only_on_seed_step_and_axis():
    a = Magnetometer(MagnetometerErrors(noise=1e-7), np.array([3, 4]))
    b = Magnetometer(MagnetometerErrors(noise=1e-7), np.array([4]))
    assert np.array_equal(a.sample(np.repeat(B, 2, axis=0), 12)[1], b.sample(B, 12)[0])  # episode 2 is seed 4
    assert not np.array_equal(a.sample(B, 12)[0], a.sample(B, 13)[0])
