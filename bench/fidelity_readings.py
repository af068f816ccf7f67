"""The identifications behind the presets and the readings tables of docs/fidelity.md (not a test).

``python bench/fidelity_readings.py [hst|hst-fit|table1|cubesat-fit|flexible]`` prints, as Markdown:

* ``hst``: paper 000's published results (J of the GA and root-locus gains, the
  root-locus requirements on the linear model, Table 1) under each reading of
  the unpublished motor tried;
* ``hst-fit``: the least squares that identified the preset's motor
  (K_i = K_b, R_a, drive voltage; no torque limit) from the printed J's with the
  root-locus requirements as penalties, from the four starts of the record;
* ``table1``: paper 000 Table 1 (nonlinear vs linear RMSE) under the readings
  of the run length, the output conversion and the motor;
* ``cubesat-fit``: paper 003's attitude gains and step from its two settling times;
* ``flexible``: paper 002's settling times under the readings of its model.

Every figure is recomputed here from the presets; nothing is read outside the repository.
"""

from __future__ import annotations

import sys
from pathlib import Path

import control
import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from attitude_sil.core.analysis.metrics import flexible_split  # noqa: E402
from attitude_sil.core.plant.plants import FLEXIBLE_CASES  # noqa: E402
from attitude_sil.core.plant.quaternion import euler_from_quat  # noqa: E402
from attitude_sil.core.sim.build import flexible_states  # noqa: E402
from attitude_sil.core.sim.engine import simulate, simulate_summary  # noqa: E402
from attitude_sil.core.sim.scenario import load_scenario  # noqa: E402
from attitude_sil.tuning.fidelity import PAPER_000_GAINS, PAPER_002_GAINS, PAPER_002_SETTLING  # noqa: E402
from attitude_sil.tuning.linearize import (  # noqa: E402
    PAPER_000_TABLE_1,
    PAPER_000_TABLE_1_DURATION,
    euler_eq9_unit_scalar,
    rmse_table,
)
from attitude_sil.tuning.rootlocus import closed_loop, reduced_roll_loop  # noqa: E402

CONFIG = ROOT / "config"
HST = load_scenario(CONFIG / "hst_roll_step.yaml")
T1 = np.array(list(PAPER_000_TABLE_1.values()))
#: the motor before this identification (assumed: K = 1.5, R = 1.5 ohm, 3000 rpm no-load drive, 0.8 N m)
OLD = {"K": 1.5, "R": 1.5, "V": 1.5 * 3000 * np.pi / 30, "tmax": 0.8}
FITTED = {"K": 1.002, "R": 1.1889, "V": 10.36, "tmax": 100.0}  # hst_roll_step_unlimited.yaml


def hst_motor(K, R, V, tmax, scn=HST):  # noqa: N803 - the paper's symbols
    """The HST preset with another motor reading (L/R = 1 ms)."""
    return scn.with_values("wheels", **{"motor.torque_constant": K, "motor.back_emf_constant": K,
                                        "motor.resistance": R, "motor.inductance": R * 1e-3, "motor.v_max": V,
                                        "motor.torque_max": tmax}).with_values("controller", output_limit=V)


def hst_figures(scn) -> dict:
    """J of both published gain sets (nonlinear) and the root-locus gains' linear Ts and OS."""
    sets = [PAPER_000_GAINS["ga"], PAPER_000_GAINS["root_locus"]]
    params = {k: [[g[i]] * 3 for g in sets] for i, k in enumerate(("pid.kp", "pid.ki", "pid.kd", "pid.n"))}
    m = simulate_summary(scn, 2, controller_params=params, controller="pid", schedule=[], threads=1).metrics
    info = control.step_info(closed_loop(reduced_roll_loop(scn), *PAPER_000_GAINS["root_locus"]),
                             T=np.linspace(0.0, 60.0, 6001))
    return {"J_ga": float(m["cost_J"][0]), "J_rl": float(m["cost_J"][1]), "tau_ga": float(m["time_constant_s"][0]),
            "tau_rl": float(m["time_constant_s"][1]), "lin_ts": float(info["SettlingTime"]),
            "lin_os": float(info["Overshoot"])}


def cmd_hst() -> None:
    readings = [
        ("assumed before (K = R = 1.5, 471 V, 0.8 N m)", OLD),
        ("identified, with the 0.8 N m limit kept", {**FITTED, "tmax": 0.8}),
        ("best J's with the 0.8 N m limit (K 0.26, R 0.11, no voltage limit)",
         {"K": 0.2618, "R": 0.1138, "V": 1e4, "tmax": 0.8}),
        ("no limits at all, least squares (K 1.66, R 5.23)", {"K": 1.6623, "R": 5.2332, "V": 1e4, "tmax": 100.0}),
        ("exact J's, branch tau_RL < tau_d (K 1.70, R 5.16, 28.3 V)",
         {"K": 1.7014, "R": 5.1598, "V": 28.274, "tmax": 100.0}),
        ("exact J's, branch tau_RL > tau_d (K 1.77, R 5.15, 6.75 V)",
         {"K": 1.7746, "R": 5.1477, "V": 6.7511, "tmax": 100.0}),
        ("**identified (unlimited variant)**: exact J's and the RL requirements (K 1.00, R 1.19, 10.4 V)", FITTED),
        ("**rated (preset)**: the identified K, R with 0.8 N m and the 3000 rpm drive",
         {**FITTED, "V": FITTED["K"] * 3000 * np.pi / 30, "tmax": 0.8}),
    ]
    print("| motor reading | J GA (0.5129) | J RL (0.7215) | RL linear Ts (< 6 s) | RL linear OS (< 2 %) "
          "| Table 1, project / paper |")
    print("| --- | --- | --- | --- | --- | --- |")
    for label, r in readings:
        scn = hst_motor(**r)
        f = hst_figures(scn)
        ratio = _table1(scn, 20.0, "renormalised") / T1
        print(f"| {label} | {f['J_ga']:.4f} | {f['J_rl']:.4f} | {f['lin_ts']:.2f} | {f['lin_os']:.3f} "
              f"| {ratio.min():.3f}-{ratio.max():.3f} |")


def cmd_hst_fit() -> None:
    def resid(z):
        scn = hst_motor(*np.exp(z), 100.0)
        f = hst_figures(scn)
        return np.nan_to_num(np.array([(f["J_ga"] - 0.5129) / 0.01, (f["J_rl"] - 0.7215) / 0.01,
                                       max(0.0, f["lin_ts"] - 6.0) / 0.1, max(0.0, f["lin_os"] - 2.0) / 0.1]),
                             nan=1e3)
    print("| start (K, R, V) | identified (K, R, V) | J GA | J RL | RL linear Ts | RL linear OS |")
    print("| --- | --- | --- | --- | --- | --- |")
    for start in ((1.66, 5.23, 30.0), (1.66, 5.23, 10.0), (1.66, 5.23, 100.0), (1.0, 2.0, 20.0),
                  (1.0019, 1.1904, 10.928)):
        res = minimize(lambda z: float(np.sum(resid(z) ** 2)), np.log(start), method="Nelder-Mead",
                       options={"maxiter": 300, "xatol": 1e-5, "fatol": 1e-8})
        x = np.exp(res.x)
        f = hst_figures(hst_motor(*x, 100.0))
        print(f"| {start} | ({x[0]:.4f}, {x[1]:.4f}, {x[2]:.3f}) | {f['J_ga']:.5f} | {f['J_rl']:.5f} "
              f"| {f['lin_ts']:.2f} | {f['lin_os']:.3f} |")


def _table1(scn, duration=20.0, reading="eq9") -> np.ndarray:
    """Table 1 with the linear model's attitude read by eq. 9 of (g, 1) ("eq9", as ``rmse_table``) or renormalised."""
    angles = np.array(list(PAPER_000_TABLE_1), float)
    n = angles.size
    sp = np.zeros((3 * n, 3))
    for a in range(3):
        sp[a * n:(a + 1) * n, a] = angles
    g = (52.995, 2.488, 132.442, 4.748)
    params = {k: np.array([[g[i]] * 3] * 3 * n) for i, k in enumerate(("pid.kp", "pid.ki", "pid.kd", "pid.n"))}
    out = {}
    for model in ("rigid_body", "linearized"):
        s = scn.with_values("plant", model=model)
        tr = simulate(s, 3 * n, duration=duration, controller="pid", schedule=[],
                      episode_values={"guidance.setpoint_rpy_deg": sp},
                      controller_params=params, threads=1)
        eq9 = model == "linearized" and reading == "eq9"
        out[model] = np.degrees(euler_eq9_unit_scalar(tr.q_BN) if eq9 else euler_from_quat(tr.q_BN))
    tab = np.empty((n, 3))
    for a in range(3):
        d = out["rigid_body"][a * n:(a + 1) * n, :, a] - out["linearized"][a * n:(a + 1) * n, :, a]
        tab[:, a] = np.sqrt(np.mean(d**2, axis=1))
    return tab


def cmd_table1() -> None:
    fitted = hst_motor(**FITTED)
    readings = [("identified motor, 20 s, linear attitude renormalised (before)",
                 lambda: _table1(fitted, 20.0, "renormalised")),
                ("run of 10 s", lambda: _table1(fitted, 10.0, "renormalised")),
                ("run of 40 s", lambda: _table1(fitted, 40.0, "renormalised")),
                ("motor assumed before (K = R = 1.5, 0.8 N m)",
                 lambda: _table1(hst_motor(**OLD), 20.0, "renormalised")),
                ("identified motor with the 0.8 N m limit",
                 lambda: _table1(hst_motor(**{**FITTED, "tmax": 0.8}), 20.0, "renormalised")),
                ("linear attitude read by eq. 9 with q4 = 1 (not renormalised), 20 s", lambda: _table1(fitted, 20.0)),
                ("eq. 9 with q4 = 1, 9 s", lambda: _table1(fitted, 9.0)),
                ("**eq. 9 with q4 = 1, 10.5 s (identified, preset: `rmse_table`)**",
                 lambda: rmse_table(fitted, duration=PAPER_000_TABLE_1_DURATION)),
                ("eq. 9 with q4 = 1, 12 s", lambda: _table1(fitted, 12.0)),
                ("eq. 9 with q4 = 1, 14 s", lambda: _table1(fitted, 14.0))]
    print("| reading | 3 deg roll (6.365e-4) | 35 deg pitch (2.696) | project / paper, all 15 cells "
          "| RMS log ratio | 35 deg / 3 deg, roll (paper 1606) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for label, fn in readings:
        tab = fn()
        ratio = tab / T1
        print(f"| {label} | {tab[0, 0]:.3g} | {tab[4, 1]:.3g} | {ratio.min():.3f}-{ratio.max():.3f} "
              f"| {np.sqrt(np.mean(np.log(ratio) ** 2)):.2f} | {tab[4, 0] / tab[0, 0]:.0f} |")


def cmd_cubesat_fit() -> None:
    scn = load_scenario(CONFIG / "cubesat_1u.yaml")

    def ts(z):
        kp, kd, step = np.exp(z)
        out = []
        for law in ("pid", "fuzzy_pid"):
            m = simulate_summary(scn, 1, controller_params={f"{law}.kp": [[kp] * 3], f"{law}.kd": [[kd] * 3]},
                                 controller=law, schedule=[], threads=1,
                                 episode_values={"guidance.setpoint_rpy_deg": [[step, 0.0, 0.0]]}).metrics
            out.append(float(np.nan_to_num(m["settling_time_s"][0], nan=99.0)))
        return out

    print("| start (Kp, Kd, step deg) | identified (Kp, Kd, step deg) | Ts PID (2.5 s) | Ts hybrid (2.0 s) |")
    print("| --- | --- | --- | --- |")
    for start in ((152.0, 10.5, 20.0), (116.0, 7.5, 20.0), (67.0, 14.6, 20.0), (60.0, 8.0, 15.0),
                  (53.42, 8.698, 17.05)):
        res = minimize(lambda z: (ts(z)[0] - 2.5) ** 2 + (ts(z)[1] - 2.0) ** 2, np.log(start), method="Nelder-Mead",
                       options={"maxiter": 150, "xatol": 1e-4, "fatol": 1e-6})
        x = np.exp(res.x)
        a, b = ts(res.x)
        print(f"| {start} | ({x[0]:.2f}, {x[1]:.3f}, {x[2]:.2f}) | {a:.2f} | {b:.2f} |")


def flexible_settling(scn, gains, n=100.0, limit=10.0, band=0.02, duration=120.0) -> dict:
    """(flexible, rigid) settling times per case of a PID (kp, ki, kd) on a reading of paper 002's model."""
    kp, ki, kd = gains
    out = {}
    for case in FLEXIBLE_CASES:
        v = scn.with_values("plant", **{"flex.case": case}, duration=duration)
        v = v.with_values("wheels", torque_limit=limit).with_values("controller", output_limit=limit)
        tr = simulate(v, 1, controller_params={"pid.kp": [[kp] * 3], "pid.ki": [[ki] * 3], "pid.kd": [[kd] * 3],
                                               "pid.n": [[n] * 3]}, schedule=[], threads=1)
        theta, alpha = flexible_states(v, tr)
        s = flexible_split(tr.t, theta, alpha, 0.0, band)
        out[case] = (float(s["flexible_settling_time_s"][0]), float(s["rigid_settling_time_s"][0]))
    return out


def cmd_flexible() -> None:
    scn = load_scenario(CONFIG / "flexible_axis.yaml")
    pso = PAPER_002_GAINS["pso"]
    readings = [("filter fitted before: N = 2.016, 0.66 % band", {"n": 2.016, "band": 0.0066}), ("N = 10", {"n": 10.0}),
                ("derivative nearly unfiltered, N = 1000", {"n": 1000.0}), ("no torque limit", {"limit": 1e6}),
                ("1 % band", {"band": 0.01}), ("5 % band", {"band": 0.05}),
                ("gains acting on degrees (x 57.3)", {"scale": 57.2958}),
                ("**preset, eq. 4 as written**: N = 100, 2 % band", {})]
    paper = " / ".join(f"{c}: {int(v[0])}" for c, v in PAPER_002_SETTLING["pso"].items())
    print(f"PSO gains; paper (flexible = rigid): {paper}\n")
    print("flexible / rigid settling, s (never: not settled in 120 s)\n")
    print("| reading | nominal | case1 | case2 | case3 | case4 | hardest case | RMS vs paper, s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    target = np.array([v for pair in PAPER_002_SETTLING["pso"].values() for v in pair])
    for label, kw in readings:
        scale = kw.pop("scale", 1.0)
        res = flexible_settling(scn, tuple(g * scale for g in pso), **kw)
        cells = [" / ".join("never" if not np.isfinite(x) else f"{x:.0f}" for x in pair) for pair in res.values()]
        hardest = max(res, key=lambda c: np.nan_to_num(max(res[c]), nan=1e9))
        got = np.array([v for pair in res.values() for v in pair])
        rms = np.sqrt(np.mean((np.nan_to_num(got, nan=120.0) - target) ** 2))
        print(f"| {label} | " + " | ".join(cells) + f" | {hardest} | {rms:.1f} |")


if __name__ == "__main__":
    commands = {"hst": cmd_hst, "hst-fit": cmd_hst_fit, "table1": cmd_table1, "cubesat-fit": cmd_cubesat_fit,
                "flexible": cmd_flexible}
    for name in sys.argv[1:] or commands:
        print(f"\n## {name}\n")
        commands[name]()
