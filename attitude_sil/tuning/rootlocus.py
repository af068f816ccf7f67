"""Model-based PID tuning on the linearised HST (paper 000, "Root locus-based tuning").

The loop from the roll voltage command to the roll angle is built from the
linearised body (:func:`attitude_sil.core.linear.linear_model`, eq. 20-28)
and the linear part of the wheel motors (eq. 15-16 through the allocation of
eq. 14) as a python-control state-space model. The paper moved the
closed-loop poles along the root locus in MATLAB's Control System Designer
until the linear step response met its requirements (time constant 1.5 s,
overshoot under 2 %, settling under 6 s). Here the same requirements are met
numerically on the same kind of model: Nelder-Mead over log(Kp, Ki, Kd, N)
within the spec's bounds, on ``|tau - tau_d| + 10 max(0, OS - 2) +
0.5 max(0, Ts - 6)`` of the linear closed-loop step response
(python-control). The design is then scored with the nonlinear model's cost
J, so the two tuning methods compare as in the paper's Results, and the
closed-loop poles as the PID gain is scaled (the root locus through the
design) are plotted next to the results.
"""

from __future__ import annotations

import json

import control
import numpy as np
from matplotlib.figure import Figure
from scipy.optimize import minimize

from attitude_sil.core.engine import build_wheels, inertia_matrix, simulate
from attitude_sil.core.linear import linear_model
from attitude_sil.core.metrics import scenario_metrics

from .results import TuningResult, write_best_yaml

__all__ = ["roll_loop", "closed_loop", "tune_root_locus"]


def roll_loop(scn, axis: int = 0):
    """python-control model from the body-axis voltage on ``axis`` to that axis' quaternion error part.

    States: body (omega, g, h_w) and, per wheel, (current, speed); the wheel
    momentum state of the body model is replaced by the motors' own.
    """

    p = scn.values["plant"]
    inertia = inertia_matrix(p["inertia"])
    a_b, _ = linear_model(inertia)
    wheels = build_wheels(scn, 1).assembly
    m = wheels.motor
    n = wheels.n_wheels
    g_axes = wheels.axes_B
    alloc = wheels.allocation
    # states: omega (3), g (3), per wheel (i, w)
    ns = 6 + 2 * n
    a = np.zeros((ns, ns))
    b = np.zeros((ns, 1))
    inv = np.linalg.inv(inertia)
    a[0:6, 0:6] = a_b[0:6, 0:6]
    for j in range(n):
        ii, ww = 6 + 2 * j, 7 + 2 * j
        a[ii, ii] = -m.resistance / m.inductance
        a[ii, ww] = -m.back_emf_constant / m.inductance
        a[ww, ii] = m.torque_constant / m.rotor_inertia
        a[ww, ww] = -m.viscous_friction / m.rotor_inertia
        b[ii, 0] = -alloc[j, axis] / m.inductance  # e_w = -A_dagger v
        # body: I w' = -A (K_i i) (reaction of the motor torque)
        a[0:3, ii] += -inv @ g_axes[:, j] * m.torque_constant
    c = np.zeros((1, ns))
    c[0, 3 + axis] = 1.0
    return control.ss(a, b, c, 0.0)


def closed_loop(plant, kp, ki, kd, n):
    """Unity feedback of the PID ``kp + ki/s + kd n s/(s+n)`` around ``plant`` (reference in g units)."""

    s = control.tf("s")
    pid = kp + ki / s + kd * n * s / (s + n)
    return control.feedback(pid * plant, 1)


def _targets(scn):
    s = scn.values["scenario"]
    tau = s["metrics.tau_d"]
    os_frac = 0.02
    zeta = -np.log(os_frac) / np.sqrt(np.pi**2 + np.log(os_frac) ** 2)
    return tau, zeta


def tune_root_locus(spec, progress=None):
    """Place the dominant closed-loop poles (see the module docstring); write the usual results."""

    scn = spec.scenarios[0]
    axis = scn.values["scenario"]["metrics.axis"]
    # the other axes are uncontrollable from this input (free integrators): drop them
    plant = control.ss(control.tf(roll_loop(scn, axis)).minreal(tol=1e-6))
    tau, zeta = _targets(scn)
    sigma = 1.0 / tau
    target = complex(-sigma, sigma * np.sqrt(1 - zeta**2) / zeta)
    t = np.linspace(0.0, 30.0, 1501)
    max_settle = float(spec.algorithm.get("settling_time_max", 6.0))

    def objective(logk):
        kp, ki, kd, n = np.exp(logk)
        cl = closed_loop(plant, kp, ki, kd, n)
        if np.any(cl.poles().real >= 0):
            return 1e6
        y = control.step_response(cl, T=t).outputs
        y = np.asarray(y).ravel()
        if not np.all(np.isfinite(y)) or y[-1] <= 0:
            return 1e6
        tc = t[np.argmax(y >= 0.632 * y[-1])]
        os_pct = max(0.0, (y.max() / y[-1] - 1.0) * 100.0)
        outside = np.nonzero(np.abs(y - y[-1]) > 0.02 * abs(y[-1]))[0]
        ts = t[outside[-1]] if outside.size else 0.0
        return abs(tc - tau) + 10.0 * max(0.0, os_pct - 2.0) + 0.5 * max(0.0, ts - max_settle)

    genes = {g.param: g for g in spec.genome}
    names = ("pid.kp", "pid.ki", "pid.kd", "pid.n")
    lo = np.log([max(genes[k].low, 1e-3) if k in genes else 1e-3 for k in names])
    hi = np.log([genes[k].high if k in genes else 1e3 for k in names])
    best = None
    rng = np.random.default_rng(spec.seed)
    for _ in range(int(spec.algorithm.get("restarts", 4))):
        start = rng.uniform(lo, hi)
        res = minimize(lambda z: objective(np.clip(z, lo, hi)), start, method="Nelder-Mead",
                       options={"xatol": 1e-4, "fatol": 1e-5, "maxiter": int(spec.algorithm.get("maxiter", 400))})
        if best is None or res.fun < best.fun:
            best = res
    best.x = np.clip(best.x, lo, hi)
    kp, ki, kd, n = np.exp(best.x)
    cl = closed_loop(plant, kp, ki, kd, n)
    info = control.step_info(cl, T=np.linspace(0, 40, 8001))
    gains = {"pid.kp": [[kp] * 3], "pid.ki": [[ki] * 3], "pid.kd": [[kd] * 3], "pid.n": [[n] * 3]}
    tr = simulate(scn, 1, controller_params=gains, controller="pid", schedule=[])
    m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_c_B, scn.values["scenario"])
    out = spec.output
    out.mkdir(parents=True, exist_ok=True)
    x = np.array([kp, ki, kd, n])
    labels = ["pid.kp", "pid.ki", "pid.kd", "pid.n"]
    row = {"generation": 1, "index": 0, "x": x.tolist(), "genome": dict(zip(labels, x.tolist(), strict=True)),
           "cost": [float(m["cost_J"][0])],
           "terms": {"time_constant_s": float(m["time_constant_s"][0]),
                     "overshoot_pct": float(m["overshoot_pct"][0]),
                     "linear_rise_time_s": float(info["RiseTime"]),
                     "linear_settling_time_s": float(info["SettlingTime"]),
                     "linear_overshoot_pct": float(info["Overshoot"]), "design_objective": float(best.fun)},
           "failure": ""}
    (out / "evaluations.jsonl").write_text(json.dumps(row) + "\n")
    (out / "evaluations.json").write_text(json.dumps([row], indent=1))
    spec_genes = spec.genome
    spec.genome = [g for g in spec_genes if g.param in labels]
    best_values = write_best_yaml(spec, np.array([x[labels.index(g.param)] for g in spec.genome]), out / "best.yaml") \
        if spec.genome else {}
    spec.genome = spec_genes
    poles = cl.poles()
    summary = {"name": spec.name, "spec": str(spec.path), "algorithm": spec.algorithm, "cost": spec.cost,
               "seed": spec.seed, "best_cost": row["cost"], "best_parameters": best_values,
               "target_pole": [target.real, target.imag], "zeta": zeta, "tau_d": tau,
               "closed_loop_poles": [[p.real, p.imag] for p in sorted(poles, key=lambda p: -p.real)],
               "linear_step_info": {k: float(v) for k, v in info.items()}, "generations": [],
               "nonlinear": {"time_constant_s": row["terms"]["time_constant_s"],
                             "overshoot_pct": row["terms"]["overshoot_pct"], "cost_J": row["cost"][0]}}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plot_locus(plant, kp, ki, kd, n, target, out / "root_locus.png")
    if progress is not None:
        progress({"generation": 1, "generations": 1, "best": row["cost"][0], "generation_best": row["cost"][0],
                  "median": row["cost"][0], "failed": 0, "evaluations": 1, "evals_per_s": 0.0, "cached": False})
    return TuningResult(best_x=x, best_cost=np.array(row["cost"]),
                        best_params={k: np.array(v[0]) for k, v in gains.items()}, evaluations=1)


def _plot_locus(plant, kp, ki, kd, n, target, path) -> None:
    """Closed-loop poles as the PID's overall gain k sweeps 0.05-20 x the design, the design marked."""

    ks = np.logspace(-1.3, 1.3, 200)
    fig = Figure(figsize=(7, 5.5), dpi=110)
    ax = fig.subplots()
    for k in ks:
        poles = closed_loop(plant, k * kp, k * ki, k * kd, n).poles()
        ax.plot(poles.real, poles.imag, ".", color="0.6", ms=2)
    design = closed_loop(plant, kp, ki, kd, n).poles()
    ax.plot(design.real, design.imag, "x", color="C3", ms=9, mew=2, label="design")
    ax.plot([target.real] * 2, [target.imag, -target.imag], "o", mfc="none", color="C0", ms=11,
            label="target (tau_d, 2 % overshoot)")
    lim = 6 * abs(target.real)
    ax.set_xlim(-lim, 0.2 * lim)
    ax.set_ylim(-lim, lim)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("real (1/s)")
    ax.set_ylabel("imag (rad/s)")
    ax.set_title("HST roll loop: closed-loop poles as the PID gain is scaled")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
