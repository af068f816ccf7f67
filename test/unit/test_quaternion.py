"""Quaternion algebra and kinematics (paper 000 eq. 8-11)."""

import numpy as np
import pytest

from attitude_sil.core.plant import quaternion as qm


def rand_quats(n, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_euler_round_trip():
    rng = np.random.default_rng(1)
    rpy = np.column_stack([rng.uniform(-3, 3, 50), rng.uniform(-1.5, 1.5, 50), rng.uniform(-3, 3, 50)])
    back = qm.euler_from_quat(qm.quat_from_euler(rpy))
    assert np.allclose(back, rpy, atol=1e-12)


def test_euler_is_zyx_sequence():
    # eq. 8 must equal yaw about z, then pitch about y, then roll about x (Hamilton, body-fixed)
    r, p, y = 0.3, -0.2, 1.1
    def axis(i, a):
        v = np.zeros(4)
        v[i] = np.sin(a / 2)
        v[3] = np.cos(a / 2)
        return v
    expected = qm.quat_multiply(qm.quat_multiply(axis(2, y), axis(1, p)), axis(0, r))
    assert np.allclose(qm.quat_from_euler(np.array([r, p, y])), expected, atol=1e-15)


def test_product_identity_inverse_and_dcm():
    q = rand_quats(20)
    ident = np.tile([0.0, 0.0, 0.0, 1.0], (20, 1))
    assert np.allclose(qm.quat_multiply(q, qm.quat_conjugate(q)), ident, atol=1e-15)
    # rotation composition matches matrix composition
    p = rand_quats(20, seed=2)
    assert np.allclose(qm.quat_to_dcm(qm.quat_multiply(q, p)), qm.quat_to_dcm(q) @ qm.quat_to_dcm(p), atol=1e-14)
    assert np.allclose(qm.cross(q[:, :3], p[:, :3]), np.cross(q[:, :3], p[:, :3]))


def test_kinematics_matches_constant_rate_rotation():
    # with constant omega in B, q(t) = q0 ⊗ exp(omega t / 2); compare the derivative at t = 0
    q0 = rand_quats(5, seed=3)
    w = np.random.default_rng(4).standard_normal((5, 3))
    h = 1e-6
    ang = np.linalg.norm(w, axis=1, keepdims=True) * h
    dq = np.hstack([w / np.linalg.norm(w, axis=1, keepdims=True) * np.sin(ang / 2), np.cos(ang / 2)])
    numeric = (qm.quat_multiply(q0, dq) - q0) / h
    assert np.allclose(qm.quat_derivative(q0, w), numeric, atol=1e-6)


def test_error_vector_points_towards_setpoint():
    q_BN = qm.quat_from_euler(np.array([[0.0, 0.0, 0.0]]))
    q_RN = qm.quat_from_euler(np.array([[np.radians(1.0), 0.0, 0.0]]))
    e = qm.error_vector(q_BN, q_RN)
    assert e[0, 0] == pytest.approx(np.sin(np.radians(0.5)), rel=1e-12)
    assert np.allclose(e[0, 1:], 0.0)
    # short way round: -q is the same rotation, same error
    assert np.allclose(qm.error_vector(-q_BN, q_RN), e)


def test_normalize_rejects_zero():
    with pytest.raises(ValueError):
        qm.quat_normalize(np.zeros(4))


def test_received_quaternions_are_renormalised_within_tolerance_and_refused_beyond():
    q = qm.quat_from_euler(np.radians([[10.0, -20.0, 30.0]]))
    assert qm.unit_or_none(q) is q  # already unit: untouched, bit for bit
    scaled = qm.unit_or_none(q * (1.0 + 5e-4))
    assert scaled is not None and np.allclose(scaled, q, atol=1e-15)
    assert qm.unit_or_none(q * 10.0) is None  # the (7.071, 0, 0, 7.071) case: not an attitude
    assert qm.unit_or_none(np.zeros((1, 4))) is None
