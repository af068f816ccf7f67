"""The magnetorquer rods and the cross-product dumping law, against closed forms and orbit averages.

The rods: torque = m x B exactly, each rod clipped on its own. The law: its
torque is -k (I - b b^T) h_err (a closed form of the cross product). Flown
(config/hst_momentum_dump.yaml, the stepwise driver): the wheel momentum
that gravity gradient pumps in grows far less with dumping than without; an
initial momentum decays as exp(-k <I - b b^T> t) from the orbit average of
the field the run flew through; and a direction the field keeps to is
dumped only as slowly as its small eigenvalue says.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from attitude_sil.core.control.momentum import CrossProductDumping
from attitude_sil.core.plant.magnetorquers import Magnetorquers, rod_axes
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError, SpecError
from attitude_sil.tuning.evaluate import evaluate
from attitude_sil.tuning.spec import load_spec

PRESET = default_config_dir() / "hst_momentum_dump.yaml"
ORBIT_S = 5720.3648028657235  # 2 pi sqrt(a^3 / mu) of the preset's a = 6913137 m
RNG = np.random.default_rng(42)


def _scenario(duration: float, dt: float = 1.0, **controller):
    scn = load_scenario(PRESET).with_values("plant", duration=duration).with_values("/**", control_period=dt)
    return scn.with_values("controller", **controller) if controller else scn


def test_rods_make_m_cross_b_and_saturate_rod_by_rod():
    axes = rod_axes(load_scenario(PRESET).param("magnetorquers", "rods.axes"))  # HST's four bars
    rods = Magnetorquers(axes, 100.0)
    m_cmd, b = RNG.normal(0.0, 90.0, (50, 3)), RNG.normal(0.0, 3e-5, (50, 3))
    d = rods.rod_dipoles(m_cmd)
    small = np.all(np.abs(d) < 100.0, axis=1)
    assert 10 < small.sum() < 50  # both kinds drawn
    # unsaturated: the rods make the command exactly (a minimum-norm share of it)
    np.testing.assert_allclose(rods.dipole_B(m_cmd)[small], m_cmd[small], rtol=0, atol=1e-12)
    # each rod on its own: clipped at +-100, the others untouched
    raw = m_cmd @ np.linalg.pinv(axes.T).T  # (to the last bit of the sums' order)
    np.testing.assert_allclose(d, np.clip(raw, -100.0, 100.0), rtol=1e-14, atol=0)
    assert np.array_equal(np.abs(d) == 100.0, np.abs(raw) > 100.0)  # exactly the rods past their limit
    assert np.any((np.abs(raw) > 100.0).sum(axis=1) == 1)  # a row with one rod clipped
    m = rods.dipole_B(m_cmd)
    np.testing.assert_allclose(m, d @ axes, rtol=0, atol=1e-12)
    tau = rods.torque(m_cmd, b)
    np.testing.assert_array_equal(tau[:, 0], m[:, 1] * b[:, 2] - m[:, 2] * b[:, 1])
    np.testing.assert_array_equal(tau[:, 1], m[:, 2] * b[:, 0] - m[:, 0] * b[:, 2])
    np.testing.assert_array_equal(tau[:, 2], m[:, 0] * b[:, 1] - m[:, 1] * b[:, 0])
    assert np.max(np.abs(np.sum(tau * b, axis=1))) < 1e-18  # nothing along the field


@pytest.mark.parametrize("flat, problem", [([1, 0, 0, 0, 1], "3 per rod"), ([1, 0, 0, 0, 0, 0, 0, 0, 1], "zero axis"),
                                           ([1, 0, 0, 0, 1, 0, 1, 1, 0], "span fewer than 3")])
def test_a_bad_rod_layout_is_one_line(flat, problem):
    with pytest.raises(ScenarioError, match=problem) as err:
        load_scenario(PRESET).with_values("magnetorquers", **{"rods.axes": flat})
    assert "\n" not in str(err.value) and "magnetorquers" in str(err.value)


def test_dumping_torque_is_the_normal_component_of_minus_k_h_err():
    law = CrossProductDumping(2e-3, [0.1, -0.2, 0.3])
    h, b = RNG.normal(0.0, 5.0, (100, 3)), RNG.normal(0.0, 3e-5, (100, 3))
    tau = np.cross(law.dipole(h, b), b)
    bh = b / np.linalg.norm(b, axis=1, keepdims=True)
    err = h - law.target_B
    closed = -2e-3 * (err - bh * np.sum(bh * err, axis=1, keepdims=True))
    np.testing.assert_allclose(tau, closed, rtol=0, atol=1e-14 * np.abs(closed).max())
    assert np.array_equal(law.dipole(h[:1], np.zeros((1, 3))), np.zeros((1, 3)))  # no field: no command


def test_momentum_management_needs_a_field():
    with pytest.raises(ScenarioError, match="need a field") as err:
        load_scenario(PRESET).with_values("plant", **{"environment.magnetic_field.model": "none"})
    assert "\n" not in str(err.value)


def test_hst_dumping_holds_the_momentum_gravity_gradient_pumps_in():
    # two orbits at 1 s steps, with the bars and without; growth over the second orbit (after the transient)
    n = int(round(2 * ORBIT_S))
    ends = [int(round(ORBIT_S)), n]
    growth = {}
    for mode in ("none", "cross_product"):
        tr = simulate(_scenario(float(n), **{"momentum.mode": mode}))
        h = tr.h_wheels_B[0]
        growth[mode] = np.linalg.norm(h[ends[1]] - h[ends[0]])
        assert np.abs(tr.omega_BN_B).max() < 1e-5  # the PID holds the target throughout
        if mode == "cross_product":
            dumped_orbit_1 = h[ends[0]]
    assert growth["none"] > 0.1  # N m s per orbit: gravity gradient off the principal axes
    assert growth["cross_product"] < growth["none"] / 10.0, growth
    # the step does not move the result: an orbit at 0.5 s steps ends where the 1 s one did
    half = simulate(_scenario(float(ends[0]), dt=0.5)).h_wheels_B[0, -1]
    np.testing.assert_allclose(half, dumped_orbit_1, rtol=0, atol=0.01 * np.linalg.norm(dumped_orbit_1))


def _decay(inclination_deg: float, field: str, gain: float = 2e-4):
    """An initial wheel momentum (no disturbance) dumped over two orbits: the run's momentum at the end, the
    prediction expm(-k <I - b b^T> t) h0 from the field it flew through, and the average's eigen-pairs."""
    scn = _scenario(float(round(2 * ORBIT_S)), **{"momentum.gain": gain}).with_values(
        "/**", **{"orbit.inclination_deg": inclination_deg}).with_values("disturbance", models=[])
    scn = scn.with_values("wheels", initial_speed_rpm=[100.0, -50.0, 30.0, 0.0]).with_values(
        "plant", **{"environment.magnetic_field.model": field})
    tr = simulate(scn)
    h, b = tr.h_wheels_B[0], tr.magnetic_field_B[0, :-1]  # the field of each step held over it
    bh = b / np.linalg.norm(b, axis=1, keepdims=True)
    average = np.eye(3) - np.einsum("ni,nj->ij", bh, bh) / len(bh)
    return h[0], h[-1], expm(-gain * average * tr.t[-1]) @ h[0], np.linalg.eigh(average), gain * tr.t[-1]


def test_an_initial_momentum_decays_at_the_rate_of_the_orbit_average():
    h0, h_end, predicted, _, _ = _decay(28.5, "igrf")
    assert np.linalg.norm(h_end) < 0.5 * np.linalg.norm(h0)  # it did decay
    # within 10 % of what decayed: averaging holds for k T = 1.1 (its error is second order in k T)
    assert np.linalg.norm(h_end - predicted) < 0.1 * np.linalg.norm(h0 - predicted)


def test_the_direction_the_field_keeps_to_is_not_dumped():
    # an equatorial orbit in the dipole: the field stays near the dipole's axis, whose direction the average
    # barely reaches (eigenvalue ~0.05 of 1)
    h0, h_end, _, (values, vectors), kt = _decay(0.0, "dipole")
    assert values[0] < 0.1 < 0.9 < values[1]
    kept = (vectors[:, 0] @ h_end) / (vectors[:, 0] @ h0)
    assert kept > 0.85  # it keeps what its eigenvalue says (exp(-0.055 k t), k t = 2.29: 0.88) ...
    assert kept == pytest.approx(np.exp(-values[0] * kt), rel=0.05)
    for i in (1, 2):  # ... while the directions normal to it lose most of theirs
        assert abs(vectors[:, i] @ h_end) < 0.25 * abs(vectors[:, i] @ h0)


def test_per_episode_gains_fly_each_episode_as_its_own_run():
    # what the tuner and Monte Carlo hand the engine: momentum.gain and momentum.target per episode
    scn = _scenario(200.0, dt=0.5).with_values("controller", **{"momentum.gain": 0.02})
    gains, targets = np.array([0.01, 0.05]), np.array([[0.0, 0.0, 0.0], [0.1, -0.1, 0.05]])
    both = simulate(scn, 2, controller_params={"momentum.gain": gains, "momentum.target": targets})
    for p in range(2):
        alone = simulate(scn.with_values("controller", **{"momentum.gain": float(gains[p]),
                                                          "momentum.target": targets[p].tolist()}))
        np.testing.assert_allclose(both.dipole_cmd_B[p], alone.dipole_cmd_B[0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(both.h_wheels_B[p], alone.h_wheels_B[0], rtol=1e-12, atol=1e-15)
    assert np.max(np.abs(both.dipole_cmd_B[0] - both.dipole_cmd_B[1])) > 1.0  # A m^2: the gains told apart


def test_tune_scores_the_dumping_gain_per_candidate(tmp_path):
    spec = load_spec(default_config_dir() / "tune_hst_momentum_dump.yaml")
    spec.scenarios = [s.with_values("plant", duration=600.0) for s in spec.scenarios]
    spec.conditions = [{}]
    gains = np.array([1e-4, 1e-2])
    ev = evaluate(spec, gains[:, None])
    for p, gain in enumerate(gains):  # each candidate's cost is its own run's: peak |h_w| + w x dipole effort
        alone = simulate(spec.scenarios[0].with_values("controller", **{"momentum.gain": float(gain)}))
        h = np.linalg.norm(alone.h_wheels_B[0], axis=1)
        effort = np.sum(np.linalg.norm(alone.dipole_cmd_B[0, :-1], axis=1) * np.diff(alone.t))
        assert ev.F[p, 0] == pytest.approx(h.max() + 1e-6 * effort, rel=1e-9)
    assert ev.F[1, 0] < 0.5 * ev.F[0, 0]  # the higher gain holds the momentum down
    # a scenario whose magnetorquers do not fly has no momentum to judge: one line
    bad = tmp_path / "bad.yaml"
    bad.write_text((default_config_dir() / "tune_hst_momentum_dump.yaml").read_text().replace(
        "scenarios: [hst_momentum_dump.yaml]", f"scenarios: [{default_config_dir() / 'hst_roll_step.yaml'}]"))
    with pytest.raises(SpecError, match="cost momentum judges the wheel momentum") as err:
        load_spec(bad)
    assert "\n" not in str(err.value)
