"""Sensor and rod faults (issue 43's table): a gyro axis off, stuck, with a bias jump, a scale or a spike; a
star tracker frozen; a magnetometer off or stuck; the magnetorquers off or stuck (the last on B-dot's
detumbling cube, against the run without the fault: no torque in the window, or the dipole of the step before
crossed with the field).

The reference for each mode is the same run without the fault: flown on the
truth (``feedback: truth``), the body moves alike, so the faulted run's
readings are the fault applied to the nominal run's, on its axis and in its
window, and equal to them, bit for bit, everywhere else. The filter is not
told: flown on its estimate, a 36 deg/h bias jump on z is taken into the
filter's bias estimate on z (most of it within 50 s; the MEKF's bias gain sets
the pace) while x and y stay where they were. The star tracker and the
magnetometer are checked on their own suite, against the same suite without
the fault: a frozen tracker reports its last attitude again, as valid, for
the exposures of its window; a magnetometer off reads 0, a stuck one its
reading of the step before.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from attitude_sil.core.plant.quaternion import quat_from_euler
from attitude_sil.core.sensing.models import SensorSuite
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError

CONFIG = default_config_dir()
K0 = 100  # the faults start at 1 s: step 100 of 10 ms


@pytest.fixture(scope="module")
def on_truth():
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml").with_values("scenario", feedback="truth")
    return scn, simulate(scn, 2, duration=2.0).omega_BN_B_meas


@pytest.mark.parametrize("fault, expected", [
    ("gyro.x scale 1.5 at 1 for 0.5", lambda w: 1.5 * w),
    ("gyro.x bias_jump 36 at 1 for 0.5", lambda w: w + math.radians(36.0) / 3600.0),
    ("gyro.x off at 1 for 0.5", lambda w: 0.0 * w),
])
def test_a_gyro_fault_is_its_mode_on_its_axis_in_its_window(on_truth, fault, expected):
    scn, nominal = on_truth
    meas = simulate(scn.with_values("sensors", faults=[fault]), 2, duration=2.0).omega_BN_B_meas
    window = slice(K0, K0 + 50)
    np.testing.assert_array_equal(meas[:, window, 0], expected(nominal[:, window, 0]))
    outside = np.ones(meas.shape[1], dtype=bool)
    outside[window] = False
    np.testing.assert_array_equal(meas[:, outside], nominal[:, outside])
    np.testing.assert_array_equal(meas[:, :, 1:], nominal[:, :, 1:])


def test_a_stuck_axis_holds_the_reading_before_and_a_spike_is_one_reading(on_truth):
    scn, nominal = on_truth
    stuck = simulate(scn.with_values("sensors", faults=["gyro.y stuck at 1"]), 2, duration=2.0).omega_BN_B_meas
    assert np.all(stuck[:, K0:, 1] == nominal[:, K0 - 1, 1][:, None])
    np.testing.assert_array_equal(stuck[:, :K0], nominal[:, :K0])
    spike = simulate(scn.with_values("sensors", faults=["gyro.z spike 2 at 1"]), 2, duration=2.0).omega_BN_B_meas
    diff = spike - nominal
    np.testing.assert_allclose(diff[:, K0, 2], math.radians(2.0), rtol=1e-12)
    diff[:, K0, 2] = 0.0
    assert not np.any(diff)


def test_the_filter_takes_a_bias_jump_into_its_bias_estimate_on_that_axis():
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml")  # on the estimate: the filter is not told
    nominal, jumped = (simulate(s, 1, duration=60.0) for s in (scn, scn.with_values(
        "sensors", faults=["gyro.z bias_jump 36 at 10"])))
    moved = np.degrees(jumped.gyro_bias_est[0] - nominal.gyro_bias_est[0]) * 3600.0  # deg/h
    assert np.all(moved[:1000] == 0.0)  # nothing before the jump
    assert 0.6 * 36.0 < moved[5990, 2] < 1.05 * 36.0  # most of it within 50 s, none beyond
    assert np.max(np.abs(moved[:, :2])) < 0.01 * 36.0


def _suite_readings(faults: list[str]):
    """The star tracker's reports (exposure step, q (4,), valid) and the magnetometer's readings (K, 3) of a
    suite of the sensors preset flown over 3 s of a turning body in a turning field."""
    values = load_scenario(CONFIG / "hst_roll_step_sensors.yaml").with_values("sensors", faults=faults)
    suite = SensorSuite(values.values["sensors"], 0.01, 1)
    reports, mag = [], []
    for k in range(300):
        t = 0.01 * k
        q = quat_from_euler(np.array([0.01 * t, 0.002 * t * t, -0.005 * t]))[None]
        r = suite.sample(q, np.zeros((1, 3)), k).star_tracker
        if r is not None:
            reports.append((r.exposure_step, r.q_BN[0].copy(), r.valid))
        mag.append(suite.magnetometer.sample(np.array([[2e-5 + 1e-7 * k, -1e-5, 3e-5 * np.cos(t)]]), k)[0])
    return reports, np.array(mag)


def test_a_frozen_star_tracker_reports_its_last_attitude_as_valid_through_its_window():
    nominal, _ = _suite_readings([])
    frozen, _ = _suite_readings(["star_tracker stuck at 1 for 1"])
    assert [r[0] for r in frozen] == [r[0] for r in nominal] and all(r[2] for r in frozen)
    last = [r for r in nominal if r[0] < 100][-1][1]  # the exposure at 0.9 s
    for (j, q, _), (_, q_n, _) in zip(frozen, nominal, strict=True):
        np.testing.assert_array_equal(q, last if 100 <= j < 200 else q_n)
    assert any(not np.array_equal(q, last) for j, q, _ in nominal if 100 <= j < 200)  # the body turned meanwhile


def test_a_magnetometer_off_reads_zero_and_a_stuck_one_its_reading_before():
    _, nominal = _suite_readings([])
    _, off = _suite_readings(["magnetometer off at 1 for 0.5"])
    _, stuck = _suite_readings(["magnetometer stuck at 2"])
    np.testing.assert_array_equal(off[100:150], 0.0)
    np.testing.assert_array_equal(np.delete(off, np.s_[100:150], axis=0), np.delete(nominal, np.s_[100:150], axis=0))
    np.testing.assert_array_equal(stuck[200:], np.broadcast_to(nominal[199], (100, 3)))
    np.testing.assert_array_equal(stuck[:200], nominal[:200])


def test_magnetorquers_off_make_no_torque_and_stuck_ones_hold_the_dipole_of_the_step_before():
    scn = load_scenario(CONFIG / "cubesat_1u_detumble.yaml")  # B-dot on the rods, 0.1 s steps
    nominal = simulate(scn, 1, duration=20.0)
    off = simulate(scn.with_values("magnetorquers", faults=["magnetorquers off at 5 for 5"]), 1, duration=20.0)
    window = slice(50, 100)
    np.testing.assert_array_equal(off.magnetic_torque_B[0, window], 0.0)
    np.testing.assert_array_equal(off.magnetic_torque_B[0, :50], nominal.magnetic_torque_B[0, :50])
    assert np.max(np.abs(off.dipole_cmd_B[0, window])) > 0.01  # the law still commands: the rods do not make it
    stuck = simulate(scn.with_values("magnetorquers", faults=["magnetorquers stuck at 5"]), 1, duration=20.0)
    made = np.cross(nominal.dipole_cmd_B[0, 49], stuck.magnetic_field_B[0, 50:])  # m(4.9 s) x B(t), rods unclipped
    np.testing.assert_allclose(stuck.magnetic_torque_B[0, 50:], made, rtol=1e-12, atol=1e-18)
    with pytest.raises(ScenarioError, match="the magnetorquers do not fly in this run"):
        load_scenario(CONFIG / "hst_roll_step.yaml").with_values("magnetorquers", faults=["magnetorquers off"])


def test_a_slow_star_tracker_reports_older_exposures_at_the_same_steps():
    # the preset's tracker: an exposure every 10 steps, reported 10 steps later; 0.3 s more from 1 s to 2 s
    nominal, _ = _suite_readings([])
    slow, _ = _suite_readings(["star_tracker latency 0.3 at 1 for 1"])
    of = {j: q for j, q, _ in nominal}
    k = [j + 10 for j, _, _ in nominal]  # the report steps, the same with the fault
    assert [(r[0], r[2]) for r in slow] == [
        (s - 10, True) if s < 100 or s >= 200 else (s - 10, False) if s < 130 else (s - 40, True) for s in k]
    for j, q, valid in slow:
        if valid:  # the exposure's own attitude and noise, however late it comes
            np.testing.assert_array_equal(q, of[j])
    # at 2 s the tracker reports its newest exposure (1.9 s): 1.6, 1.7 and 1.8 s are never reported
    assert sorted({r[0] for r in slow if r[2]} ^ {r[0] for r in nominal}) == [160, 170, 180]


def test_a_filter_that_keeps_the_older_reports_flies_a_slow_tracker_as_one_that_always_was():
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml")  # latency 0.1 s, flown on the estimate
    slow = simulate(scn.with_values("sensors", faults=["star_tracker latency 0.3"])
                    .with_values("estimator", **{"star_tracker.max_age_s": 0.4}), 1, duration=5.0)
    always = simulate(scn.with_values("/**", **{"star_tracker.latency_s": 0.4}), 1, duration=5.0)
    nominal = simulate(scn, 1, duration=5.0)
    for name in ("q_BN", "q_BN_est", "attitude_sigma"):
        np.testing.assert_array_equal(getattr(slow, name), getattr(always, name))
    assert np.max(np.abs(slow.q_BN_est - nominal.q_BN_est)) > 1e-9  # the latency shows


def test_a_filter_that_keeps_only_the_latency_drops_a_slow_trackers_reports():
    # reports at 1.0 ... 1.9 s carry exposures 0.6 ... 1.5 s (the first three nothing new), all older than the
    # filter's 0.1 s: to the filter, the tracker is off for the exposures it would have reported then
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml")
    slow = simulate(scn.with_values("sensors", faults=["star_tracker latency 0.3 at 1 for 1"]), 1, duration=3.0)
    off = simulate(scn.with_values("sensors", faults=["star_tracker off at 0.9 for 1"]), 1, duration=3.0)
    for name in ("q_BN", "q_BN_est", "attitude_sigma"):
        np.testing.assert_array_equal(getattr(slow, name), getattr(off, name))
    with pytest.raises(ScenarioError, match="star_tracker latency = 0.005 s is not a whole number of control steps"):
        SensorSuite(scn.with_values("sensors", faults=["star_tracker latency 0.005"]).values["sensors"], 0.01)
