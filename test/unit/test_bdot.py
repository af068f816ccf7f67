"""B-dot detumbling: its dipole against the closed form, its gain k*, and a gain sweep flown on the cube.

The closed form: in a field fixed in N, a body turning at omega sees
db/dt = -omega x b, so m = (k/|B|) omega x b and m x B = -k (I - b b^T) omega.
The sweep (config/cubesat_1u_detumble.yaml, five gains in one batch): the
detumble time at Avanzini and Giulietti's k* is within 20 % of the sweep's
best (their result: k* is the gain of fastest decay).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from attitude_sil.core.analysis.magnetic import MagneticFigures, magnetic_columns
from attitude_sil.core.control.laws.bdot import BDot, detumble_gain
from attitude_sil.core.plant.quaternion import quat_multiply, quat_to_dcm, rotation_quaternion
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, derived_values, load_scenario
from attitude_sil.errors import ScenarioError

PRESET = default_config_dir() / "cubesat_1u_detumble.yaml"
MU = 3.986004418e14


def test_the_dipole_is_k_over_b_omega_cross_b_for_a_turning_body():
    dt, k = 1e-5, 3e-5
    omega = np.array([[0.2, -0.1, 0.15]])
    b_N = np.array([2e-5, -1e-5, 3e-5])
    law = BDot(k, dt)
    q0 = rotation_quaternion(np.array([0.3, 0.5, -0.2]))[None]
    q1 = quat_multiply(q0, rotation_quaternion(omega[0] * dt)[None])  # a turn at omega (in B) for dt
    b0, b1 = (np.einsum("nji,j->ni", quat_to_dcm(q), b_N) for q in (q0, q1))  # the field in B
    assert np.array_equal(law.dipole(b0), np.zeros((1, 3)))  # the first step: no difference yet
    m = law.dipole(b1)
    b_hat = b1 / np.linalg.norm(b1)
    closed = k / np.linalg.norm(b1) * np.cross(omega, b_hat)
    np.testing.assert_allclose(m, closed, rtol=0, atol=2 * float(np.linalg.norm(omega)) * dt * np.abs(closed).max())
    tau = np.cross(m, b1)
    np.testing.assert_allclose(tau, -k * (omega - b_hat * np.sum(b_hat * omega)), rtol=1e-4)


def test_k_star_from_the_preset_orbit_and_inertia():
    scn = load_scenario(PRESET)
    n = math.sqrt(MU / 6778137.0**3)
    expected = 2.0 * n * (1.0 + math.sin(math.radians(51.6))) * 0.00166
    assert detumble_gain(n, math.radians(51.6), 0.00166) == pytest.approx(expected, rel=1e-15)
    assert derived_values(scn, "controller")["bdot.gain"] == pytest.approx(expected, rel=1e-9)
    # a gain the file sets is the node's own
    assert "bdot.gain" not in derived_values(scn.with_values("controller", **{"bdot.gain": 1e-5}), "controller")


def test_a_gain_sweep_detumbles_fastest_near_k_star():
    # 0.2 s steps: the detumble times equal the 0.1 s steps' within 0.1 % at k* and 2 k*
    scn = load_scenario(PRESET).with_values("/**", control_period=0.2).with_values("plant", duration=4500.0)
    k_star = derived_values(scn, "controller")["bdot.gain"]
    ratios = np.array([0.25, 0.5, 1.0, 2.0, 4.0])
    tr = simulate(scn, 5, controller_params={"bdot.gain": k_star * ratios})
    times = []
    for p in range(5):
        fig = MagneticFigures(0.5, True)
        for k in range(tr.t.size):
            fig.add(float(tr.t[k]), tr.omega_BN_B[p, k], tr.h_wheels_B[p, k], tr.dipole_cmd_B[p, k])
        times.append(fig.report()["detumble_time_s"])
        # an independent reading: the sample after the last one at or above 0.5 deg/s
        rate = np.degrees(np.linalg.norm(tr.omega_BN_B[p], axis=1))
        above = np.flatnonzero(rate >= 0.5)
        direct = None if above[-1] == tr.t.size - 1 else float(tr.t[above[-1] + 1])
        assert times[-1] == direct
    finite = [t for t in times if t is not None]
    assert times[2] is not None and len(finite) >= 3
    assert times[2] <= 1.2 * min(finite), dict(zip(ratios.tolist(), times, strict=True))
    # it did detumble: from 17 deg/s (10 per axis) to below 0.5
    assert np.degrees(np.linalg.norm(tr.omega_BN_B[2, 0])) == pytest.approx(math.sqrt(3) * 10.0)


def test_bdot_without_a_field_or_from_a_swap_alone_is_one_line():
    with pytest.raises(ScenarioError, match="bdot drives the magnetorquers, which need a field") as err:
        load_scenario(PRESET).with_values("plant", **{"environment.magnetic_field.model": "none"})
    assert "\n" not in str(err.value)
    pid = load_scenario(PRESET).with_values("controller", controller_type="pid")
    with pytest.raises(ScenarioError, match="a swap to bdot needs the magnetorquers"):
        simulate(pid, 1, duration=1.0, schedule=[(5, "bdot")])


def test_the_batch_figures_equal_the_running_ones():
    # magnetic_columns (the tuner's and Monte Carlo's summaries) against MagneticFigures (a run's, a bag's), on
    # two episodes of the cube: one that detumbles within the run, one that does not
    scn = load_scenario(PRESET).with_values("/**", control_period=0.5).with_values("plant", duration=3000.0)
    k_star = derived_values(scn, "controller")["bdot.gain"]
    tr = simulate(scn, 2, controller_params={"bdot.gain": k_star * np.array([1.0, 0.25])})
    columns = magnetic_columns(tr.t, tr.omega_BN_B, tr.h_wheels_B, tr.dipole_cmd_B, 0.5)
    for p in range(2):
        fig = MagneticFigures(0.5, True)
        for k in range(tr.t.size):
            fig.add(float(tr.t[k]), tr.omega_BN_B[p, k], tr.h_wheels_B[p, k], tr.dipole_cmd_B[p, k])
        for key, value in fig.report().items():
            assert columns[key][p] == pytest.approx(np.nan if value is None else value, rel=1e-12, nan_ok=True), key
    assert np.isfinite(columns["detumble_time_s"][0]) and np.isnan(columns["detumble_time_s"][1])
