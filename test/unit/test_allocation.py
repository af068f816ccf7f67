"""The wheels' allocation over the wheels available (issue 43's redundancy management, its first part).

Paper 000 eq. 14 shares a body-axis command among every wheel by the
pseudo-inverse of their axes. With a wheel lost that share is wrong: on HST's
pyramid a unit roll command with wheel 1 lost delivers (0.750, -0.687,
0.731), the issue's figure. ``wheels.allocation: available`` takes the
pseudo-inverse over the wheels of ``wheels.available`` alone, which delivers
each unit command exactly; a set that does not span the body axes is refused
in one line; both drivers fly it alike (the wheels node's reallocation while
it runs: test/graph/test_allocation_node.py).

The torque envelope per body axis (the largest pure torque the wheels can
make, each at most 0.8 N m) is the zonotope's facets' closed form
(:func:`torque_envelope`), checked against a linear program's answer
(scipy's HiGHS) for HST's four wheels, each three of them and random sets.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from attitude_sil.cli import main
from attitude_sil.core.plant.wheels import (
    GEOMETRIES,
    allocation_envelope,
    allocation_over,
    null_vector,
    torque_envelope,
)
from attitude_sil.core.sim.build import build_wheels
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError

CONFIG = default_config_dir()
PYRAMID = GEOMETRIES["hst_pyramid"]()


def _delivered(allocation: np.ndarray, lost: int | None, command) -> np.ndarray:
    """The body torque direction the wheels make for ``command``, wheel ``lost`` (0-based) making nothing."""
    share = allocation @ np.asarray(command, dtype=float)
    if lost is not None:
        share[lost] = 0.0
    return PYRAMID @ share


def test_every_wheels_share_with_wheel_1_lost_is_the_issues_figure():
    got = _delivered(allocation_over(PYRAMID), 0, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(got, [0.750, -0.687, 0.731], atol=5e-4)


@pytest.mark.parametrize("lost", [0, 1, 2, 3])
def test_the_three_that_remain_deliver_each_unit_command_exactly(lost):
    available = [i for i in range(4) if i != lost]
    allocation = allocation_over(PYRAMID, available)
    assert not np.any(allocation[lost])  # the lost wheel gets nothing
    for axis in np.eye(3):
        np.testing.assert_allclose(_delivered(allocation, lost, axis), axis, rtol=0, atol=1e-12)


def test_wheels_that_do_not_span_the_body_axes_are_refused():
    with pytest.raises(ScenarioError, match="wheels 1, 2 do not span the three body axes") as err:
        allocation_over(PYRAMID, [0, 1])
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("available, words", [([1, 2], "wheels 1, 2 do not span"), ([2, 3, 7], "has wheels 1..4")])
def test_a_bad_available_set_is_one_line(available, words, tmp_path, capfd):
    over = tmp_path / "over.yaml"
    over.write_text(f"/**/wheels:\n  ros__parameters:\n    allocation: available\n    available: {available}\n")
    assert main(["run", str(CONFIG / "hst_roll_step.yaml"), "--params", str(over), "--no-record", "--quiet"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and words in err, err


def test_both_drivers_fly_the_allocation_alike_and_it_leaves_the_lost_wheel_still():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels", allocation="available",
                                                                   available=[2, 3, 4])
    runs = [simulate(scn, 2, duration=1.0, driver=d) for d in ("compiled", "stepwise")]
    for name in ("q_BN", "wheel_speed", "tau_c_B"):
        np.testing.assert_array_equal(getattr(runs[0], name), getattr(runs[1], name), err_msg=name)
    assert not np.any(runs[0].wheel_speed[:, :, 0])  # wheel 1 is given nothing and never turns
    assert np.max(np.abs(runs[0].wheel_speed[:, :, 1:])) > 0.1


def _lp_envelope(axes: np.ndarray, torque_max: float) -> np.ndarray:
    """max t such that the wheels' torques u (|u_j| <= T) make t e_i exactly, per body axis: a linear program."""
    out = []
    n = axes.shape[1]
    for i in range(3):
        c = np.zeros(n + 1)
        c[-1] = -1.0
        a_eq = np.hstack([axes, -np.eye(3)[:, i:i + 1]])
        r = linprog(c, A_eq=a_eq, b_eq=np.zeros(3), bounds=[(-torque_max, torque_max)] * n + [(0, None)],
                    method="highs")
        assert r.status == 0, r.message
        out.append(r.x[-1])
    return np.array(out)


@pytest.mark.parametrize("available", [None, [1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
def test_the_torque_envelope_per_axis_is_the_linear_programs_with_four_wheels_and_with_three(available):
    used = list(range(4)) if available is None else available
    envelope = torque_envelope(PYRAMID, 0.8, available)
    np.testing.assert_allclose(envelope, _lp_envelope(PYRAMID[:, used], 0.8), rtol=1e-9)
    if available is None:  # the figures of the faults guide
        np.testing.assert_allclose(envelope, [0.7739, 2.1263, 2.2627], atol=5e-5)
    else:  # three wheels of the pyramid: half of four's on every axis
        np.testing.assert_allclose(envelope, 0.5 * torque_envelope(PYRAMID, 0.8), rtol=1e-12)
    # eq. 14's share reaches it on the body axes here (the pyramid's symmetry), and never beyond
    np.testing.assert_allclose(allocation_envelope(allocation_over(PYRAMID, available), 0.8), envelope, rtol=1e-9)


def test_the_envelope_of_random_wheel_sets_is_the_linear_programs_and_bounds_the_pseudo_inverses():
    rng = np.random.default_rng(43)
    for n in (3, 4, 5, 6, 6, 7):
        axes = rng.normal(size=(3, n))
        axes /= np.linalg.norm(axes, axis=0)
        envelope = torque_envelope(axes, 0.8)
        np.testing.assert_allclose(envelope, _lp_envelope(axes, 0.8), rtol=1e-9)
        assert np.all(allocation_envelope(allocation_over(axes), 0.8) <= envelope * (1.0 + 1e-12))
    assert not np.any(torque_envelope(PYRAMID, 0.8, [0, 2]))  # two wheels span no volume: no pure torque


def test_a_per_wheel_command_is_the_users_allocation_made_by_the_drives():
    # the wheels' model takes each wheel's motor torque (N m) in place of a body-axis command (the wheel_cmd
    # of a user's allocation): eq. 14's share of a body torque makes that torque, and a share along the null
    # vector spins the wheels and makes none
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    body, own, null = (build_wheels(scn, 2) for _ in range(3))
    a = body.assembly.allocation
    n = null_vector(PYRAMID, a)
    for k in range(200):
        tau = np.array([[0.3 * np.sin(0.05 * k), -0.2, 0.1], [0.1, 0.5 * np.cos(0.03 * k), -0.4]])
        made, mine = body.advance(tau, True), own.advance(np.zeros((2, 3)), True, wheel_cmd=-(tau @ a.T))
        np.testing.assert_allclose(mine.tau_c_B, made.tau_c_B, rtol=0, atol=1e-12)
        spun = null.advance(np.zeros((2, 3)), True, wheel_cmd=np.outer([0.2, -0.1], n))
        np.testing.assert_allclose(spun.tau_c_B, 0.0, rtol=0, atol=1e-12)
    # the wheels did spin along n: J s' = T - B s on each (J = 0.84 kg m^2, 2 s of 0.2 and 0.1 N m)
    np.testing.assert_allclose(np.abs(null.x[:, :, 2] @ n), [0.2 * 2.0 / 0.84, 0.1 * 2.0 / 0.84], rtol=0.01)
