"""Physics invariants of the core: momentum, RK4 order, motor exactness, limits, model check."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from attitude_sil.core.plant.quaternion import euler_from_quat
from attitude_sil.core.plant.rigid_body import BodyState, inertial_momentum, rk4_step
from attitude_sil.core.plant.wheels import MotorParams, WheelAssembly, hst_pyramid
from attitude_sil.core.sim.build import build_plant, build_wheels
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario, scenario_from_dict
from conftest import CONFIG


def test_hst_pyramid_allocation_is_exact_inverse():
    a = hst_pyramid()
    assert a.shape == (3, 4)
    assert np.allclose(np.linalg.norm(a, axis=0), 1.0)  # unit spin axes
    assert np.allclose(a @ np.linalg.pinv(a), np.eye(3), atol=1e-12)  # eq. 14 reproduces any body torque


def test_total_momentum_conserved_over_60s():
    """Body + wheels, no external torque: |H_N(t) - H_N(0)| / |H_N(0)| <= 1e-9 over 60 s."""
    scn = load_scenario(CONFIG / "hst_roll_yaw.yaml").with_values("disturbance", models=[])
    scn = scn.with_values("plant", initial_body_rate=[0.01, -0.02, 0.015], duration=60.0)
    tr = simulate(scn, 1)
    inertia = np.diag([31.046, 77.217, 78.754])[None]
    h = np.stack([inertial_momentum(tr.q_BN[:, k], tr.omega_BN_B[:, k], tr.h_wheels_B[:, k], inertia)
                  for k in range(tr.t.size)], axis=1)[0]
    # the wheels really exchanged momentum with the body
    assert np.max(np.abs(tr.h_wheels_B)) > 0.1
    drift = np.max(np.linalg.norm(h - h[0], axis=1)) / np.linalg.norm(h[0])
    assert drift <= 1e-9


def _torque_free(dt, t_end):
    inertia = np.diag([31.046, 77.217, 78.754])[None]
    s = BodyState(np.array([[0.0, 0.0, 0.0, 1.0]]), np.array([[0.3, 0.05, -0.2]]), np.array([[1.0, -2.0, 0.5]]))
    zero = np.zeros((1, 3))
    for _ in range(int(round(t_end / dt))):
        s = rk4_step(s, inertia, np.linalg.inv(inertia), zero, zero, dt)
    return np.concatenate([s.q_BN[0], s.omega_BN_B[0]])


def test_rk4_is_fourth_order():
    ref = _torque_free(0.5 / 64, 20.0)
    errs = [np.max(np.abs(_torque_free(dt, 20.0) - ref)) for dt in (0.5, 0.25, 0.125)]
    ratios = [errs[i] / errs[i + 1] for i in range(2)]
    # a 4th-order method divides the error by 2^4 = 16 when dt halves
    for r in ratios:
        assert 13.0 < r < 19.0, (errs, ratios)


def test_motor_interval_is_exact():
    """expm integration of eq. 15-16 equals a tight ODE solution over one held-voltage step."""
    m = MotorParams(1.5, 1.5e-3, 1.5, 1.5, 0.84, 1e-4, 471.0, 1e9, 1e9)
    dt = 0.01
    wa = WheelAssembly(np.eye(3)[:, :1], m, dt)
    x0 = np.array([[[0.1, 2.0, 3.0]]])
    e = 10.0
    x1, _ = wa.step(x0, np.array([[e]]))
    def f(_, x):
        th, i, w = x
        return [w, (e - m.resistance * i - m.back_emf_constant * w) / m.inductance,
                (m.torque_constant * i - m.viscous_friction * w) / m.rotor_inertia]
    sol = solve_ivp(f, (0, dt), x0[0, 0], method="Radau", rtol=1e-12, atol=1e-12)
    assert np.allclose(x1[0, 0], sol.y[:, -1], rtol=1e-8, atol=1e-9)


def test_wheel_limits_hold():
    scn = scenario_from_dict({})
    wheels = build_wheels(scn, 1)
    m = wheels.assembly.motor
    torques, speeds = [], []
    for _ in range(200_0):  # 20 s of full command
        out = wheels.advance(np.array([[1e4, -1e4, 1e4]]))
        torques.append(np.abs(out.effort).max())
        speeds.append(np.abs(out.velocity).max())
    # current limit holds to within what back-EMF changes in one 10 ms step (<1 %)
    assert max(torques) <= m.torque_max * 1.01
    assert max(torques) >= m.torque_max * 0.95  # and the drive really pushes to it
    assert max(speeds) <= m.speed_max * 1.01


def test_model_check_3V_roll():
    """Paper 000 'Model validation': 3 V on the roll motor, no disturbance: rolls on and on."""
    scn = scenario_from_dict({})
    plant, wheels = build_plant(scn, 1), build_wheels(scn, 1)
    zero = np.zeros((1, 3))
    rpy, rates = [], []
    for _ in range(6000):  # 60 s
        rpy.append(euler_from_quat(plant.state.q_BN)[0])
        rates.append(plant.state.omega_BN_B[0].copy())
        out = wheels.advance(np.array([[3.0, 0.0, 0.0]]))
        plant.advance(out.tau_c_B, out.h_wheels_B, zero)
    rpy, rates = np.array(rpy), np.array(rates)
    roll = np.unwrap(rpy[:, 0])
    assert np.all(np.diff(roll[1:]) > 0.0)  # keeps rolling in one direction
    assert rates[-1, 0] > 0.0 and rates[-1, 0] == pytest.approx(rates[3000, 0], rel=1e-2)  # no torque stops it
    assert np.max(np.abs(rpy[:, 1:])) < 1e-6  # pitch and yaw stay at zero


def test_compiled_wheel_step_equals_reference():
    """The compiled wheel loop does what the documented numpy steps do."""
    scn = scenario_from_dict({})
    wa = build_wheels(scn, 3).assembly
    rng = np.random.default_rng(5)
    x = rng.standard_normal((3, 4, 3)) * [1.0, 0.3, 200.0]
    x[0, 0, 2] = wa.motor.speed_max * 1.001  # one wheel over the speed limit
    v = rng.standard_normal((3, 3)) * 50.0
    x1, tau, h0 = wa.advance(x, v)
    e = wa.wheel_voltages(v, x)
    x1_ref, tau_ref = wa.step(x, e)
    assert np.allclose(x1, x1_ref, rtol=1e-12, atol=1e-12)
    assert np.allclose(tau, tau_ref, rtol=1e-9, atol=1e-9)
    assert np.allclose(h0, wa.momentum_B(x), rtol=1e-12)


def test_compiled_rk4_equals_the_documented_numpy_step():
    """kernels.rk4_body does the RK4 of rigid_body.body_derivatives (eq. 3, 4, 10-11)."""
    from attitude_sil.core.plant.rigid_body import body_derivatives

    rng = np.random.default_rng(11)
    inertia = np.array([np.diag([31.0, 77.0, 78.0]), [[5.0, 0.1, 0.0], [0.1, 6.0, 0.2], [0.0, 0.2, 4.0]]])
    inv = np.linalg.inv(inertia)
    q = rng.standard_normal((2, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, h, tc, te = (rng.normal(0, s, (2, 3)) for s in (0.1, 2.0, 0.5, 0.1))
    dt = 0.05
    k1 = body_derivatives(q, w, h, inertia, inv, tc, te)
    k2 = body_derivatives(*(x + dt / 2 * d for x, d in zip((q, w, h), k1, strict=True)), inertia, inv, tc, te)
    k3 = body_derivatives(*(x + dt / 2 * d for x, d in zip((q, w, h), k2, strict=True)), inertia, inv, tc, te)
    k4 = body_derivatives(*(x + dt * d for x, d in zip((q, w, h), k3, strict=True)), inertia, inv, tc, te)
    ref = [x + dt / 6 * (a + 2 * b + 2 * c + d) for x, a, b, c, d in zip((q, w, h), k1, k2, k3, k4, strict=True)]
    ref[0] /= np.linalg.norm(ref[0], axis=1, keepdims=True)
    out = rk4_step(BodyState(q, w, h), inertia, inv, tc, te, dt)
    for got, want in zip((out.q_BN, out.omega_BN_B, out.h_wheels_B), ref, strict=True):
        assert np.allclose(got, want, rtol=1e-12, atol=1e-14)


def test_the_compiled_orbit_torques_are_the_papers_equations_as_written():
    # orbit_torques (what the disturbance node and the stepwise driver run) against paper 001 eq. 2-3 in
    # their numpy forms on R_BL, to the last bit, over random attitudes, LVLH frames and inertias
    from attitude_sil.core.plant.disturbance import aerodynamic_torque, gravity_gradient_torque, orbit_torques
    from attitude_sil.core.plant.quaternion import quat_conjugate, quat_multiply, quat_to_dcm

    rng = np.random.default_rng(7)
    q_BN = rng.normal(size=(50, 4))
    q_BN /= np.linalg.norm(q_BN, axis=1, keepdims=True)
    q_LN = rng.normal(size=4)
    q_LN /= np.linalg.norm(q_LN)
    a = rng.uniform(1, 5, (50, 3, 3))
    inertia = a @ np.swapaxes(a, 1, 2)  # symmetric positive definite, products of inertia too
    cp = np.array([0.01, -0.02, 0.05])
    R_BL = np.swapaxes(quat_to_dcm(quat_multiply(quat_conjugate(q_LN), q_BN)), -1, -2)
    rate, speed = 1.1e-3, 7.6e3
    gg = gravity_gradient_torque(R_BL, inertia, rate)
    aero = aerodynamic_torque(R_BL, 1e-11, 2.2, 0.01, speed, cp)
    for on_gg, on_aero, want in ((True, False, gg), (False, True, aero), (True, True, None)):
        tau = np.zeros((50, 3))
        orbit_torques(q_BN, q_LN, inertia, 3.0 * rate**2, 0.5 * 1e-11 * 2.2 * 0.01 * speed**2, cp, on_gg, on_aero,
                      tau)
        assert np.array_equal(tau, (np.zeros((50, 3)) + gg) + aero if on_gg and on_aero else want)
    assert np.min(np.abs(gg)) > 0 and np.min(np.abs(aero)) > 0  # both moments present: equality is not trivial


def test_the_lvlh_frame_multiplied_out_is_the_quaternion_product_to_the_bit():
    from attitude_sil.core.plant.disturbance import lvlh_attitude
    from attitude_sil.core.plant.quaternion import quat_multiply

    rng = np.random.default_rng(11)
    frames = rng.normal(size=(20, 4))
    frames /= np.linalg.norm(frames, axis=1, keepdims=True)
    for q_LN0, t in zip(frames, rng.uniform(0.0, 6000.0, 20), strict=True):
        half = 0.5 * 1.1e-3 * t
        want = quat_multiply(q_LN0, np.array([0.0, np.sin(half), 0.0, np.cos(half)]))
        assert np.array_equal(lvlh_attitude(t, q_LN0, 1.1e-3), want)
    assert np.array_equal(lvlh_attitude(100.0, frames, 1.1e-3), quat_multiply(frames, lvlh_attitude(100.0, np.array(
        [0.0, 0.0, 0.0, 1.0]), 1.1e-3)))  # many frames at once: the product as it is


@pytest.mark.parametrize("n", [1, 10])
def test_the_compiled_noise_means_are_numpys_draws_summed_in_order_with_the_power_as_set(n):
    # step_means (the compiled driver's disturbance noise) against the numpy form DisturbanceModel.torque takes
    # step by step: the same PCG64 stream, each step's (n, 3) block summed over the sample axis; and the
    # band-limited white noise of paper 000 sec. 2.A: a held mean of n samples of variance power / T_s has
    # variance power / dt (dt = n T_s), so the impulse it gives the body over a step is that of the power
    from attitude_sil.core.plant.disturbance import step_means

    steps, sample_time, power = 4000, 1e-3, np.array([2e-7, 5e-7, 1e-6])
    std = np.sqrt(power / sample_time)
    draws = np.random.Generator(np.random.PCG64(21)).standard_normal((steps * n, 3))
    want = np.add.reduce(draws.reshape(steps, n, 3), axis=1) / n * std
    got = np.empty((steps, 3))
    step_means(np.random.Generator(np.random.PCG64(21)), n, std, got)
    assert np.array_equal(got, want)
    # sample variance of 4000 normals: relative standard error sqrt(2 / 4000) = 2.2 %; 12 % is over 5 of them
    assert np.allclose(np.var(got, axis=0), power / (n * sample_time), rtol=0.12)
