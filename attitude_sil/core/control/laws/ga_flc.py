"""``ga_flc``: the GA-designed fuzzy logic controller of paper 004, one per body axis (volts).

Inputs: the attitude error ``θ = -2 asin(vec(q_BR))`` per axis (rad, reference
minus attitude; exact for a rotation about one axis) and the rate error
``q = Q^T ω_d - ω`` (rad/s), scaled by ``K_θ`` and ``K_q`` (eq. 6) to
[-1, 1]. Errors, not deviations, are what paper 004's Fig. 2 feeds the FLC,
and only with that sign does its Table 2 stabilise its own pitch model
(checked for the impulse and the 30 deg initial-angle cases). Seven
triangular sets per variable with vertices from positive ratios (eq. 5); 49
integer rules (1..7 = NB..PB, Table 1), table indexed ``rules[θ, q]`` as
paper 004 Table 2; product inference, weighted average over the output
vertices (the δe sets' centres); output ``K_e × δe_n`` in volts, saturated.

Genome layout (the tuner searches exactly these parameters): ``ga_flc.rules``
49 integers, row-major over θ (NB..PB) then q (NB..PB); ``ga_flc.mf_ratios``
18 positive numbers: a1..a6 for θ, then for q, then for δe;
``ga_flc.scales`` ``[K_θ (1/rad), K_q (s/rad), K_e (V)]``.

No state: a swap to it gets the generic decaying offset (:mod:`attitude_sil.core.control.law`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.control.fuzzy import PAPER_004_TABLE_2, vertices_from_ratios
from attitude_sil.core.control.kernels import error_quat_row, infer_row, reference_rate_row
from attitude_sil.core.control.law import Law, lanes
from attitude_sil.core.paramspec import ParamSpec, double_array

__all__ = ["LAW", "Params", "ga_flc_row"]


class Params(NamedTuple):
    """The GA-FLC's record."""

    rules: np.ndarray  # (n, 7, 7) int64
    vertices: np.ndarray  # (n, 3, 7): angle, rate and output vertices
    scales: np.ndarray  # (n, 3): K_theta, K_q, K_e
    u_max: float


@njit(cache=True, inline="always")
def ga_flc_row(q_BN, omega, q_RN, omega_RN_R, p, rules, vertices, scales, u_max, out):
    """The law for episode ``p`` alone (row ``p`` of every array), saturated, into ``out[p]``."""
    x, y, z, w = error_quat_row(q_BN, q_RN, p)
    nu = reference_rate_row(x, y, z, w, omega_RN_R, p)
    vec = (x, y, z)
    for i in range(3):
        # errors, reference minus measurement (paper 004 Fig. 2 feeds the FLC the error)
        theta = -2.0 * np.arcsin(min(max(vec[i], -1.0), 1.0))
        rate = nu[i] - omega[p, i]
        u = scales[p, 2] * infer_row(scales[p, 0] * theta, scales[p, 1] * rate, vertices, rules, p)
        out[p, i] = min(max(u, -u_max), u_max)


@njit(cache=True, inline="always")
def step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u):
    """The law's step (:mod:`attitude_sil.core.control.law`)."""
    ga_flc_row(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par.rules, par.vertices, par.scales, par.u_max, u)


def _record(values, n: int, dt: float) -> Params:
    ratios = np.asarray(values["mf_ratios"], dtype=float)
    vertices = vertices_from_ratios(ratios.reshape((-1, 3, 6)))
    return Params(lanes(np.asarray(values["rules"], dtype=np.int64), n, (7, 7), np.int64),
                  lanes(vertices, n, (3, 7)), lanes(values["scales"], n), float(values["output_limit"]))


LAW = Law(
    name="ga_flc",
    summary="GA-designed fuzzy logic controller: 49 rules, ratio-encoded sets (paper 004 eq. 5-6, Table 2)",
    params=(
        ParamSpec("rules", "integer_array", PAPER_004_TABLE_2.ravel().tolist(),
                  "49 rule outputs 1..7 (NB..PB), row-major: rows angle NB..PB, columns rate NB..PB "
                  "(paper 004 Table 2)", lengths=(49,), min=1, max=7, runtime=True),
        double_array("mf_ratios", [1.0] * 18,
                     "MF vertex ratios a1..a6 (eq. 5) for angle, then rate, then output; all > 0 "
                     "(assumed: evenly spaced, the paper prints only a figure)",
                     lengths=(18,), min=0.0, min_exclusive=True, runtime=True),
        double_array("scales", [1.0 / math.radians(30.0), 1.0, 1.3],
                     "scaling factors K_theta 1/rad, K_q s/rad, K_e V (eq. 6; paper: 30 deg, 1.0, 1.3)",
                     lengths=(3,), min=0.0, min_exclusive=True, runtime=True),
    ),
    state={},
    record=_record,
    step=step,
)
