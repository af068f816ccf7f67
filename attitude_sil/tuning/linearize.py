"""``attitude-sil linearize``: the nonlinear and the linearised HST model on the same commands.

Reproduces paper 000's Table 1: for angle commands of 3, 8, 15, 25 and 35 deg on
each axis in turn, both closed loops (same PID, same wheels; only the body
model differs: eq. 4 + 10-11 against eq. 20-28) run in the batch engine, and
the RMSE between the two responses of the commanded axis, in degrees, is
tabulated next to the paper's values. ROS-free.

Reading of the linear model's angles: the paper converts quaternions to Euler
angles with eq. 9 and takes the linear model's scalar part "to be 1"; so the
linear run's attitude is read as eq. 9 of ``(g, 1)``, not renormalised
(:func:`euler_eq9_unit_scalar`). Its steady state then differs from the
nonlinear one by the cubic term of the kinematics, so the RMSE depends on the
run length, which the paper does not give: :data:`PAPER_000_TABLE_1_DURATION`
is identified from Table 1 itself (docs/fidelity.md, "Paper 000, Table 1").
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.papers import PAPER_000_COMPARISON_GAINS, PAPER_000_TABLE_1_DURATION
from attitude_sil.core.plant.quaternion import euler_from_quat
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import Scenario
from attitude_sil.errors import ScenarioError

__all__ = ["PAPER_000_TABLE_1", "PAPER_000_COMPARISON_GAINS", "PAPER_000_TABLE_1_DURATION", "euler_eq9_unit_scalar",
           "rmse_table", "format_table"]

#: paper 000 Table 1, RMSE in degrees: command -> (roll, pitch, yaw)
PAPER_000_TABLE_1 = {
    3: (6.365e-4, 7.893e-4, 7.878e-4),
    8: (0.014, 0.016, 0.0153),
    15: (0.089, 0.113, 0.102),
    25: (0.396, 0.656, 0.499),
    35: (1.0219, 2.696, 1.434),
}


def euler_eq9_unit_scalar(q: np.ndarray) -> np.ndarray:
    """Paper 000 eq. 9 applied to ``(g, 1)``: roll, pitch, yaw (rad) of a quaternion's vector part over its scalar.

    The linearised model's attitude with its scalar element "assumed to be 1"
    (not renormalised), shape (..., 4) -> (..., 3).
    """
    g = q[..., :3] / q[..., 3:4]
    q1, q2, q3 = g[..., 0], g[..., 1], g[..., 2]
    return np.stack([np.arctan2(2 * q1 + 2 * q2 * q3, 1 - 2 * (q1**2 + q2**2)),
                     np.arcsin(np.clip(2 * q2 - 2 * q3 * q1, -1.0, 1.0)),
                     np.arctan2(2 * q3 + 2 * q1 * q2, 1 - 2 * (q2**2 + q3**2))], axis=-1)


def rmse_table(scn: Scenario, angles_deg=(3, 8, 15, 25, 35), gains=PAPER_000_COMPARISON_GAINS,
               duration: float | None = None) -> np.ndarray:
    """RMSE (deg) between the nonlinear and linearised responses, shape (len(angles), 3).

    Entry [i, a] is the RMSE of the axis-a angle when ``angles_deg[i]`` is
    commanded on axis a alone, both runs starting at rest from the scenario's
    initial attitude.

    Raises
    ------
    ScenarioError
        An angle that is not finite, zero or beyond 180 deg; gains or a duration the schema refuses.
    """
    angles = np.asarray(angles_deg, dtype=float)
    if angles.size == 0 or not np.all(np.isfinite(angles)) or np.any(angles == 0) or np.any(np.abs(angles) > 180):
        raise ScenarioError(f"--angles: each angle must be a finite, nonzero command of at most 180 deg, "
                            f"got {list(angles_deg)}")
    if len(gains) != 4:
        raise ScenarioError(f"--gains takes KP KI KD N, got {len(gains)} values")
    try:
        scn = scn.with_values("controller", **{name: [float(g)] * 3 for name, g in
                                               zip(("pid.kp", "pid.ki", "pid.kd", "pid.n"), gains, strict=True)})
        if duration is not None:
            if not duration > 0:
                raise ScenarioError(f"must be > 0, got {duration}")
            scn = scn.with_values("plant", duration=duration)
    except ScenarioError as exc:
        what = "--gains (KP KI KD N)" if "pid." in str(exc) else "--duration"
        raise ScenarioError(f"{what}: {exc}") from None
    n = angles.size
    setpoints = np.zeros((3 * n, 3))
    for a in range(3):
        setpoints[a * n:(a + 1) * n, a] = angles
    kp, ki, kd, nn = gains
    params = {"pid.kp": [[kp] * 3], "pid.ki": [[ki] * 3], "pid.kd": [[kd] * 3], "pid.n": [[nn] * 3]}
    runs = {}
    base = scn.with_values("guidance", step_time=0.0).with_values("disturbance", models=[])
    for model in ("rigid_body", "linearized"):
        s = base.with_values("plant", model=model)
        tr = simulate(s, 3 * n, duration=duration, controller="pid", schedule=[],
                      episode_values={"guidance.setpoint_rpy_deg": setpoints},
                      controller_params={k: np.repeat(v, 3 * n, axis=0) for k, v in params.items()})
        runs[model] = np.degrees(euler_eq9_unit_scalar(tr.q_BN) if model == "linearized"
                                 else euler_from_quat(tr.q_BN))
    out = np.empty((n, 3))
    for a in range(3):
        d = runs["rigid_body"][a * n:(a + 1) * n, :, a] - runs["linearized"][a * n:(a + 1) * n, :, a]
        out[:, a] = np.sqrt(np.mean(d**2, axis=1))
    return out


def format_table(angles_deg, table: np.ndarray) -> str:
    """Our RMSE next to paper 000's Table 1."""
    lines = ["RMSE between the nonlinear and the linearised model, deg (paper 000 Table 1 in brackets)",
             f"{'command':>8}  {'roll':>22}  {'pitch':>22}  {'yaw':>22}"]
    for i, ang in enumerate(angles_deg):
        paper = PAPER_000_TABLE_1.get(int(ang)) if float(ang).is_integer() else None
        cells = []
        for a in range(3):
            ref = f"({paper[a]:.4g})" if paper else ""
            cells.append(f"{table[i, a]:>10.4g} {ref:>11}")
        lines.append(f"{ang:>7g}°  " + "  ".join(cells))
    return "\n".join(lines)
