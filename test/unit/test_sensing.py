"""The sensor models and the attitude filter: the statistics they promise, not only that they run.

* the gyro's Allan deviation, computed from a long run of the model, recovers the configured angle random
  walk and bias instability (IEEE Std 952 annex C: the three sources' Allan variances add);
* the star tracker's errors have the covariance it reports, its reports come on its schedule, late by its
  latency and stamped with the exposure, and an outage reports no attitude;
* the filter is consistent: its NEES over a 50-run Monte Carlo lies in the 95 % chi-square band, its
  attitude error after convergence is below the star tracker's own noise, its bias estimate converges to
  the gyro's true bias;
* truth feedback leaves every controller number as it was without sensors, estimate feedback closes the loop
  on the filter.
"""

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import nnls

from attitude_sil.core.plant.quaternion import attitude_error_B, rotation_quaternion
from attitude_sil.core.sensing.mekf import Mekf, MekfSettings, transition
from attitude_sil.core.sensing.models import (
    ARCSEC,
    DEG,
    Gyro,
    GyroErrors,
    StarTracker,
    StarTrackerErrors,
    StarTrackerReport,
    Tachometer,
    allan_variance_model,
)
from attitude_sil.core.sim.build import build_sensing
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.errors import ScenarioError
from conftest import CONFIG


def _allan_variance(rate: np.ndarray, dt: float, ms: np.ndarray) -> np.ndarray:
    """Overlapping Allan variance (IEEE Std 952 eq. C.5 on the integrated angle) of rate samples (K, n),
    averaged over the n series, at cluster sizes ms."""
    theta = np.vstack([np.zeros((1, rate.shape[1])), np.cumsum(rate, axis=0) * dt])
    return np.array([np.mean((theta[2 * m:] - 2 * theta[m:-m] + theta[:-2 * m]) ** 2) / (2 * (m * dt) ** 2)
                     for m in ms])


def test_the_gyro_allan_deviation_recovers_its_angle_random_walk_and_bias_instability():
    # a navigation-grade gyro (LN-200 class: 0.07 deg/sqrt(h), 1 deg/h), 32 units x 3 axes x 10,000 s at 4 Hz
    errors = GyroErrors(arw=0.07 * DEG / 60.0, bias_instability=1.0 * DEG / 3600.0, correlation_time=100.0)
    dt, P, K = 0.25, 32, 40_000
    gyro = Gyro(errors, dt, np.arange(P))
    still, level = np.zeros((P, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (P, 1))
    rate = np.empty((K, P, 3))
    for k in range(K):
        rate[k] = gyro.sample(level, still, k)
    ms = np.unique(np.logspace(0, np.log10(K // 8), 40).astype(int))
    T = ms * dt
    avar = _allan_variance(rate.reshape(K, P * 3), dt, ms)
    # least squares for the sources' powers (N^2, K^2, B^2; tau known), each row weighted by its relative
    # uncertainty (about 1 / sqrt(clusters)); the fit knows nothing of the generator
    A = np.stack([1.0 / T, T / 3.0, allan_variance_model(T, 0.0, 1.0, errors.correlation_time, 0.0)], axis=1)
    w = np.sqrt(P * 3 * (K - 2 * ms) / ms) / avar
    (n2, k2, b2), _ = nnls(A * w[:, None], avar * w)
    assert np.sqrt(n2) == pytest.approx(errors.arw, rel=0.10)
    assert np.sqrt(b2) == pytest.approx(errors.bias_instability, rel=0.10)
    assert np.sqrt(k2) < 0.1 * errors.bias_instability / np.sqrt(errors.correlation_time)  # none configured
    # and the curve itself follows the model within 10 % where it has at least 200 clusters per series
    model = allan_variance_model(T, errors.arw, errors.bias_instability, errors.correlation_time, 0.0)
    dense = (K - 2 * ms) / ms >= 200
    assert np.all(np.abs(np.sqrt(avar[dense] / model[dense]) - 1.0) < 0.10)


def test_gyro_scale_misalignment_bias_quantisation_and_range():
    errors = GyroErrors(bias=(1e-4, -2e-4, 3e-4), scale_factor=(1e-3, 0.0, -1e-3), misalignment=(0.0, 0.0, 1e-3),
                        resolution=1e-5, range=0.5)
    gyro = Gyro(errors, 0.01, np.array([0]))
    w = np.array([[0.1, 0.2, 0.0]])
    m = gyro.sample(np.array([[0.0, 0.0, 0.0, 1.0]]), w, 0)
    skew = np.array([[0.0, -1e-3, 0.0], [1e-3, 0.0, 0.0], [0.0, 0.0, 0.0]])
    expected = (np.diag([1.001, 1.0, 0.999]) @ (np.eye(3) - skew) @ w[0]) + np.array([1e-4, -2e-4, 3e-4])
    assert np.allclose(m[0], np.round(expected / 1e-5) * 1e-5, rtol=0, atol=1e-15)
    assert np.allclose(m[0] / 1e-5, np.round(m[0] / 1e-5), atol=1e-9)  # on the quantisation grid
    turned = rotation_quaternion(np.array([[2.0, -2.0, 0.0]]) * 0.01)  # 2 rad/s over the step
    assert np.all(np.abs(gyro.sample(turned, w, 1)[0, :2]) == 0.5)  # saturated at the range
    with pytest.raises(ScenarioError, match="step 5, expected step 2"):
        gyro.sample(np.array([[0.0, 0.0, 0.0, 1.0]]), w, 5)


def test_star_tracker_errors_match_their_covariance_and_its_schedule():
    errors = StarTrackerErrors(cross_boresight=5 * ARCSEC, about_boresight=40 * ARCSEC, boresight_axis=1,
                               rate_hz=4.0, latency=0.1, outages=((2.0, 3.0),))
    P = 2000
    st = StarTracker(errors, 0.01, np.arange(P))
    assert (st.schedule.period_steps, st.schedule.latency_steps) == (25, 10)
    rng = np.random.default_rng(1)
    truth = {}
    reports = []
    for k in range(500):
        q = rotation_quaternion(rng.normal(size=(P, 3)))
        truth[k] = q
        r = st.sample(q, k)
        if r is not None:
            reports.append((k, r))
    # one report every 25 steps, from step 10 on, of the exposure 10 steps earlier (t_j, the stamp)
    assert [k for k, _ in reports] == list(range(10, 500, 25))
    assert all(r.exposure_step == k - 10 for k, r in reports)
    # exposures at 2.0, 2.25, 2.5 and 2.75 s fall in the outage: no attitude
    assert [r.exposure_step for _, r in reports if not r.valid] == [200, 225, 250, 275]
    err = np.concatenate([attitude_error_B(truth[r.exposure_step], r.q_BN) for _, r in reports if r.valid])
    sigma = errors.sigma_B
    assert np.allclose(sigma, [5 * ARCSEC, 40 * ARCSEC, 5 * ARCSEC])
    # 32,000 samples per axis: the sample standard deviation is within 1 % (2.5 sigma) of the truth
    assert np.allclose(err.std(axis=0), sigma, rtol=0.01)
    assert np.all(np.abs(err.mean(axis=0)) < 3 * sigma / np.sqrt(len(err)))
    # and the normalised squared error is chi-square with 3 degrees of freedom
    d2 = np.sum((err / sigma) ** 2, axis=1)
    assert stats.kstest(d2, "chi2", args=(3,)).pvalue > 0.01


def test_tachometer_readings_are_counts_over_the_step():
    tach = Tachometer(24, 0.01)
    lsb = 2 * np.pi / (24 * 0.01)
    speed = 37.3  # rad/s, held
    readings = [tach.sample(np.array([speed * k * 0.01]), np.array([speed]))[0] for k in range(2000)]
    assert np.allclose(np.array(readings) / lsb, np.round(np.array(readings) / lsb))  # whole counts
    assert np.mean(readings[1:]) == pytest.approx(speed, rel=1e-3)  # counts over time give the speed
    assert readings[0] == pytest.approx(round(speed / lsb) * lsb)


def test_transition_matches_the_matrix_exponential():
    from scipy.linalg import expm

    omega = np.array([[0.3, -0.2, 0.5], [1e-7, 0.0, 0.0]])
    for w in omega:
        F = np.zeros((6, 6))
        F[:3, :3] = -np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        F[:3, 3:] = -np.eye(3)
        assert np.allclose(transition(w[None], 0.1)[0], expm(F * 0.1), rtol=0, atol=1e-14)


def _consistent_scenario(P: int):
    """HST roll step with the filter's model exact: white rate noise, a bias that is a random walk over the
    run (Gauss-Markov, tau 1e6 s) with the filter's walk and initial sigma equal to it, an initial attitude
    error drawn from the filter's initial covariance; latency 0.1 s and an outage to exercise both."""
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    tau, B = 1.0e6, 0.5  # s, deg/h
    scn = scn.with_values("sensors", **{"gyro.arw_deg_rt_h": 0.05, "gyro.bias_instability_deg_h": B,
                                        "gyro.bias_correlation_time_s": tau, "star_tracker.rate_hz": 4.0,
                                        "star_tracker.latency_s": 0.1, "star_tracker.cross_boresight_arcsec": 5.0,
                                        "star_tracker.about_boresight_arcsec": 40.0,
                                        "star_tracker.outages_s": [8.0, 12.0]})
    sigma0 = 0.01  # deg
    scn = scn.with_values("estimator", bias_walk_deg_h_rt_h=B * np.sqrt(2.0 / tau) * 60.0,
                          initial_attitude_sigma_deg=sigma0, initial_bias_sigma_deg_h=B,
                          initial_attitude_rpy_deg=[0.0, 0.0, 0.0])
    scn = scn.with_values("scenario", sensors=True)
    rng = np.random.default_rng(7)
    values = {"sensors.seed": np.arange(P) + 100, "plant.initial_attitude_rpy_deg": rng.normal(0.0, sigma0, (P, 3))}
    return scn, values


@pytest.fixture(scope="module", params=["mekf", "usque"])
def monte_carlo(request):
    """The consistent scenario's 50 runs with each filter: the MEKF, and the unscented filter of
    examples/custom_estimator (a plugin, on the same test)."""
    P = 50
    scn, values = _consistent_scenario(P)
    scn = scn.with_values("estimator", type=request.param)
    tr = simulate(scn, P, duration=20.0, episode_values=values, driver="stepwise")
    return scn, values, tr


@pytest.fixture(scope="module")
def replayed(monte_carlo):
    """The run's filter again, on the recorded truth, for its full covariance: the run-average NEES per step,
    whether each step's estimate is the run's, and the last step's estimate (with its covariance)."""
    scn, values, tr = monte_carlo
    P, K1 = tr.q_BN.shape[:2]
    sensing = build_sensing(scn, P, values["sensors.seed"])
    nees, same = np.empty((K1,)), np.empty((K1,), bool)
    for k in range(K1):
        est, _ = sensing.step(k, tr.q_BN[:, k], tr.omega_BN_B[:, k])
        same[k] = np.array_equal(est.q_BN, tr.q_BN_est[:, k]) and np.array_equal(est.gyro_bias,
                                                                                  tr.gyro_bias_est[:, k])
        e = np.concatenate([attitude_error_B(est.q_BN, tr.q_BN[:, k]), tr.gyro_bias_true[:, k] - est.gyro_bias], 1)
        nees[k] = np.mean(np.einsum("pi,pi->p", e, np.linalg.solve(est.cov, e[..., None])[..., 0]))
    return nees, same, est


def test_filter_nees_lies_in_the_95_percent_chi_square_band(monte_carlo, replayed):
    _, _, tr = monte_carlo
    P = tr.q_BN.shape[0]
    nees, same, _ = replayed
    assert same.all()  # the run's filter, number for number
    lo, hi = stats.chi2.ppf([0.025, 0.975], 6 * P) / P
    # a consistent filter: the run-average NEES at a step lies in the band 95 % of the time; the steps are
    # correlated, so allow 90 %; and its mean over the run is the state's dimension, 6, within the band
    inside = np.mean((nees >= lo) & (nees <= hi))
    assert inside >= 0.90, (inside, lo, hi, nees.min(), nees.max())
    assert lo <= nees.mean() <= hi


def test_filter_beats_the_star_tracker_and_knows_its_error(monte_carlo, replayed):
    scn, _, tr = monte_carlo
    after = tr.t >= 5.0
    ake = attitude_error_B(tr.q_BN[:, after], tr.q_BN_est[:, after])
    rms = np.sqrt(np.mean(ake**2, axis=(0, 1)))
    sigma_st = np.array([5.0, 5.0, 40.0]) * ARCSEC
    assert np.all(rms < sigma_st), rms / ARCSEC
    # the filter's own 1-sigma agrees with the error it makes (within 20 % per axis over 50 runs)
    assert np.allclose(rms, np.sqrt(np.mean(tr.attitude_sigma[:, after] ** 2, axis=(0, 1))), rtol=0.2)
    # bias: barely observable in 20 s here (the gyro's 0.05 deg/sqrt(h) walk hides a 0.5 deg/h drift for about
    # (N / b)^2 = 36 s), so the filter's 1-sigma only starts down from its initial 0.5 deg/h (to 0.41 across the
    # boresight, 0.45 about it, where the tracker sees 8 times worse); the test below checks it converges
    P = tr.q_BN.shape[0]
    _, _, est = replayed
    to_deg_h = 3600.0 / DEG
    sigma_b = np.sqrt(np.diagonal(est.cov, axis1=1, axis2=2)[:, 3:]) * to_deg_h  # (P, 3)
    err_b = (tr.gyro_bias_true[:, -1] - tr.gyro_bias_est[:, -1]) * to_deg_h
    initial = scn.param("estimator", "initial_bias_sigma_deg_h")
    assert np.all(sigma_b < 0.95 * initial), sigma_b.max(axis=0)  # the star tracker's reports did reach it
    # the final errors are what the filter says: over 50 independent runs x 3 axes their normalised squares
    # sum to a chi-square of 150 degrees of freedom, inside its two-sided 99 % band (126.9 here)
    lo_b, hi_b = stats.chi2.ppf([0.005, 0.995], 3 * P)
    assert lo_b <= np.sum((err_b / sigma_b) ** 2) <= hi_b, np.sum((err_b / sigma_b) ** 2)
    # and inside its initial uncertainty: RMS over runs and axes 0.39 deg/h here
    assert np.sqrt(np.mean(err_b**2)) < initial, np.sqrt(np.mean(err_b**2, axis=0))


def test_the_bias_estimate_converges_to_a_constant_gyro_bias():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    bias = np.array([3.0, -2.0, 1.0])  # deg/h
    scn = scn.with_values("sensors", **{"gyro.bias_deg_h": list(bias), "gyro.bias_instability_deg_h": 0.0})
    scn = scn.with_values("estimator", initial_bias_sigma_deg_h=5.0)
    scn = scn.with_values("scenario", feedback="estimate")
    tr = simulate(scn, 1, duration=120.0)
    sensing = build_sensing(scn, 1)
    for k in range(tr.q_BN.shape[1]):  # the run's filter again, for its final covariance
        est, _ = sensing.step(k, tr.q_BN[:, k], tr.omega_BN_B[:, k])
    sigma_b = np.sqrt(np.diagonal(est.cov[0])[3:]) * 3600.0 / DEG  # deg/h
    err = tr.gyro_bias_est[0, -1] * 3600.0 / DEG - bias
    # from 5 deg/h of prior to the filter's bias-walk floor (about 0.06 deg/h with the default 0.01 deg/h/sqrt(h)),
    # and the error inside 3 of its sigmas: the estimate went to the true bias, not only somewhere stable
    assert np.all(sigma_b < 0.1), sigma_b
    assert np.all(np.abs(err) < 3.0 * sigma_b), (err, sigma_b)
    err_10s = tr.gyro_bias_est[0, 1000] * 3600.0 / DEG - bias
    assert np.linalg.norm(err) < 0.2 * np.linalg.norm(err_10s)


def test_truth_feedback_leaves_the_controller_as_it_was_and_estimate_feedback_closes_on_the_filter():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    plain = simulate(scn, 1, duration=5.0)
    sensed = simulate(scn.with_values("scenario", sensors=True), 1, duration=5.0)
    assert np.array_equal(plain.u_cmd, sensed.u_cmd) and np.array_equal(plain.q_BN, sensed.q_BN)
    assert plain.q_BN_est is None and sensed.q_BN_est is not None
    closed = simulate(scn.with_values("scenario", feedback="estimate"), 1, duration=5.0)
    assert not np.array_equal(plain.u_cmd, closed.u_cmd)
    # the loop reads the estimate: the PID's command at step 0 is what it gives on the filter's output
    from attitude_sil.core.sim.build import build_controller
    ctrl = build_controller(scn, 1)
    u0 = ctrl.compute(closed.q_BN_est[:, 0], closed.omega_BN_B_est[:, 0], closed.q_RN[:, 0], closed.omega_RN_R[:, 0],
                      0)
    assert np.array_equal(u0, closed.u_cmd[:, 0])
    # and it flies the 1 deg roll step as the truth-fed loop does, to arcseconds (the filter's error)
    assert np.degrees(2 * closed.q_BN[0, -1, 0]) == pytest.approx(np.degrees(2 * plain.q_BN[0, -1, 0]), abs=2e-3)


def test_the_filter_drops_a_report_older_than_it_keeps_and_refuses_one_from_the_future():
    s = MekfSettings(gyro_arw=1e-5, bias_walk=1e-8, star_tracker_sigma=(1e-5,) * 3,
                     initial_q_BN=np.array([0.0, 0.0, 0.0, 1.0]), initial_attitude_sigma=1e-3,
                     initial_bias_sigma=1e-6)
    f = Mekf(s, 0.01, 1, latency_steps=2)
    for k in range(5):
        f.step(k, np.zeros((1, 3)))
    turned = np.array([[0.0, 0.0, np.sin(5e-4), np.cos(5e-4)]])  # 1 mrad about z: an update would move it
    before = f.step(5, np.zeros((1, 3)), StarTrackerReport(1, turned, True))
    assert f.dropped == 1 and np.array_equal(before.q_BN, [[0.0, 0.0, 0.0, 1.0]])  # no update
    after = f.step(6, np.zeros((1, 3)), StarTrackerReport(4, turned, True))  # 2 steps back: kept
    assert f.dropped == 1 and after.q_BN[0, 2] > 1e-4
    with pytest.raises(ScenarioError, match="a star tracker report at step 7 of exposure step 8, after it"):
        f.step(7, np.zeros((1, 3)), StarTrackerReport(8, turned, True))


def test_a_star_tracker_off_the_control_grid_is_refused_in_one_line():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    with pytest.raises(ScenarioError, match="latency_s = 0.015 s is not a whole number of control steps"):
        scn.with_values("sensors", **{"star_tracker.latency_s": 0.015}).with_values("scenario", sensors=True)
    with pytest.raises(ScenarioError, match="outages_s must hold"):
        scn.with_values("sensors", **{"star_tracker.outages_s": [3.0]}).with_values("scenario", sensors=True)


def test_a_sensor_campaign_disperses_seeds_and_bias_and_each_run_reruns_alone():
    from attitude_sil.core.sim.engine import simulate_summary
    from attitude_sil.tuning.montecarlo import load_mc_spec, run_chunk, run_of, summarize_campaign

    spec = load_mc_spec(CONFIG / "mc_hst_roll_step_sensors.yaml", runs=4, overrides={"set.plant.duration": 12.0})
    table = run_chunk(spec, 0, 4)
    assert np.array_equal(table["sensors.seed"], spec.scenario.param("sensors", "seed") + np.arange(4))
    assert np.std(table["sensors.gyro.bias_deg_h[0]"]) > 0.1  # 1 deg/h 1-sigma, four draws
    for col in ("ape_rms_x_rad", "ake_rms_x_rad", "ake_p99_z_rad"):
        assert np.all(np.isfinite(table[col])) and np.all(table[col] > 0), col
    assert len(set(table["ake_rms_x_rad"])) == 4  # four noise draws, four figures
    # run 2 alone (its scenario with its values set) gives what it gave in the batch of four
    alone = simulate_summary(run_of(spec, 2), 1)
    assert alone.metrics["ake_rms_x_rad"][0] == pytest.approx(table["ake_rms_x_rad"][2], rel=1e-12)
    summary = summarize_campaign(spec, table, False)
    assert set(summary["metrics"]["ake_rms_x_rad"]) >= {"p50", "p90", "p99"}
