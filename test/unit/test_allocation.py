"""The wheels' allocation over the wheels available (issue 43's redundancy management, its first part).

Paper 000 eq. 14 shares a body-axis command among every wheel by the
pseudo-inverse of their axes. With a wheel lost that share is wrong: on HST's
pyramid a unit roll command with wheel 1 lost delivers (0.750, -0.687,
0.731), the issue's figure. ``wheels.allocation: available`` takes the
pseudo-inverse over the wheels of ``wheels.available`` alone, which delivers
each unit command exactly; a set that does not span the body axes is refused
in one line; both drivers fly it alike (the wheels node's reallocation while
it runs: test/graph/test_allocation_node.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.cli import main
from attitude_sil.core.plant.wheels import GEOMETRIES, allocation_over
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
