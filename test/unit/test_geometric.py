"""The geometric tracking law (paper 001 eq. 7): sign conventions and the Lyapunov check."""

import numpy as np
import pytest

from attitude_sil.core.control.bank import ControllerBank
from attitude_sil.core.control.laws.geometric import skew_vee, torque_reference
from attitude_sil.core.plant.quaternion import quat_derivative, quat_from_euler, quat_multiply, quat_to_dcm
from attitude_sil.core.sim.build import law_bank
from attitude_sil.core.sim.params import spec_for
from attitude_sil.errors import ScenarioError

J = np.diag([5.69, 5.69, 4.26])  # Hawai'iSat-1
K = np.array([0.06, 0.02, 0.03])
L = np.array([0.1, 0.09, 0.08])


def test_attitude_term_matches_papers_sum():
    rng = np.random.default_rng(1)
    q = rng.standard_normal((5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    Q = quat_to_dcm(q)
    s_k = skew_vee(K[:, None] * np.eye(3) @ Q - np.swapaxes(Q, -1, -2) @ (K[:, None] * np.eye(3)))
    paper = sum(K[i] * np.cross(np.eye(3)[i], np.einsum("pji,j->pi", Q, np.eye(3)[i])) for i in range(3))
    assert np.allclose(s_k, -paper)  # eq. 7 adds +sum k_i e_i x Q^T e_i, i.e. -S_K


def _values(**extra):
    return {"k": K.tolist(), "l": L.tolist(), "inertia": J.ravel().tolist(), **extra}


def _law(dt, torque_limit):
    return law_bank("geometric", 1, dt, {**_values(), "torque_limit": torque_limit})


def _lyapunov(q_BN, w, q_RN, w_d):
    Q = np.swapaxes(quat_to_dcm(q_RN), -1, -2) @ quat_to_dcm(q_BN)  # R_d^T R (eq. 5)
    w_e = w - np.einsum("pji,pj->pi", Q, w_d)
    return 0.5 * np.einsum("pi,ij,pj->p", w_e, J, w_e) + np.sum(K * (1.0 - np.diagonal(Q, axis1=1, axis2=2)),
                                                                  axis=1), w_e


def test_lyapunov_function_decreases_at_rate_minus_we_L_we():
    """Torque-driven rigid body under the unsaturated law, tracking a rotating reference."""
    dt = 0.01
    w_d = np.array([[0.0, 0.0011, 0.0]])  # LVLH-like constant rate about y, in R
    q_RN = np.array([[0.0, 0.0, 0.0, 1.0]])
    q_BN = quat_from_euler(np.radians([[60.0, -40.0, 120.0]]))  # far from the reference
    w = np.array([[0.02, -0.01, 0.015]])

    def f(q_b, w_b, q_r, tau):
        return quat_derivative(q_b, w_b), np.linalg.solve(J, (-np.cross(w_b, w_b @ J.T) + tau)[0])[None], \
            quat_derivative(q_r, w_d)

    vs, rates = [], []
    for _ in range(6000):  # 60 s: the slowest mode, sqrt(k/J) ~ 0.1 rad/s, has several time constants
        tau = torque_reference(_values(), q_BN, w, q_RN, w_d)
        v, w_e = _lyapunov(q_BN, w, q_RN, w_d)
        vs.append(v[0])
        rates.append(-(w_e @ np.diag(L) @ w_e.T)[0, 0])
        # RK4 with the torque held (ZOH); the law is re-evaluated every 10 ms
        k1 = f(q_BN, w, q_RN, tau)
        k2 = f(q_BN + dt / 2 * k1[0], w + dt / 2 * k1[1], q_RN + dt / 2 * k1[2], tau)
        k3 = f(q_BN + dt / 2 * k2[0], w + dt / 2 * k2[1], q_RN + dt / 2 * k2[2], tau)
        k4 = f(q_BN + dt * k3[0], w + dt * k3[1], q_RN + dt * k3[2], tau)
        q_BN = q_BN + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        w = w + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        q_RN = q_RN + dt / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        q_BN /= np.linalg.norm(q_BN)
        q_RN /= np.linalg.norm(q_RN)
    vs = np.array(vs)
    # V never increases beyond the hold's O(dt^2) effect, and falls a lot
    assert np.all(np.diff(vs) <= 1e-9)
    assert vs[-1] < 0.5 * vs[0]
    # dV/dt = -w_e^T L w_e (finite difference, central, against the formula)
    vdot = (vs[2:] - vs[:-2]) / (2 * dt)
    scale = np.max(np.abs(rates))
    assert np.max(np.abs(vdot - np.array(rates[1:-1]))) < 0.02 * scale


def test_torque_saturates_and_reference_rate_is_fed_forward():
    law = _law(0.01, torque_limit=1.2e-3)
    q = quat_multiply(np.array([[0, 0, 0, 1.0]]), quat_from_euler(np.radians([[30.0, 0, 0]])))
    u = law.compute(q, np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]]), np.zeros((1, 3)))
    assert np.max(np.abs(u)) == pytest.approx(1.2e-3)
    # aligned and rotating with the reference: nothing to correct, only nu x J nu
    w_d = np.array([[0.0, 0.0011, 0.0]])
    law2 = _law(0.01, torque_limit=1.0)
    u2 = law2.compute(np.array([[0, 0, 0, 1.0]]), w_d, np.array([[0, 0, 0, 1.0]]), w_d)
    assert np.allclose(u2, np.cross(w_d, w_d @ J.T))


def test_equal_k_entries_are_refused():
    spec = spec_for("controller", "geometric.k")
    with pytest.raises(ValueError, match="distinct"):
        spec.validate([0.05, 0.05, 0.02], "controller")
    assert spec.validate([0.05, 0.04, 0.02], "controller") == [0.05, 0.04, 0.02]


def test_compiled_law_equals_the_numpy_reference():
    """The compiled step == the numpy reference (feed-forward on), saturated, over random states and a rotating
    reference, with per-episode gains and a per-episode inertia."""
    from attitude_sil.core.sim.scenario import load_scenario
    from conftest import CONFIG

    values = dict(load_scenario(CONFIG / "hawaiisat_lvlh.yaml").values["controller"])
    assert values["geometric.feedforward"]  # the preset feeds the environment forward: the test covers it
    rng = np.random.default_rng(9)
    inertia = np.array([(J * s).ravel() for s in rng.uniform(0.8, 1.2, 6)])  # (6, 9): one J per episode
    gains = {"k": rng.uniform(0.01, 0.1, (6, 3)), "l": rng.uniform(0.01, 0.1, (6, 3)), "inertia": inertia}
    values.update({f"geometric.{n}": v for n, v in gains.items()})
    values.update({"geometric.torque_limit": 1e-3, "controller_type": "geometric"})
    law = ControllerBank(values, 0.05, 6)
    ref = {**values, **gains, "feedforward": values["geometric.feedforward"]}
    w_d = np.tile([0.0, 0.0011, 0.0], (6, 1))
    w_prev = None
    for step in range(5):
        q_b = rng.standard_normal((6, 4))
        q_b /= np.linalg.norm(q_b, axis=1, keepdims=True)
        q_r = rng.standard_normal((6, 4))
        q_r /= np.linalg.norm(q_r, axis=1, keepdims=True)
        args = (q_b, rng.normal(0, 0.01, (6, 3)), q_r, w_d * (1 + 0.1 * step))
        expected = np.clip(torque_reference(ref, *args, w_d_prev=w_prev, dt=0.05), -1e-3, 1e-3)
        w_prev = args[3]
        assert np.allclose(law.compute(*args), expected, rtol=1e-9, atol=1e-15)


def test_inertia_values_become_one_matrix_per_episode():
    """``geometric.inertia`` as 3 or 9 values, or per-episode rows of either, gives (..., 3, 3) matrices.

    Issue 22 found ``np.diag`` taking the diagonal of a (P, 3) array instead of building P matrices.
    """
    from attitude_sil.core.plant.rigid_body import inertia_matrix

    rows = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    assert np.array_equal(inertia_matrix(rows), np.stack([np.diag(r) for r in rows]))
    assert np.array_equal(inertia_matrix([1.0, 2.0, 3.0]), np.diag([1.0, 2.0, 3.0]))
    a = np.arange(18.0).reshape(2, 3, 3)
    full = (a @ np.swapaxes(a, 1, 2) + 10.0 * np.eye(3)).reshape(2, 9)  # symmetric positive definite
    assert np.array_equal(inertia_matrix(full), full.reshape(2, 3, 3))
    assert np.array_equal(inertia_matrix(full[0]), full[0].reshape(3, 3))
    # the one inertia_matrix of the package checks what the plant and the law both read
    with pytest.raises(ScenarioError, match="symmetric"):
        inertia_matrix(np.arange(9.0))
    with pytest.raises(ScenarioError, match="positive definite"):
        inertia_matrix([1.0, -2.0, 3.0])


def test_per_episode_inertia_is_each_episodes_own_matrix():
    """The preset's own inertia passed per episode, (P, 3) or (P, 9), changes nothing in a tracking run.

    With the bug above paper 001's Ts went 175.9 -> 222.2 s. A different inertia per episode must reach
    its episode and only it. Hawai'iSat-1 tracks a rotating frame, where J enters the law's feed-forward
    (a regulator with a fixed reference never uses J); its torque rods run in the stepwise driver, and
    the compiled driver builds the same record (``test_compiled_law_equals_the_numpy_reference``).
    """
    from attitude_sil.core.sim.engine import simulate
    from attitude_sil.core.sim.scenario import load_scenario
    from conftest import CONFIG

    scn = load_scenario(CONFIG / "hawaiisat_lvlh.yaml")
    own = np.array(scn.param("controller", "geometric.inertia"), float)  # (3,) diagonal
    run = dict(duration=20.0, schedule=[], threads=1)
    base = simulate(scn, 2, **run)
    for per_episode in (np.tile(own, (2, 1)), np.tile(np.diag(own).ravel(), (2, 1))):
        tr = simulate(scn, 2, controller_params={"geometric.inertia": per_episode}, **run)
        assert np.array_equal(tr.tau_c_B, base.tau_c_B)
    other = np.vstack([own, 1.2 * own])  # episode 1 believes a 20 % heavier body: only its command changes
    tr = simulate(scn, 2, controller_params={"geometric.inertia": other}, **run)
    assert np.array_equal(tr.tau_c_B[0], base.tau_c_B[0])
    assert not np.allclose(tr.tau_c_B[1], base.tau_c_B[1], rtol=1e-6, atol=0.0)
