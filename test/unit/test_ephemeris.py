"""An episode's orbit (core/environment/ephemeris.py) against the circular model it generalises.

A ``keplerian_j2`` orbit with J2 off, no eccentricity and the elements that
put LVLH on N at t = 0 is the circular orbit of Hawai'iSat's preset: its LVLH
frame equals the circular model's to 1e-14 over more than an orbit, and the
whole preset flown on it (guidance, gravity gradient and drag reading the
propagated orbit) equals the preset to 1e-12. Eccentric orbits are checked
against the two-body laws, J2 against its secular rate (test_orbit_field.py);
a malformed epoch or element set is one line.
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.cli import main
from attitude_sil.core.environment.ephemeris import BLOCK_STEPS, Ephemeris
from attitude_sil.core.plant.disturbance import lvlh_attitude, orbit_rate
from attitude_sil.core.plant.quaternion import quat_to_dcm
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from conftest import CONFIG

RADIUS = 6978137.0  # m, the preset's
# the preset's circular orbit with LVLH = N at t = 0: r along +z, v along +x (i 90 deg, node at -x, u 90 deg)
ON_N = {"orbit.model": "keplerian_j2", "orbit.semi_major_axis": RADIUS, "orbit.eccentricity": 0.0,
        "orbit.inclination_deg": 90.0, "orbit.raan_deg": 180.0, "orbit.arg_perigee_deg": 0.0,
        "orbit.true_anomaly_deg": 90.0, "orbit.j2": False}


def _refused(tmp_path, capfd, preset: str, extra: str) -> str:
    """The one line ``run`` refuses ``preset`` with once ``extra`` (parameter-file YAML) is laid over it; exit 2."""
    path = tmp_path / "s.yaml"
    path.write_text((CONFIG / preset).read_text() + extra)
    assert main(["run", str(path), "--no-record", "--quiet"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1, err
    return err


def _on(scn, values: dict):
    return scn.with_values("/**", **values)  # every node that flies the orbit


def test_a_circular_propagated_orbit_is_the_circular_model():
    scn = _on(load_scenario(CONFIG / "hawaiisat_lvlh.yaml"), ON_N)
    eph = Ephemeris(scn.values["guidance"], scn.dt)
    start = eph.at(0)
    assert np.allclose(start.q_LN, [0.0, 0.0, 0.0, 1.0], atol=1e-15)  # LVLH is N at t = 0
    rate = orbit_rate(scn.param("guidance", "orbit.mu"), RADIUS)
    worst = 0.0
    for k in range(0, 3 * BLOCK_STEPS * 100, 997):  # about 1.1 orbits, across many propagation blocks
        now = eph.at(k * eph.dt_ns)
        circular = lvlh_attitude(k * scn.dt, start.q_LN, rate)
        worst = max(worst, min(np.max(np.abs(now.q_LN - circular)), np.max(np.abs(now.q_LN + circular))))
        assert now.gg_gain == pytest.approx(3.0 * rate**2, rel=1e-12)
        assert now.omega_LN_L == pytest.approx([0.0, rate, 0.0], rel=1e-12, abs=1e-18)
        # z of LVLH is the zenith of the propagated position, y its orbit normal
        r_nl = quat_to_dcm(now.q_LN)
        assert np.allclose(r_nl[:, 2], now.r_N / np.linalg.norm(now.r_N), atol=1e-14)
    assert worst < 1e-14


def test_the_preset_flown_on_the_propagated_orbit_is_the_preset():
    scn = load_scenario(CONFIG / "hawaiisat_lvlh.yaml")
    circular = simulate(scn, 1, duration=20.0, driver="stepwise")
    propagated = simulate(_on(scn, ON_N), 1, duration=20.0, driver="stepwise")
    assert np.max(np.abs(circular.q_BN - propagated.q_BN)) < 1e-12
    assert np.max(np.abs(circular.u_cmd - propagated.u_cmd)) < 1e-12


def test_j2_and_eccentricity_move_the_run():
    # the same flight on an eccentric orbit with J2: the frame, the gradient's gain and the drag change with it
    scn = load_scenario(CONFIG / "hawaiisat_lvlh.yaml")
    base = simulate(_on(scn, ON_N), 1, duration=20.0, driver="stepwise")
    moved = simulate(_on(scn, {**ON_N, "orbit.eccentricity": 0.05, "orbit.j2": True}), 1, duration=20.0,
                     driver="stepwise")
    assert np.max(np.abs(base.q_BN - moved.q_BN)) > 1e-6


@pytest.mark.parametrize("key, value, words", [
    ("orbit.epoch", "2026-13-01", "is not an ISO 8601 UTC time"),
    ("orbit.epoch", "2026-01-01T00:00:00+02:00", "is not in UTC"),
    ("orbit.model", "sgp4", "orbit.model"),
])
def test_a_malformed_orbit_is_one_line(key, value, words, tmp_path, capfd):
    err = _refused(tmp_path, capfd, "hawaiisat_lvlh.yaml", f"/**/guidance:\n  ros__parameters:\n    {key}: {value!r}\n")
    assert words in err, err


def test_an_orbit_inside_the_earth_is_one_line(tmp_path, capfd):
    err = _refused(tmp_path, capfd, "hawaiisat_lvlh.yaml", "/**:\n  ros__parameters:\n    orbit.model: keplerian_j2\n"
                   "    orbit.semi_major_axis: 6.5e6\n    orbit.eccentricity: 0.5\n")
    assert "inside the Earth" in err, err


def test_a_field_epoch_outside_igrf_is_one_line(tmp_path, capfd):
    err = _refused(tmp_path, capfd, "hst_roll_step.yaml", "/**:\n  ros__parameters:\n"
                   "    orbit.epoch: '2031-06-01T00:00:00Z'\n/**/plant:\n  ros__parameters:\n"
                   "    environment.magnetic_field.model: igrf\n")
    assert "IGRF-14 covers 1900 to 2030; the epoch's year 2031.414 is outside it" in err, err


def test_the_3d_view_draws_the_propagated_orbits_lvlh():
    from attitude_sil.core.sim.build import build_scene

    eccentric = {**ON_N, "orbit.eccentricity": 0.05, "orbit.j2": True}
    scn = _on(load_scenario(CONFIG / "hawaiisat_lvlh.yaml"), eccentric)
    scene = build_scene(scn.values)
    eph = Ephemeris(scn.values["guidance"], scn.dt)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for t in (0.0, 600.0, 2400.0):
        assert np.array_equal(scene.rotations(t, q)[1], eph.at(int(round(t * 1e9))).q_LN)
    circular = build_scene(load_scenario(CONFIG / "hawaiisat_lvlh.yaml").values)
    assert circular.orbit is None and not np.allclose(circular.rotations(2400.0, q)[1], scene.rotations(2400.0, q)[1])


def test_one_orbit_for_every_node_that_flies_it(tmp_path, capfd):
    # the disturbances on a J2 orbit while the plant publishes the circular one: refused, naming the nodes
    err = _refused(tmp_path, capfd, "hawaiisat_lvlh.yaml", "/**/disturbance:\n  ros__parameters:\n"
                   "    orbit.model: keplerian_j2\n")
    assert "orbit.model differs between nodes (plant='circular', guidance='circular', " \
        "disturbance='keplerian_j2'); set it under /**" in err, err
