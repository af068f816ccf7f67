"""The environment's physics against references of its own kind (core/environment).

* the dipole model (the expansion cut at degree 1) against the closed form
  of a centred dipole's field, 1e-12 relative;
* IGRF-14 against an independent implementation, the ``ppigrf`` package
  (a test dependency only), within 1 nT at 1,000 random points and epochs;
* the two-body orbit: energy and angular momentum over a day, 1e-10 relative;
* J2: the node's regression measured on the integrated orbit against the
  first-order secular rate -3/2 n J2 (R_e/p)^2 cos i, within 0.5 %;
* time: GMST against a value published for a given instant, and the
  inertial-to-Earth-fixed rotation's sense;
* bad input: one line each.
"""

from __future__ import annotations

import math
import re
from datetime import UTC, datetime

import numpy as np
import pytest

from attitude_sil.core.environment.earth_time import (
    EARTH_ROTATION_RATE,
    decimal_year,
    eci_to_ecef,
    epoch_from_text,
    gmst_rad,
    julian_date,
)
from attitude_sil.core.environment.geomagnetic import (
    REFERENCE_RADIUS,
    field_ecef,
    field_eci,
    igrf_coefficients,
    validity,
)
from attitude_sil.core.environment.orbit import (
    MU_EARTH,
    Elements,
    OrbitPropagator,
    elements_to_state,
    nodal_regression_rate,
    state_to_elements,
)
from attitude_sil.errors import ScenarioError

RNG = np.random.default_rng(20261127)


def test_the_dipole_model_is_the_closed_form_of_a_centred_dipole():
    year = 2026.9
    g, h = igrf_coefficients(year)
    moment = np.array([g[1, 1], h[1, 1], g[1, 0]])  # V = a^3 (g . r) / r^3 for this vector (tesla)
    r = RNG.normal(size=(500, 3))
    r *= (REFERENCE_RADIUS + RNG.uniform(2e5, 4e7, size=(500, 1))) / np.linalg.norm(r, axis=1, keepdims=True)
    rn = np.linalg.norm(r, axis=1, keepdims=True)
    rhat = r / rn
    closed = (REFERENCE_RADIUS / rn) ** 3 * (3.0 * np.sum(moment * rhat, axis=1, keepdims=True) * rhat - moment)
    model = field_ecef(r, year, "dipole")
    assert np.max(np.linalg.norm(model - closed, axis=1) / np.linalg.norm(closed, axis=1)) < 1e-12
    # the dipole of 2026 points south: B is northward (+z) on the equator below it
    assert field_ecef(np.array([[REFERENCE_RADIUS, 0.0, 0.0]]), year, "dipole")[0, 2] > 2e-5


def test_igrf_matches_an_independent_implementation_within_a_nanotesla():
    import ppigrf  # the oracle: a test dependency (setup.py's test extra), never one of the package

    worst = 0.0
    span = validity()
    for _ in range(50):  # 50 random epochs of 1900-2030, 20 random points each: 1,000 points
        when = datetime(1900, 1, 1, tzinfo=UTC) + (datetime(2030, 1, 1, tzinfo=UTC)
                                                   - datetime(1900, 1, 1, tzinfo=UTC)) * RNG.random()
        assert span[0] <= decimal_year(when) <= span[1]
        r_km = 6371.2 + RNG.uniform(100.0, 36000.0, 20)
        theta, phi = np.radians(RNG.uniform(1.0, 179.0, 20)), np.radians(RNG.uniform(-180.0, 180.0, 20))
        oracle = np.array([np.ravel(x) for x in ppigrf.igrf_gc(r_km, np.degrees(theta), np.degrees(phi),
                                                                when.replace(tzinfo=None))])  # (3, 20) nT
        st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
        b = field_ecef((r_km * 1e3)[:, None] * np.stack([st * cp, st * sp, ct], -1), decimal_year(when)) * 1e9
        ours = np.stack([b[:, 0] * st * cp + b[:, 1] * st * sp + b[:, 2] * ct,  # back to (r, theta, phi)
                         b[:, 0] * ct * cp + b[:, 1] * ct * sp - b[:, 2] * st,
                         -b[:, 0] * sp + b[:, 1] * cp])
        worst = max(worst, float(np.max(np.abs(ours - oracle))))
    assert worst < 1.0, worst


def test_outside_the_coefficients_an_epoch_is_one_line():
    first, last = validity()
    assert (first, last) == (1900.0, 2030.0)
    for year in (1899.5, 2030.5):
        with pytest.raises(ScenarioError, match=r"IGRF-14 covers 1900 to 2030; the epoch's year") as err:
            igrf_coefficients(year)
        assert "\n" not in str(err.value)
    assert np.all(field_ecef(np.array([[7e6, 0.0, 0.0]]), 2040.0, "none") == 0.0)  # no field needs no epoch


def test_field_in_inertial_axes_turns_with_the_earth():
    # a point fixed on the turning Earth sees one field: the inertial field at the inertial point, turned back
    year = 2026.0
    r_e = np.array([[6.9e6, 1.0e6, 2.0e6]])
    b_e = field_ecef(r_e, year)[0]
    for theta in (0.3, 2.0, 5.5):
        rot = eci_to_ecef(np.array([theta]))[0]
        r_n = rot.T @ r_e[0]
        b_n = field_eci(r_n[None], np.array([theta]), year)[0]
        assert np.allclose(rot @ b_n, b_e, rtol=0.0, atol=1e-15)


def test_gmst_against_a_published_value_and_the_rotation_rate():
    # Vallado, Fundamentals of Astrodynamics and Applications, 4th ed., example 3-5: 1992-08-20 12:14 UT1 gives
    # GMST = 152.578787810 deg
    when = datetime(1992, 8, 20, 12, 14, tzinfo=UTC)
    assert math.degrees(float(gmst_rad(julian_date(when)))) == pytest.approx(152.578787810, abs=1e-7)
    day = float(gmst_rad(julian_date(when, 86400.0)) - gmst_rad(julian_date(when)))
    assert (day % (2 * math.pi)) / 86400.0 == pytest.approx(EARTH_ROTATION_RATE - 2 * math.pi / 86400.0, rel=1e-6)
    # x_E = R x_N: the Greenwich meridian (x_E) lies at +theta in N
    theta = 0.7
    assert np.allclose(eci_to_ecef(np.array(theta)) @ np.array([math.cos(theta), math.sin(theta), 0.0]),
                       [1.0, 0.0, 0.0])


def test_a_two_body_orbit_keeps_its_energy_and_angular_momentum_for_a_day():
    el = Elements(6.913e6, 0.01, math.radians(28.5), 0.3, 0.2, 0.1)
    r, v = OrbitPropagator(el, j2=0.0).states(np.linspace(0.0, 86400.0, 1441))
    energy = 0.5 * np.sum(v * v, axis=1) - MU_EARTH / np.linalg.norm(r, axis=1)
    h = np.cross(r, v)
    assert np.max(np.abs(energy / energy[0] - 1.0)) < 1e-10
    assert np.max(np.linalg.norm(h - h[0], axis=1)) / np.linalg.norm(h[0]) < 1e-10
    # and the elements of the start come back from the state
    back = state_to_elements(*elements_to_state(el))
    assert np.allclose([back.a, back.e, back.i, back.raan, back.argp, back.nu],
                       [el.a, el.e, el.i, el.raan, el.argp, el.nu], rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("incl_deg, a_m", [(98.19, 7.078e6), (28.5, 6.913e6)])  # sun-synchronous 700 km; HST
def test_j2_turns_the_node_at_the_secular_rate(incl_deg, a_m):
    el = Elements(a_m, 0.001, math.radians(incl_deg), 0.3, 0.2, 0.1)
    t = np.linspace(0.0, 3 * 86400.0, 3 * 289)
    r, v = OrbitPropagator(el).states(t)
    raan = np.unwrap([state_to_elements(a, b).raan for a, b in zip(r, v, strict=True)])
    measured = np.polyfit(t, raan, 1)[0]
    assert measured == pytest.approx(nodal_regression_rate(el), rel=5e-3)
    if incl_deg > 90.0:  # sun-synchronous: about +0.9856 deg/day, the Sun's mean motion
        assert math.degrees(measured) * 86400.0 == pytest.approx(0.9856, rel=5e-3)


@pytest.mark.parametrize("el, words", [
    (Elements(7e6, 1.2, 0.5, 0, 0, 0), "eccentricity 1.2 is not in [0, 1)"),
    (Elements(6.0e6, 0.0, 0.5, 0, 0, 0), "inside the Earth"),
    (Elements(7e6, 0.0, 4.0, 0, 0, 0), "is not in [0, 180]"),
    (Elements(float("nan"), 0.0, 0.5, 0, 0, 0), "not finite"),
])
def test_a_malformed_element_set_is_one_line(el, words):
    with pytest.raises(ScenarioError, match=re.escape(words)) as err:
        OrbitPropagator(el)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("text, words", [("2026-13-01", "not an ISO 8601 UTC time"),
                                         ("2026-01-01T00:00:00+02:00", "not in UTC")])
def test_a_malformed_epoch_is_one_line(text, words):
    with pytest.raises(ScenarioError, match=words):
        epoch_from_text(text, "orbit.epoch")
    assert epoch_from_text("2026-01-01T00:00:00Z", "orbit.epoch") == datetime(2026, 1, 1, tzinfo=UTC)
    assert decimal_year(datetime(2026, 7, 2, 12, tzinfo=UTC)) == pytest.approx(2026.5, abs=1e-9)
