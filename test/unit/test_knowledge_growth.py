"""A blinded star tracker: the attitude-knowledge error grows as gyro error propagation says (issue 43).

HST's sensors preset (navigation-grade gyro: angle random walk N = 0.07
deg/sqrt(h), a Gauss-Markov bias of B = 1 deg/h and tau_c = 300 s; a 10 Hz
tracker) flies 300 runs, each with its own sensor seed, on the truth. At
t0 = 40 s the fault ``star_tracker off at 40`` blinds the tracker and the
MEKF propagates on the gyro alone, its bias estimate held. The knowledge error
per body axis, theta (rotation vector of q_true^-1 q_est, small), then obeys

    theta(t0 + tau) = theta0 + beta0 tau + b0 (L - tau) + int w + int n

with beta0 = b(t0) - b_est(t0), b0 = b(t0), L = tau_c (1 - exp(-tau / tau_c))
(the bias relaxes toward 0), w the Gauss-Markov bias's own innovation, of
integrated variance B^2 tau_c^2 (2x - 3 + 4 e^-x - e^-2x), x = tau / tau_c,
and n the white rate noise, of integrated variance N^2 tau. The reference:
the mean square over the runs and axes of the first three terms (the
knowledge and bias-knowledge errors at t0, as the runs had them) plus the two
variances, from the gyro's datasheet numbers. Over 900 samples a measured RMS
has a sampling error of about 2.4 %: the 10 % the issue sets is four of them.
Without the random walk, or without the bias terms, the reference is more
than 10 % off: each term is needed.
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.core.plant.quaternion import quat_conjugate, quat_multiply
from attitude_sil.core.sensing.models import GyroErrors
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario

T0, TAU_END, RUNS = 40.0, 60.0, 300
TAUS = (15.0, 30.0, 45.0, 60.0)


@pytest.fixture(scope="module")
def blinded():
    scn = load_scenario(default_config_dir() / "hst_roll_step_sensors.yaml")
    scn = scn.with_values("scenario", feedback="truth").with_values("plant", duration=T0 + TAU_END)
    scn = scn.with_values("sensors", faults=[f"star_tracker off at {T0:g}"])
    tr = simulate(scn, RUNS, duration=T0 + TAU_END, driver="stepwise",
                  episode_values={"sensors.seed": np.arange(1, RUNS + 1)})
    dq = quat_multiply(quat_conjugate(tr.q_BN), tr.q_BN_est)
    theta = 2.0 * dq[..., :3] * np.sign(dq[..., 3:4])  # (P, K+1, 3) rad, body axes
    return scn, tr, theta


def _reference(gyro: GyroErrors, theta0, beta0, b0, tau: float, arw: bool = True, bias: bool = True) -> float:
    """Mean square knowledge error (rad^2) tau s into the outage, by gyro error propagation."""
    tc, x = gyro.correlation_time, tau / gyro.correlation_time
    lag = tc * (1.0 - np.exp(-x)) - tau
    start = theta0 + (beta0 * tau + b0 * lag if bias else 0.0)
    drift = gyro.bias_instability**2 * tc**2 * (2 * x - 3 + 4 * np.exp(-x) - np.exp(-2 * x)) if bias else 0.0
    return float(np.mean(start**2) + drift + (gyro.arw**2 * tau if arw else 0.0))


def test_the_knowledge_error_of_a_blinded_tracker_grows_as_gyro_error_propagation_says(blinded):
    scn, tr, theta = blinded
    gyro = GyroErrors.from_values(scn.values["sensors"])
    k0 = int(round(T0 / scn.dt))
    theta0, b0 = theta[:, k0], tr.gyro_bias_true[:, k0]
    beta0 = b0 - tr.gyro_bias_est[:, k0]
    assert np.std(theta0[:, 0]) > 0.0  # the runs are independent draws, not one run 300 times
    rows = []
    for tau in TAUS:
        k = k0 + int(round(tau / scn.dt))
        measured = np.sqrt(np.mean(theta[:, k] ** 2))
        rows.append((tau, measured, np.sqrt(_reference(gyro, theta0, beta0, b0, tau)),
                     np.sqrt(_reference(gyro, theta0, beta0, b0, tau, arw=False)),
                     np.sqrt(_reference(gyro, theta0, beta0, b0, tau, bias=False))))
    for tau, measured, full, _, _ in rows:
        assert measured == pytest.approx(full, rel=0.10), (tau, measured, full)
    assert max(abs(m / a - 1.0) for _, m, _, a, _ in rows) > 0.10  # the random walk is needed
    assert max(abs(m / b - 1.0) for _, m, _, _, b in rows) > 0.10  # and so are the bias terms
    assert rows[-1][1] > 10.0 * np.sqrt(np.mean(theta0**2))  # the error grew: the tracker was blind
    # the filter knew: its own 1-sigma at the end is the spread the runs show, within the same 10 %
    assert np.sqrt(np.mean(tr.attitude_sigma[:, -1] ** 2)) == pytest.approx(rows[-1][1], rel=0.10)
