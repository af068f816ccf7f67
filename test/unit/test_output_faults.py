"""The controller output's faults (issue 43): ``controller gain K`` and ``controller delay D``.

Checked against references of their own kind:

* the stage itself on a known command sequence: ``g u[k - d]`` inside each
  fault's window, the command before the record where ``k - d < 0``;
* a gain of 2 on the output is the PID with its three gains doubled, bit for
  bit (a product by 2 is exact, and the 1 deg step never reaches the output
  limit);
* the compiled loop flies both faults as the stepwise driver does, bit for bit;
* the margins of the sampled loop (``attitude_sil.tuning.margins``, python-control
  on ``roll_loop``'s linearised model, zero-order hold, the package's discrete
  PID): the HST roll loop decays at 0.98 x its gain margin and grows at 1.02 x,
  decays at a delay 2 % under its delay margin (PM / w_c) and grows 2 % over.
  The issue asks for 5 %; the runs start 1e-4 and 1e-3 deg off, where the wheels
  stay far from their 0.8 N m limit, so the nonlinear loop is the linear one to
  second order in the amplitude and 2 % is a margin of several times the growth
  per window measured at the threshold (the delay's threshold lies between 111
  and 112 steps of 10 ms; the linear margin says 111.5);
* refusals: a controller fault with no reaction wheels (a delay that is not
  whole steps, a negative gain, two gains: the fault list's one-line refusals,
  test_faults.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.core.faults import parse_fault
from attitude_sil.core.plant.command_faults import command_fault_record, command_fault_rows
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError
from attitude_sil.tuning.margins import loop_margins, sampled_pid_loop

CONFIG = default_config_dir()
DT_NS = 10_000_000


def test_the_stage_applies_the_gain_and_reads_the_command_d_steps_back_inside_each_window():
    faults = [parse_fault("controller gain 3 at 0.05 for 0.04"), parse_fault("controller delay 0.02 at 0.03")]
    cf = command_fault_record(faults, DT_NS, 2, held=np.array([[7.0, 7.0, 7.0], [-7.0, -7.0, -7.0]]))
    applied = []
    for k in range(12):
        u = np.array([[k, 2 * k, 3 * k], [-k, 0.0, 1.0]], dtype=float)
        out = np.empty_like(u)
        command_fault_rows(u, k, cf, out)
        applied.append(out[:, 0].copy())
    applied = np.array(applied)
    expected = []
    for k in range(12):
        j = k - 2 if k >= 3 else k  # the delay from step 3 on
        g = 3.0 if 5 <= k < 9 else 1.0  # the gain for 0.04 s from step 5
        expected.append([g * j, -g * j])
    np.testing.assert_array_equal(applied, np.array(expected))
    late = command_fault_record([parse_fault("controller delay 0.05")], DT_NS, 1, held=np.array([[7.0, 8.0, 9.0]]))
    out = np.empty((1, 3))
    command_fault_rows(np.ones((1, 3)), 0, late, out)
    np.testing.assert_array_equal(out, [[7.0, 8.0, 9.0]])  # before the record: the command applied before it


def test_a_gain_of_2_is_the_pid_with_its_gains_doubled_bit_for_bit():
    base = load_scenario(CONFIG / "hst_roll_step.yaml")
    faulty = base.with_values("wheels", faults=["controller gain 2"])
    c = base.values["controller"]
    doubled = base.with_values("controller", **{f"pid.{g}": [2.0 * x for x in c[f"pid.{g}"]]
                                                for g in ("kp", "ki", "kd")})
    a, b = (simulate(s, 1, duration=5.0, driver="stepwise") for s in (faulty, doubled))
    for name in ("q_BN", "omega_BN_B", "wheel_speed"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(2.0 * a.u_cmd, b.u_cmd)  # the record keeps the law's command, not the applied
    assert not np.array_equal(a.q_BN, simulate(base, 1, duration=5.0, driver="stepwise").q_BN)


def test_both_drivers_fly_gain_and_delay_alike():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values(
        "wheels", faults=["controller delay 0.3 at 0.5", "controller gain 0.5 at 1 for 1.5"])
    a, b = (simulate(scn, 2, duration=4.0, driver=d) for d in ("compiled", "stepwise"))
    for name in ("q_BN", "wheel_speed", "tau_c_B", "u_cmd"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _growth(scn, fault: str, duration: float, window_s: float) -> float:
    """Peak |roll rate| over the run's last window over the same peak two windows in (a ratio > 1: growing)."""
    tr = simulate(scn.with_values("wheels", faults=[fault]), 1, duration=duration, driver="stepwise")
    n = int(round(window_s / 0.01))
    w = np.abs(tr.omega_BN_B[0, :, 0])
    return float(np.max(w[-n:]) / np.max(w[2 * n:3 * n]))


@pytest.fixture(scope="module")
def hst_margins():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    return scn, loop_margins(sampled_pid_loop(scn, 0))


def test_the_loop_goes_unstable_at_the_sampled_loops_gain_margin(hst_margins):
    scn, m = hst_margins
    assert 100.0 < m["gain_margin"] < 160.0 and 15.0 < m["phase_crossover_rad_s"] < 25.0  # the sampled PID's
    small = scn.with_values("guidance", setpoint_rpy_deg=[1e-4, 0.0, 0.0])
    below, above = (_growth(small, f"controller gain {r * m['gain_margin']:.9g}", 10.0, 1.0) for r in (0.98, 1.02))
    assert below < 0.9 and above > 1.1, (below, above)


def test_the_loop_goes_unstable_at_the_delay_that_uses_up_its_phase_margin(hst_margins):
    scn, m = hst_margins
    steps = m["delay_margin_s"] / 0.01
    assert m["delay_margin_s"] == pytest.approx(np.radians(m["phase_margin_deg"]) / m["gain_crossover_rad_s"])
    small = scn.with_values("guidance", setpoint_rpy_deg=[1e-3, 0.0, 0.0])
    below, above = (_growth(small, f"controller delay {round(r * steps) * 0.01:.2f}", 100.0, 10.0)
                    for r in (0.98, 1.02))
    assert below < 0.9 and above > 1.1, (below, above)


def test_an_output_fault_needs_reaction_wheels():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels", actuator="torque")
    with pytest.raises(ScenarioError, match="acts on the reaction wheels' command"):
        scn.with_values("wheels", faults=["controller gain 2"])
