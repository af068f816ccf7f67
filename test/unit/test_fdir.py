"""The wheels' FDIR (issue 43, item 3): detect on the tachometer, isolate, reallocate.

Checked against references of their own kind:

* the observer's design: with the count's quantisation made negligible, a
  wheel whose angle departs from the model's by a constant acceleration ``a``
  leaves the closed-form steady residual ``a dt^2 / (1 - p)^2`` (p the double
  pole), to 1e-9 relative;
* a healthy assembly's residual is the count's quantisation only: within one
  count of the tachometer through the whole roll step under both the PID
  (whose wheels reach their 0.8 N m drive limit, which the model flies too)
  and the geometric law, nothing is isolated, and the run is the run without
  an FDIR, bit for bit;
* the isolation is the persistence rule: the step it isolates at ends the
  first run of ``persistence`` steps over the threshold in the residual trace;
* a torque-limited drive holds its motor torque to the limit (issue 43's row,
  wheel 1 lost at 2 s with the FDIR and reallocation: test_wheel_failure_preset.py);
* the Monte Carlo report on a hand-made table: detections, misses, false
  alarms and latency counted as defined.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from attitude_sil.cli.format import format_campaign
from attitude_sil.core.plant.fdir import WheelFdir, fdir_report, tachometer_angle
from attitude_sil.core.plant.lanes import ANGLE, SPEED
from attitude_sil.core.sim.build import build_wheels
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.tuning.executor import InProcess
from attitude_sil.tuning.montecarlo import load_mc_spec, run_campaign

CONFIG = default_config_dir()
FDIR = {"fdir.enabled": True}


def _steady_residual(dt: float, a: float, bandwidth: float) -> tuple[float, float]:
    """(the FDIR's residual on a wheel taking an extra torque J a the model does not know, after 30 s with no
    quantisation; the continuous observer's closed form a / (w^2 + 2 w / tau_m))."""
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("/**", control_period=dt)
    assembly = build_wheels(scn, 1).assembly
    fdir = WheelFdir(assembly, 1, 2**52, 1.0, 10, bandwidth)  # a count of 1.4e-15 rad: no quantisation
    x = assembly.initial_state(1)
    fdir.reset(x)
    cmd = np.array([[0.3, -0.2, 0.1]])
    for k in range(int(round(30.0 / dt))):
        fdir.check(k, x)
        model_next, _, _ = assembly.nominal().advance(fdir.x_hat, cmd, False, k, fdir.isolation())
        x, _, _ = assembly.advance(x, cmd, False, k)
        x[0, 0, ANGLE] += 0.5 * a * dt * dt  # wheel 1's extra torque, over the step
        x[0, 0, SPEED] += a * dt
        fdir.predict(cmd, False, k)
        np.testing.assert_array_equal(fdir.x_hat, model_next)  # the prediction is the nominal motor's step
    assert np.all(np.abs(fdir.residual[0, 1:]) < 1e-12)  # the others follow their model exactly
    m = assembly.motor
    inv_tau = m.torque_constant * m.back_emf_constant / (m.resistance * m.rotor_inertia) \
        + m.viscous_friction / m.rotor_inertia  # the motor's mechanical pole, 1/s
    return float(fdir.residual[0, 0]), a / (bandwidth**2 + 2.0 * bandwidth * inv_tau)


def test_an_unmodelled_wheel_torque_leaves_the_observers_closed_form_residual_as_the_step_shrinks():
    # the continuous observer (gains 2 w, w^2 on a motor of mechanical time constant tau_m) holds a constant
    # unmodelled acceleration a at e = a / (w^2 + 2 w / tau_m); the discrete one differs by O(w dt)
    coarse, closed = _steady_residual(0.01, 0.05, 2.0)
    fine, _ = _steady_residual(0.002, 0.05, 2.0)
    assert coarse == pytest.approx(closed, rel=0.03)  # w dt = 0.02
    assert abs(fine / closed - 1.0) < 0.3 * abs(coarse / closed - 1.0)  # first order in the step: 5x finer


@pytest.mark.parametrize("law", ["pid", "geometric"])
def test_a_healthy_assemblys_residual_is_within_a_count_and_nothing_is_isolated(law):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("controller", controller_type=law)
    tr = simulate(scn.with_values("wheels", **FDIR), 1, driver="stepwise")
    q = 2.0 * math.pi / scn.values["wheels"]["fdir.counts_per_rev"]
    assert np.max(np.abs(tr.fdir_residual)) < q
    if law == "pid":  # its step reaches the drive limit (0.8 N m), which the model flies too
        assert np.max(np.abs(tr.wheel_effort)) > 0.79
    assert not np.any(tr.fdir_isolated)
    nominal = simulate(scn, 1, driver="stepwise")
    np.testing.assert_array_equal(tr.q_BN, nominal.q_BN)  # a watching FDIR changes nothing


def test_the_tachometer_reads_the_middle_of_the_count():
    q = 2.0 * math.pi / 8
    np.testing.assert_allclose(tachometer_angle(np.array([0.0, 0.99 * q, q, -0.01 * q]), 8),
                               [0.5 * q, 0.5 * q, 1.5 * q, -0.5 * q], rtol=0, atol=1e-15)


def test_a_torque_limited_drive_holds_its_motor_torque_to_the_limit_in_both_drivers():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels",
                                                                   faults=["wheel2 torque_limit 0.1 at 0.5"])
    a, b = (simulate(scn, 1, duration=3.0, driver=d) for d in ("compiled", "stepwise"))
    np.testing.assert_array_equal(a.q_BN, b.q_BN)
    effort = np.abs(b.wheel_effort[0, :, 1])
    assert effort[:50].max() > 0.79 and effort[52:].max() <= 0.1  # (the current settles within the step)
    limited = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels", faults=["wheel2 speed_limit 1 at 0.2"])
    c = simulate(limited, 1, duration=3.0, driver="stepwise")
    s, limit = np.abs(c.wheel_speed[0, :, 1]), 1.0 * 2.0 * math.pi / 60.0
    above = s[21:-1] >= limit  # (the step at 0.2 s ends with the current it began with, L/R = 1 ms)
    assert s[21] > limit and np.all(np.diff(s[21:])[above] <= 1e-12)  # past its limit, no drive makes it faster
    assert np.any(s[21:] < limit)  # and it slows down through its limit


def test_the_campaign_report_counts_detections_misses_and_false_alarms():
    failed = [1, 2, 3, 0, 0, 4, 1]
    t_fail = [2.0, 3.0, 1.0, 0.0, 0.0, 5.0, 4.0]
    mode = ["lost", "stuck", "torque_limit", "lost", "lost", "lost", "stuck"]
    wheel = [1, 2, 0, 0, 3, 2, 1]  # detected, detected, missed, quiet, false alarm, wrong wheel, too early
    t_iso = [2.5, 4.0, np.nan, np.nan, 7.0, 6.0, 3.5]
    r = fdir_report(failed, t_fail, mode, wheel, t_iso, 10.0)
    assert (r["failed_runs"], r["detected"], r["missed"], r["false_alarms"]) == (5, 2, 1, 3)
    assert r["latency_s"]["max"] == pytest.approx(1.0) and r["latency_s"]["mean"] == pytest.approx(0.75)
    assert r["missed_by_mode"] == {"lost": 0, "stuck": 0, "torque_limit": 1}
    healthy_hours = (2 + 3 + 1 + 10 + 10 + 5 + 4) / 3600.0
    assert r["false_alarms_per_hour"] == pytest.approx(1 / healthy_hours)  # the one in a healthy run


def test_a_campaign_reports_its_fdir_figures_against_the_failures_it_drew(tmp_path):

    spec = load_mc_spec(CONFIG / "mc_hst_wheel_fdir.yaml", runs=12, overrides={"output": str(tmp_path / "mc")})
    with InProcess() as ex:
        result = run_campaign(spec, ex)
    t = result.table
    f = result.summary["fdir"]
    failed = t["wheels.failure.wheel"] > 0
    assert f["failed_runs"] == int(failed.sum()) > 0 and f["runs"] == 12
    detected = failed & (t["fdir_wheel"] == t["wheels.failure.wheel"])
    assert f["detected"] == int(detected.sum()) > 0 and f["false_alarms"] == 0
    lost = failed & (t["wheels.failure.mode"] == "lost")
    assert np.all(detected[lost])  # a lost wheel in the step is always found
    limited = t["wheels.failure.mode"] == "torque_limit"
    assert np.all((t["wheels.failure.value"][limited] >= 0.0) & (t["wheels.failure.value"][limited] <= 0.2))
    assert f"fdir: {f['detected']} of {f['failed_runs']} failures detected" in format_campaign(result.summary)


def test_a_seized_wheel_hands_its_momentum_to_the_body_which_keeps_the_total():
    from attitude_sil.core.plant.quaternion import quat_to_dcm

    base = load_scenario(CONFIG / "hst_roll_step.yaml")
    same = simulate(base.with_values("wheels", faults=["wheel2 friction 1 at 0.5"]), 1, duration=1.0,
                    driver="compiled")
    np.testing.assert_array_equal(same.q_BN, simulate(base, 1, duration=1.0, driver="compiled").q_BN)
    # wheel 1 at 300 rpm seizes at 2 s: B x 1e5 = 10 N m s/rad on its 0.84 kg m^2
    scn = base.with_values("wheels", initial_speed_rpm=[300.0, 0.0, 0.0, 0.0], faults=["wheel1 friction 1e5 at 2"])
    a, b = (simulate(scn, 1, duration=4.0, driver=d) for d in ("compiled", "stepwise"))
    np.testing.assert_array_equal(a.wheel_speed, b.wheel_speed)
    w1 = np.abs(b.wheel_speed[0, :, 0])
    # it stops but for what its drive, at its 0.8 N m current limit, holds against the bearing: 0.8 / 10 rad/s
    assert w1[199] > 29.0 and w1[399] == pytest.approx(0.8 / 10.0, rel=1e-6)
    inertia = np.diag(scn.values["plant"]["inertia"])
    h_N = np.einsum("kij,kj->ki", quat_to_dcm(b.q_BN[0]), b.omega_BN_B[0] @ inertia.T + b.h_wheels_B[0])
    assert np.max(np.abs(h_N - h_N[0])) < 1e-9 * np.linalg.norm(h_N[0])  # no external torque: the total stays
    assert np.max(np.abs(b.omega_BN_B[0, 250:])) > 10.0 * np.max(np.abs(b.omega_BN_B[0, 150:199]))  # the body took it
