"""Fuzzy inference (papers 003, 004): partitions, rule tables against the papers, kernel == reference."""

from pathlib import Path

import numpy as np
import pytest

from attitude_sil.core.control.fuzzy import (
    FUZZY_PID_DEFAULT_RULES,
    PAPER_003_TABLE_3,
    PAPER_004_TABLE_2,
    UNIFORM_VERTICES,
    infer,
    memberships,
    vertices_from_ratios,
)
from attitude_sil.core.control.kernels import fuzzy_infer
from attitude_sil.core.control.laws.fuzzy_pid import mix
from attitude_sil.core.sim.build import law_bank

DATA = Path(__file__).resolve().parents[1] / "data"
CODES = {"NL": 1, "NB": 1, "NM": 2, "NS": 3, "ZR": 4, "ZO": 4, "PS": 5, "PM": 6, "PL": 7, "PB": 7}


def _table(name: str) -> np.ndarray:
    """A 7 x 7 rule table copied from a paper (test/data/, source in its header) as set indices 1..7."""
    rows = [line.split(",") for line in (DATA / name).read_text().splitlines()
            if line.strip() and not line.startswith("#")]
    header, body = rows[0], rows[1:]
    assert [h for h in header[1:]] == [r[0] for r in body]  # the same labels along both axes
    return np.array([[CODES[c.strip()] for c in r[1:]] for r in body])


def test_paper_003_table_3_cell_by_cell():
    assert np.array_equal(_table("paper_003_table_3.csv"), PAPER_003_TABLE_3)


def test_paper_004_table_2_cell_by_cell():
    assert np.array_equal(_table("paper_004_table_2.csv"), PAPER_004_TABLE_2)


def test_default_fuzzy_pid_rules_repair_the_misprint():
    # the printed table says PS at zero error and zero change: it would push at rest
    assert PAPER_003_TABLE_3[3, 3] == 5
    r = FUZZY_PID_DEFAULT_RULES
    assert r[3, 3] == 4  # ZO at the centre
    assert np.array_equal(8 - r[::-1, ::-1], r)  # odd symmetry: rule(-de, -e) = -rule(de, e)
    assert np.array_equal(r[1:], PAPER_003_TABLE_3[:-1])  # the printed rows, one row down


@pytest.mark.parametrize("vertices", [UNIFORM_VERTICES, vertices_from_ratios(np.array([3.0, 1.0, 0.5, 0.2, 2.0, 1.0]))])
def test_memberships_partition_unity(vertices):
    x = np.linspace(-1.5, 1.5, 2001)
    mu = memberships(x, vertices)
    assert np.allclose(mu.sum(axis=-1), 1.0)
    assert np.all(mu >= 0.0) and np.all(mu <= 1.0)
    # each set peaks at its vertex
    assert np.allclose(memberships(vertices, vertices), np.eye(7))


def test_vertices_from_ratios_eq5():
    v = vertices_from_ratios(np.array([1.0, 2.0, 1.0, 1.0, 1.0, 2.0]))
    assert np.allclose(v, [-1.0, -0.75, -0.25, 0.0, 0.25, 0.5, 1.0])
    with pytest.raises(ValueError):
        vertices_from_ratios(np.array([1.0, 0.0, 1.0, 1.0, 1.0, 1.0]))


def test_compiled_inference_equals_reference():
    rng = np.random.default_rng(0)
    p = 40
    x_row, x_col = rng.uniform(-1.3, 1.3, (p, 3)), rng.uniform(-1.3, 1.3, (p, 3))
    v_row = vertices_from_ratios(rng.uniform(0.1, 3.0, (p, 3, 6)))
    v_col = vertices_from_ratios(rng.uniform(0.1, 3.0, (p, 3, 6)))
    centres = vertices_from_ratios(rng.uniform(0.1, 3.0, (p, 3, 6)))
    rules = rng.integers(1, 8, (p, 7, 7))
    fast = fuzzy_infer(x_row, x_col, v_row, v_col, rules, centres)
    ref = infer(memberships(x_row, v_row), memberships(x_col, v_col), rules[:, None], centres)
    assert np.allclose(fast, ref, atol=1e-12)


def test_standard_table_is_a_monotone_pd_surface():
    # with the default rules the fuzzy output grows with the error and with its change
    x = np.linspace(-1, 1, 41)
    u = infer(memberships(x[:, None], UNIFORM_VERTICES), memberships(x[None, :], UNIFORM_VERTICES),
              FUZZY_PID_DEFAULT_RULES, UNIFORM_VERTICES)
    assert np.all(np.diff(u, axis=0) >= -1e-12) and np.all(np.diff(u, axis=1) >= -1e-12)
    assert u[20, 20] == pytest.approx(0.0, abs=1e-12)


def test_mixing_cases_of_paper_003():
    f = np.array([0.25, 0.25, 0.25])
    u_pid = np.array([1.0, 3.0, 2.0])
    u_f = np.array([3.0, 1.0, 2.0])  # axis 0: fuzzy faster; axis 1: PID faster; axis 2: equal
    u = [mix(a, b, c) for a, b, c in zip(u_pid, u_f, f, strict=True)]  # the compiled block, one axis each
    assert u[0] == pytest.approx(0.25 * 1.0 + 0.75 * 3.0)  # case 1: f u_pid + (1 - f) u_fuzzy
    assert u[1] == pytest.approx(0.75 * 3.0 + 0.25 * 1.0)  # case 2: (1 - f) u_pid + f u_fuzzy
    assert u[2] == 2.0  # case 3: the PID's command
    # "faster" is magnitude, not sign
    assert mix(1.0, -3.0, 0.5) == pytest.approx(0.5 - 1.5)


def _random_states(rng, n):
    from attitude_sil.core.plant.quaternion import quat_from_euler

    q_BN = quat_from_euler(np.radians(rng.uniform(-3, 3, (n, 3))))
    q_RN = quat_from_euler(np.radians(rng.uniform(-1, 1, (n, 3))))
    return q_BN, rng.normal(0, 0.02, (n, 3)), q_RN, rng.normal(0, 0.002, (n, 3))


def _mix_reference(u_pid, u_f, f):
    """Paper 003's mixing block with the magnitude rule, in numpy (laws/fuzzy_pid.py module docstring)."""
    a_p, a_f = np.abs(u_pid), np.abs(u_f)
    return np.where(a_f > a_p + 1e-12, f * u_pid + (1.0 - f) * u_f,
                    np.where(a_p > a_f + 1e-12, (1.0 - f) * u_pid + f * u_f, u_pid))


def test_compiled_fuzzy_pid_equals_its_documented_steps():
    from attitude_sil.core.plant.quaternion import error_vector

    rng = np.random.default_rng(3)
    args = dict(e_scale=[0.02, 0.03, 0.01], de_scale=[0.01, 0.02, 0.01], u_scale=[2.0, 1.0, 3.0],
                rules=FUZZY_PID_DEFAULT_RULES.ravel().tolist())
    gains = dict(kp=[40.0] * 3, ki=[0.5] * 3, kd=[90.0] * 3, n=[2.0] * 3)
    fast = law_bank("fuzzy_pid", 6, 0.01, {**gains, **args, "output_limit": 5.0})
    ref_pid = law_bank("pid", 6, 0.01, {**gains, "output_limit": 5.0})
    e_prev = None
    for _ in range(30):
        states = _random_states(rng, 6)
        e = error_vector(states[0], states[2])
        de = np.zeros_like(e) if e_prev is None else (e - e_prev) / 0.01
        x_e, x_de = e / np.array(args["e_scale"]), de / np.array(args["de_scale"])
        u_f = np.array(args["u_scale"]) * infer(memberships(x_de, UNIFORM_VERTICES), memberships(x_e, UNIFORM_VERTICES),
                                                 FUZZY_PID_DEFAULT_RULES, UNIFORM_VERTICES)
        u_p = ref_pid.compute(*states)
        expected = np.clip(_mix_reference(u_p, u_f, np.clip(x_e, -1, 1) ** 2), -5.0, 5.0)
        assert np.allclose(fast.compute(*states), expected, atol=1e-12)
        e_prev = e


def test_compiled_ga_flc_equals_its_documented_steps():
    from attitude_sil.core.plant.quaternion import quat_error, quat_to_dcm

    rng = np.random.default_rng(4)
    ratios = rng.uniform(0.2, 2.0, 18)
    scales = [20.0, 30.0, 1.5]
    flc = law_bank("ga_flc", 5, 0.01, {"rules": PAPER_004_TABLE_2.ravel().tolist(),
                                                      "mf_ratios": ratios.tolist(), "scales": scales,
                                                      "output_limit": 1.2})
    v = vertices_from_ratios(ratios.reshape(3, 6))
    for _ in range(10):
        states = _random_states(rng, 5)
        q_BR = quat_error(states[0], states[2])
        theta = -2 * np.arcsin(q_BR[:, :3])  # error: reference minus attitude
        Q = np.swapaxes(quat_to_dcm(states[2]), -1, -2) @ quat_to_dcm(states[0])  # R_d^T R
        nu = np.einsum("pji,pj->pi", Q, states[3])  # Q^T w_d
        rate = nu - states[1]
        expected = np.clip(scales[2] * infer(memberships(scales[0] * theta, v[0]), memberships(scales[1] * rate, v[1]),
                                             PAPER_004_TABLE_2, v[2]), -1.2, 1.2)
        assert np.allclose(flc.compute(*states), expected, atol=1e-12)
