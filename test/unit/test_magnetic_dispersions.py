"""Monte Carlo disperses the residual dipole, the magnetometer's bias and the epoch: each run of a batch is the
run its dispersed scenario gives alone (what the campaign re-runs through the graph), and a spec that asks for
them on a scenario without them is one line. The epoch turns the Earth under the orbit: a sidereal day later
the field is the same within the secular variation, half a day later it is another field."""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.core.environment.ephemeris import FieldAlongOrbit
from attitude_sil.core.sim.build import build_environment
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import SpecError
from attitude_sil.tuning.dispersions import check_dispersions, episode_values, run_scenario

CONFIG = default_config_dir()


def _scenario():
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml").with_values(
        "plant", **{"environment.magnetic_field.model": "igrf"})
    return scn.with_values("disturbance", models=["residual_dipole"], **{"residual_dipole.moment": [1.0, 0.0, 0.0]})


def test_each_run_of_a_batch_is_its_dispersed_scenario_alone():
    scn = _scenario()
    disp = check_dispersions("mc", {"residual_dipole_Am2": {"dist": "normal", "scale": [5.0, 5.0, 5.0]},
                                    "magnetometer_bias_nt": {"dist": "uniform", "scale": 300.0}}, scn)
    values = episode_values(scn, disp, seed=7, runs=np.arange(3))
    moments, biases = values["disturbance.residual_dipole.moment"], values["sensors.magnetometer.bias_nt"]
    assert moments.shape == biases.shape == (3, 3)
    assert np.all(np.abs(biases) <= 300.0) and len({tuple(m) for m in moments}) == 3
    batch = simulate(scn, 3, duration=0.2, episode_values=values)
    for i in range(3):
        alone = simulate(run_scenario(scn, values, i), 1, duration=0.2)
        np.testing.assert_array_equal(batch.tau_ext_B[i], alone.tau_ext_B[0])
        np.testing.assert_array_equal(batch.magnetometer_B[i], alone.magnetometer_B[0])
        np.testing.assert_array_equal(batch.tau_ext_B[i], np.cross(moments[i], batch.magnetic_field_B[i]))
    # the bias itself, with the magnetometer's noise off: each run reads the field plus its drawn bias
    quiet = simulate(scn.with_values("sensors", **{"magnetometer.noise_nt": 0.0}), 3, duration=0.2,
                     episode_values=values)
    for i in range(3):
        np.testing.assert_allclose(quiet.magnetometer_B[i] - quiet.magnetic_field_B[i],
                                   np.broadcast_to(biases[i] * 1e-9, (quiet.t.size, 3)), rtol=0, atol=1e-20)


def test_each_run_of_a_dispersed_epoch_is_its_epoch_alone():
    # Hawai'iSat on its rods: the field the controller maps its demand through, per episode
    scn = load_scenario(CONFIG / "hawaiisat_lvlh_magnetic.yaml")
    disp = check_dispersions("mc", {"epoch_s": {"dist": "uniform", "scale": 43200.0}}, scn)
    values = episode_values(scn, disp, seed=3, runs=np.arange(3))
    epochs = values["plant.orbit.epoch"]
    assert len(set(epochs)) == 3 and all(e.startswith(("2025-12-31T", "2026-01-01T")) for e in epochs)
    batch = simulate(scn, 3, duration=0.4, episode_values=values)
    for i in range(3):
        alone = run_scenario(scn, values, i)
        assert alone.param("guidance", "orbit.epoch") == alone.param("plant", "orbit.epoch") == epochs[i]
        flown = simulate(alone, 1, duration=0.4)
        for name in ("magnetic_field_B", "dipole_cmd_B", "magnetic_torque_B", "q_BN"):
            np.testing.assert_array_equal(getattr(batch, name)[i], getattr(flown, name)[0])
    assert np.max(np.abs(batch.magnetic_field_B[0] - batch.magnetic_field_B[1])) > 1e-7  # another field


def test_a_sidereal_day_later_the_earth_and_its_field_are_where_they_were():
    orbit = build_environment(load_scenario(CONFIG / "hawaiisat_lvlh_magnetic.yaml"))[0]
    # 86,164 s, the sidereal day to the second (0.09 s short: 7e-6 rad of the Earth's turn), and half a day
    field = FieldAlongOrbit(orbit, "igrf", ["2026-01-01T00:00:00Z", "2026-01-01T23:56:04Z", "2026-01-01T12:00:00Z"])
    b = field.field_N(np.arange(0, 600, 7) * orbit.dt_ns * 50)  # over 10 min of the orbit
    assert b.shape == (3, 86, 3)
    assert np.max(np.linalg.norm(b[1] - b[0], axis=-1)) < 1e-9  # T: within a nanotesla (a day's secular change)
    assert np.min(np.linalg.norm(b[2] - b[0], axis=-1)) > 1e-6  # the Earth half turned: microteslas apart


@pytest.mark.parametrize("key, problem", [("residual_dipole_Am2", "no residual dipole"),
                                          ("magnetometer_bias_nt", "no magnetometer"),
                                          ("epoch_s", "no field model")])
def test_a_dispersion_the_scenario_cannot_take_is_one_line(key, problem):
    with pytest.raises(SpecError, match=problem) as err:
        check_dispersions("mc.yaml", {key: {"dist": "normal", "scale": 1.0}},
                          load_scenario(CONFIG / "hst_roll_step.yaml"))
    assert "\n" not in str(err.value)
