"""Robustness of a design: the same gains on perturbed plants, in the batch engine.

* rigid bodies (paper 001, Fig. 6): every principal inertia of the plant scaled
  by 1 + d for d in -12.5 % ... +12.5 % in 2.5 % steps, in one batch; the
  controller keeps its nominal model (``geometric.inertia``);
* the flexible satellite (paper 002): its nominal plant and the four mismatch
  cases, with the rigid body's and the appendage's settling times apart
  (:func:`attitude_sil.core.analysis.metrics.flexible_split`), as the paper reports them.

The figures are the scenario's metrics (``scenario.metrics.mode``).
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.analysis.metrics import scenario_metrics
from attitude_sil.core.plant.plants import FLEXIBLE_CASES
from attitude_sil.core.plant.rigid_body import inertia_matrix
from attitude_sil.core.sim.build import flexible_settling
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import Scenario

__all__ = ["INERTIA_ERRORS", "robustness", "format_robustness"]

INERTIA_ERRORS = np.round(np.arange(-0.125, 0.1251, 0.025), 4)
_KEYS = ("settling_time_s", "rigid_settling_time_s", "flexible_settling_time_s", "control_effort_Nms",
         "overshoot_pct", "mse", "fitness_f", "cost_J")


def robustness(scn: Scenario) -> list[dict]:
    """One row per perturbed plant: ``case`` and the scenario's metrics."""
    rows = []
    s = scn.values["scenario"]
    step_time = scn.param("guidance", "step_time")
    if scn.param("plant", "model") == "flexible_axis":  # paper 002's five plants, one episode each
        cases = list(FLEXIBLE_CASES)
        tr = simulate(scn, len(cases), schedule=[], episode_values={"plant.flex.case": cases})
        m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B, s, step_time=step_time)
        m.update(flexible_settling(scn, tr, flex_case=cases))
        return [{"case": case, **{k: float(m[k][i]) for k in _KEYS if k in m}} for i, case in enumerate(cases)]
    base = np.diagonal(inertia_matrix(scn.param("plant", "inertia")))
    inertias = base[None, :] * (1.0 + INERTIA_ERRORS[:, None])
    tr = simulate(scn, len(INERTIA_ERRORS), schedule=[],
                  episode_values={"plant.inertia": inertias, "disturbance.inertia": inertias})
    m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B, s, step_time=step_time)
    for i, d in enumerate(INERTIA_ERRORS):
        rows.append({"case": f"J {d * 100 + 0.0:+.1f} %", **{k: float(m[k][i]) for k in _KEYS if k in m}})
    return rows


def format_robustness(rows: list[dict]) -> str:
    keys = [k for k in _KEYS if k in rows[0]]
    lines = [f"{'plant':<12}" + "".join(f"{k:>22}" for k in keys)]
    for r in rows:
        lines.append(f"{r['case']:<12}" + "".join(f"{r[k]:>22.6g}" for k in keys))
    return "\n".join(lines)
