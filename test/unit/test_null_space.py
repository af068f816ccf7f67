"""Null-space wheel-speed management (issue 43, redundancy): the wheels' speeds along the null vector go to a
target as a designed first order, and make no body torque.

HST's pyramid has one free direction, n = (-1/2, 1/2, -1/2, 1/2): wheel
speeds along n store no momentum in the body. The loop drives s = n . omega_w
to its target with the voltage e = n ((K_b + R B / K_i) s* + k_v (s* - s)),
k_v = R J / (K_i tau) - K_b - R B / K_i, which makes J s' = (K_i (K_b + k_v) /
R + B) (s* - s): a first order of time constant tau, the motor's inductance
(L/R = 1 ms) aside; under a torque command (the geometric law) the loop adds
J (s* - s) / tau of wheel torque before the inverse motor model, the same
first order. Checked on HST holding its attitude (no step, so no drive limit
clips the loop), under both: the body torque with and without the loop
agrees to 1e-12 N m in both drivers, and s reaches 63.2 % of its target at tau within
5 %, at the control step and at half of it.
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.core.plant.actuators import RPM
from attitude_sil.core.plant.wheels import GEOMETRIES, allocation_over, null_vector
from attitude_sil.core.sim.build import build_wheels
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError

PYRAMID = GEOMETRIES["hst_pyramid"]()
TARGET_RPM = 20.0  # small enough that no drive limit clips the loop (the pyramid's 0.8 N m per wheel)


def _holding(law: str = "pid", **wheels):
    """HST holding its attitude under ``law`` (pid commands volts, geometric torque)."""
    scn = load_scenario(default_config_dir() / "hst_roll_step.yaml").with_values("guidance", setpoint_rpy_deg=[0, 0, 0])
    scn = scn.with_values("controller", controller_type=law)
    return scn.with_values("wheels", **wheels) if wheels else scn


def test_the_pyramids_null_vector_is_the_issues_and_other_sets_have_none():
    n = null_vector(PYRAMID, allocation_over(PYRAMID))
    np.testing.assert_allclose(n, [-0.5, 0.5, -0.5, 0.5], atol=1e-15)
    assert np.max(np.abs(PYRAMID @ n)) <= 1e-15
    assert not np.any(null_vector(PYRAMID, allocation_over(PYRAMID, [1, 2, 3])))  # three wheels: no free direction
    ortho = GEOMETRIES["orthogonal"]()
    assert not np.any(null_vector(ortho, allocation_over(ortho)))
    scn = load_scenario(default_config_dir() / "hst_roll_step.yaml").with_values("wheels", geometry="orthogonal")
    with pytest.raises(ScenarioError, match="no null space"):
        build_wheels(scn.with_values("wheels", **{"null_space.time_constant_s": 2.0}), 1)


@pytest.mark.parametrize("driver, law", [("compiled", "pid"), ("stepwise", "pid"), ("stepwise", "geometric")])
def test_the_null_space_loop_moves_no_body_torque(driver, law):
    loop = {"null_space.time_constant_s": 2.0, "null_space.speed_rpm": TARGET_RPM}
    off, on = (simulate(s, 1, duration=10.0, driver=driver) for s in (_holding(law), _holding(law, **loop)))
    assert np.max(np.abs(on.tau_c_B - off.tau_c_B)) <= 1e-12
    assert np.max(np.abs(on.h_wheels_B - off.h_wheels_B)) <= 1e-12
    assert np.max(np.abs(on.q_BN - off.q_BN)) <= 1e-12
    n = null_vector(PYRAMID, allocation_over(PYRAMID))
    assert on.wheel_speed[0, -1] @ n > 0.99 * TARGET_RPM * RPM  # while the wheels did move


def test_both_drivers_fly_the_loop_bit_for_bit():
    scn = _holding(**{"null_space.time_constant_s": 1.0, "null_space.speed_rpm": -TARGET_RPM})
    runs = [simulate(scn, 2, duration=3.0, driver=d) for d in ("compiled", "stepwise")]
    for name in ("q_BN", "wheel_speed", "tau_c_B"):
        np.testing.assert_array_equal(getattr(runs[0], name), getattr(runs[1], name), err_msg=name)


@pytest.mark.parametrize("law, tau, dt", [("pid", 1.0, 0.01), ("pid", 2.0, 0.01), ("pid", 4.0, 0.01),
                                          ("pid", 2.0, 0.005), ("geometric", 2.0, 0.01), ("geometric", 4.0, 0.01)])
def test_the_null_space_speed_reaches_its_target_as_the_designed_first_order(law, tau, dt):
    scn = _holding(law, **{"null_space.time_constant_s": tau, "null_space.speed_rpm": TARGET_RPM})
    scn = scn.with_values("/**", control_period=dt)
    tr = simulate(scn, 1, duration=3.0 * tau, driver="stepwise")
    s = tr.wheel_speed[0] @ null_vector(PYRAMID, allocation_over(PYRAMID))
    target = TARGET_RPM * RPM
    first = int(np.argmax(s >= (1.0 - np.exp(-1.0)) * target))
    t63 = np.interp((1.0 - np.exp(-1.0)) * target, s[first - 1:first + 1], tr.t[first - 1:first + 1])
    assert t63 == pytest.approx(tau, rel=0.05)
    assert s[-1] == pytest.approx(target * (1.0 - np.exp(-3.0)), rel=0.02)  # still the first order at 3 tau
