"""A torque law on magnetorquers alone (``torque_actuator: magnetorquers``), against its closed form.

The controller maps its torque demand tau onto the dipole m = B x tau / |B|^2,
whose torque m x B is (I - b b^T) tau: the demand's component normal to the
field, exactly, where no rod saturates; a rod past its limit is clipped on
its own. Flown (config/hawaiisat_lvlh_magnetic.yaml, paper 001's geometric
law on three 25 A m^2 rods in the IGRF field), every step's torque is that
of the demand and the field of that step, the wheels make nothing, and the
control effort Ce (paper 001 eq. 9) sums the rods' torque. Scenarios that
would give one torque two actuators, or none, are refused in one line.
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.cli import main
from attitude_sil.core.analysis.metrics import tracking_metrics
from attitude_sil.core.control.momentum import torque_dipole
from attitude_sil.core.plant.magnetorquers import rod_axes
from attitude_sil.core.plant.quaternion import cross
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario

PRESET = default_config_dir() / "hawaiisat_lvlh_magnetic.yaml"
RNG = np.random.default_rng(7)


def _normal_part(tau: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(I - b b^T) tau, b the unit field, row by row."""
    bh = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return tau - np.sum(tau * bh, axis=-1, keepdims=True) * bh


def test_the_dipole_makes_the_demand_normal_to_the_field():
    tau, b = RNG.normal(0.0, 1e-3, (200, 3)), RNG.normal(0.0, 3e-5, (200, 3))
    m = torque_dipole(tau, b)
    assert np.max(np.abs(np.sum(m * b, axis=1))) <= 1e-12 * np.max(np.abs(m * b))  # m is normal to B
    made = cross(m, b)
    np.testing.assert_allclose(made, _normal_part(tau, b), rtol=0, atol=1e-15 * np.max(np.abs(tau)) * 10)
    assert np.all(torque_dipole(tau[:2], np.zeros((2, 3))) == 0.0)  # no field, no dipole


def test_flown_every_step_is_the_closed_form_of_its_demand_and_field():
    # rods of 8 A m^2, not the preset's 25 (which the demand does not reach in this run): some steps clip
    scn = load_scenario(PRESET).with_values("magnetorquers", **{"rods.max_dipole": 8.0})
    tr = simulate(scn, 1, duration=20.0, driver="stepwise")
    b, u, m, made = tr.magnetic_field_B[0], tr.u_cmd[0], tr.dipole_cmd_B[0], tr.magnetic_torque_B[0]
    np.testing.assert_array_equal(m, torque_dipole(u, b))  # the controller reads the true field here
    assert np.array_equal(rod_axes(scn.param("magnetorquers", "rods.axes")), np.eye(3))  # a rod per body axis
    clipped = np.any(np.abs(m) > 8.0, axis=1)
    assert clipped.any() and not clipped.all()  # the run shows both: the demand made, and rods at their limit
    free = ~clipped
    np.testing.assert_allclose(made[free], _normal_part(u[free], b[free]), rtol=0,
                               atol=1e-14 * np.max(np.abs(u)))
    np.testing.assert_allclose(made[clipped], cross(np.clip(m[clipped], -8.0, 8.0), b[clipped]), rtol=1e-14)
    assert not np.any(tr.tau_c_B) and not np.any(tr.h_wheels_B) and tr.wheel_speed.shape[-1] == 0
    # Ce (paper 001 eq. 9) sums the torque the actuators made: the rods'
    ce = tracking_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B)["control_effort_Nms"][0]
    assert ce == pytest.approx(np.sum(np.linalg.norm(made[:-1], axis=1)) * scn.dt, rel=1e-12)
    assert ce > 0.0


@pytest.mark.parametrize("extra, words", [
    ("/**/wheels:\n  ros__parameters:\n    actuator: torque\n", "wheels.actuator is torque: set wheels actuator none"),
    ("/**/controller:\n  ros__parameters:\n    torque_actuator: wheels\n", "wheels.actuator none makes no torque"),
    ("/**/controller:\n  ros__parameters:\n    momentum.mode: cross_product\n", "set momentum.mode none"),
    ("/**/plant:\n  ros__parameters:\n    environment.magnetic_field.model: none\n",
     "controller.torque_actuator magnetorquers drives the magnetorquers, which need a field"),
    ("/**/controller:\n  ros__parameters:\n    torque_actuator: reaction_wheels\n", "torque_actuator"),
])
def test_one_torque_with_two_actuators_or_none_is_one_line(extra, words, tmp_path, capfd):
    path = tmp_path / "over.yaml"  # laid over the preset
    path.write_text(extra)
    assert main(["run", str(PRESET), "--params", str(path), "--no-record", "--quiet"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and words in err, err
