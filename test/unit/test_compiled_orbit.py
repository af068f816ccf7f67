"""The compiled driver on orbit-long runs: the orbit's gravity gradient and drag, and the magnetorquers' loop.

It calls the stepwise driver's kernels (``orbit_torques``, the field in B,
B-dot, the dumping law, the rods) on the same arrays in the same order, so
its trajectories are the stepwise driver's bit for bit: the HST dump preset
(gravity gradient on a propagated J2 orbit, four bars dumping at a gain per
episode), B-dot flown as a scheduled swap, and the gravity gradient alone.
``auto`` takes it for them; a field epoch per episode stays stepwise, and
``driver='compiled'`` says why in one line.
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.core.sim.engine import RunOptions, _Run, simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError

CONFIG = default_config_dir()
MAGNETIC = ("magnetic_field_B", "dipole_cmd_B", "magnetic_torque_B")
ARRAYS = ("q_BN", "omega_BN_B", "h_wheels_B", "u_cmd", "tau_c_B", "tau_ext_B", "wheel_speed")


def _same(a, b, names) -> None:
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        assert x is not None and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def test_the_hst_dump_is_the_stepwise_drivers_bit_for_bit():
    scn = load_scenario(CONFIG / "hst_momentum_dump.yaml")
    gains = {"momentum.gain": np.array([1e-3, 5e-3]), "momentum.target": np.array([[0.0, 0.0, 0.0],
                                                                                   [0.05, 0.0, -0.02]])}
    runs = [simulate(scn, 2, duration=300.0, controller_params=gains, driver=d) for d in ("compiled", "stepwise")]
    _same(*runs, ARRAYS + MAGNETIC)
    compiled = runs[0]
    assert np.max(np.abs(compiled.magnetic_torque_B)) > 1e-7  # N m: the bars act
    assert not np.array_equal(compiled.dipole_cmd_B[0], compiled.dipole_cmd_B[1])  # each episode its gain
    assert np.max(np.abs(compiled.tau_ext_B)) > 1e-6  # and gravity gradient pumps
    assert _Run(scn, 1, RunOptions()).compiled  # auto takes it


def test_bdot_swapped_in_flies_compiled_as_stepwise():
    # B-dot's difference runs every step, whichever law is active: a swap to it at step 40 starts from the
    # previous step's field, in both drivers
    scn = load_scenario(CONFIG / "hst_momentum_dump.yaml").with_values(
        "controller", **{"momentum.mode": "none", "bdot.gain": 50.0}).with_values(
        "scenario", **{"schedule.times": [20.0], "schedule.controller_types": ["bdot"]})  # step 40 of 0.5 s
    runs = [simulate(scn, 1, duration=60.0, driver=d) for d in ("compiled", "stepwise")]
    _same(*runs, ARRAYS + MAGNETIC)
    m = runs[0].dipole_cmd_B[0]
    assert not np.any(m[:40]) and np.all(np.linalg.norm(m[41:], axis=1) > 0.0)


def test_the_orbit_disturbances_alone_fly_compiled_as_stepwise():
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values(
        "/**", **{"orbit.model": "keplerian_j2", "orbit.eccentricity": 0.01}).with_values(
        "disturbance", models=["gravity_gradient", "aerodynamic", "constant"])
    runs = [simulate(scn, 3, duration=2.0, driver=d) for d in ("compiled", "stepwise")]
    _same(*runs, ARRAYS)
    assert runs[0].magnetic_torque_B is None  # no rods: nothing of theirs
    assert np.max(np.abs(runs[0].tau_ext_B)) > 0.0


def test_a_field_epoch_per_episode_stays_stepwise():
    scn = load_scenario(CONFIG / "hst_momentum_dump.yaml")
    epochs = {"plant.orbit.epoch": np.array(["2026-01-01T00:00:00Z", "2026-01-01T06:00:00Z"])}
    assert not _Run(scn, 2, RunOptions(episode_values=epochs)).compiled
    with pytest.raises(ScenarioError, match="a field epoch per episode runs in the stepwise driver") as err:
        simulate(scn, 2, duration=1.0, episode_values=epochs, driver="compiled")
    assert "\n" not in str(err.value)
