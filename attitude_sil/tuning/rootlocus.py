"""Model-based PID tuning on the linearised HST (paper 000, "Root locus-based tuning").

The loop from the roll voltage command to the roll angle is built from the
linearised body (:func:`attitude_sil.core.plant.linear.linear_model`, eq. 20-28)
and the linear part of the wheel motors (eq. 15-16 through the allocation of
eq. 14) as a python-control state-space model. The paper moved the
closed-loop poles along the root locus in MATLAB's Control System Designer
until the linear step response met its requirements (time constant 1.5 s,
overshoot under 2 %, settling under 6 s). Here the same is done as a
pole-placement design on the root locus: the PID
``Kp (1 + 1/(Ti s)) + Kd N s/(s + N)`` with its derivative filter ``N`` and
integral time ``Ti`` fixed (spec ``algorithm.n``, ``algorithm.ti``) has two
free gains, which the root-locus condition ``C(s) P(s) = -1`` at two real
closed-loop poles fixes exactly: the dominant pole at ``s1 = -1/tau_d`` and
a second one at ``s2 = -m/tau_d``. ``m`` is the designer's one knob (how far
the second pole is dragged along the locus): it is stepped over a grid and the
design whose linear step response (python-control) has its 63.2 % time
nearest ``tau_d`` with overshoot under 2 % and settling under
``settling_time_max`` is kept. The closed-loop poles are reported, the design
is scored with the nonlinear model's cost J (as the paper's Results do), and
the root locus through the design (``control.root_locus_map`` of the loop
with the PID's overall gain as the locus parameter) is plotted next to the results.

python-control and matplotlib are imported in the functions that use them:
with scipy.signal they are the slowest imports of the package, and every
process that tunes (the tuner imports this module for every method) or reads
the fidelity rows would pay for them at its start.
"""

from __future__ import annotations

import json

import numpy as np

from attitude_sil.core.analysis.metrics import scenario_metrics
from attitude_sil.core.plant.linear import linear_model
from attitude_sil.core.plant.rigid_body import inertia_matrix
from attitude_sil.core.sim.build import build_wheels
from attitude_sil.core.sim.engine import simulate
from attitude_sil.errors import SpecError

from .results import TuningResult, write_best_yaml

__all__ = ["roll_loop", "reduced_roll_loop", "closed_loop", "place_poles", "tune_root_locus"]


def roll_loop(scn, axis: int = 0):
    """python-control model from the body-axis voltage on ``axis`` to that axis' quaternion error part.

    States: body (omega, g, h_w) and, per wheel, (current, speed); the wheel
    momentum state of the body model is replaced by the motors' own.
    """
    import control

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
    import control

    s = control.tf("s")
    pid = kp + ki / s + kd * n * s / (s + n)
    return control.feedback(pid * plant, 1)


def reduced_roll_loop(scn, axis: int = 0):
    """:func:`roll_loop` with the states this input cannot reach removed (the other axes' free integrators)."""
    import control
    return control.ss(control.tf(roll_loop(scn, axis)).minreal(tol=1e-6))


def _step_figures(cl, t: np.ndarray) -> tuple[float, float, float]:
    """(63.2 % time, overshoot %, 2 % settling time) of a closed loop's unit step."""
    import control
    y = np.asarray(control.step_response(cl, T=t).outputs).ravel()
    if not np.all(np.isfinite(y)) or y[-1] <= 0:
        return np.inf, np.inf, np.inf
    tc = float(t[np.argmax(y >= 0.632 * y[-1])])
    os_pct = max(0.0, (float(y.max()) / y[-1] - 1.0) * 100.0)
    outside = np.nonzero(np.abs(y - y[-1]) > 0.02 * abs(y[-1]))[0]
    ts = float(t[outside[-1]]) if outside.size else 0.0
    return tc, os_pct, ts


def place_poles(plant, tau_d: float, n: float = 10.0, ti: float = 100.0, settling_max: float = 6.0,
                overshoot_max: float = 2.0, ratios=None) -> dict:
    """PID gains that put two real closed-loop poles at ``-1/tau_d`` and ``-m/tau_d`` (module docstring).

    Parameters
    ----------
    plant : python-control LTI, the loop from the command to the controlled output
    tau_d : desired time constant, s
    n, ti : the PID's derivative filter (rad/s) and integral time (s), fixed
    settling_max, overshoot_max : requirements on the linear step response (s, %)
    ratios : the grid of ``m`` (default 1.2 ... 8)

    Returns
    -------
    dict: ``gains`` (Kp, Ki, Kd, N), ``m``, ``placed`` (the two placed poles),
    ``poles`` (every closed-loop pole, slowest first), ``time_constant_s``,
    ``overshoot_pct``, ``settling_time_s`` of the linear step, ``meets`` (both requirements met).
    """
    t = np.linspace(0.0, 8.0 * settling_max, 2401)
    best = None
    for m in (np.linspace(1.2, 8.0, 35) if ratios is None else ratios):
        s_pts = (-1.0 / tau_d, -m / tau_d)
        if any(abs(sp + n) < 1e-9 for sp in s_pts):
            continue
        # C(s) P(s) = -1 at both poles, linear in (Kp, Kd) with Ki = Kp / Ti
        rows = [[((1.0 + 1.0 / (ti * sp)) * complex(plant(sp))).real, (n * sp / (sp + n) * complex(plant(sp))).real]
                for sp in s_pts]
        try:
            kp, kd = np.linalg.solve(np.array(rows), [-1.0, -1.0])
        except np.linalg.LinAlgError:
            continue
        if not (kp > 0 and kd > 0):
            continue
        cl = closed_loop(plant, kp, kp / ti, kd, n)
        poles = cl.poles()
        if np.any(poles.real > 1e-9):
            continue
        tc, os_pct, ts = _step_figures(cl, t)
        meets = os_pct < overshoot_max and ts < settling_max
        key = (not meets, abs(tc - tau_d))
        if best is None or key < best[0]:
            best = (key, {"gains": (float(kp), float(kp / ti), float(kd), float(n)), "m": float(m),
                          "placed": [float(s_pts[0]), float(s_pts[1])],
                          "poles": [[float(p.real), float(p.imag)] for p in sorted(poles, key=lambda p: -p.real)],
                          "time_constant_s": tc, "overshoot_pct": os_pct, "settling_time_s": ts, "meets": meets})
    if best is None:
        raise SpecError(f"no positive PID places a closed-loop pole at {-1.0 / tau_d:.4g} with N = {n}, Ti = {ti}")
    return best[1]


def _targets(scn):
    s = scn.values["scenario"]
    tau = s["metrics.tau_d"]
    os_frac = 0.02
    zeta = -np.log(os_frac) / np.sqrt(np.pi**2 + np.log(os_frac) ** 2)
    return tau, zeta


def tune_root_locus(spec, progress=None):
    """Place the dominant closed-loop poles (see the module docstring); write the usual results."""
    import control

    scn = spec.scenarios[0]
    axis = scn.values["scenario"]["metrics.axis"]
    # the other axes are uncontrollable from this input (free integrators): drop them
    plant = reduced_roll_loop(scn, axis)
    tau, zeta = _targets(scn)
    target = complex(-1.0 / tau, 0.0)
    max_settle = float(spec.algorithm.get("settling_time_max", 6.0))

    design = place_poles(plant, tau, n=float(spec.algorithm.get("n", 10.0)),
                         ti=float(spec.algorithm.get("ti", 100.0)), settling_max=max_settle)
    kp, ki, kd, n = design["gains"]
    cl = closed_loop(plant, kp, ki, kd, n)
    info = control.step_info(cl, T=np.linspace(0, 40, 8001))
    gains = {"pid.kp": [[kp] * 3], "pid.ki": [[ki] * 3], "pid.kd": [[kd] * 3], "pid.n": [[n] * 3]}
    tr = simulate(scn, 1, controller_params=gains, controller="pid", schedule=[])
    m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B, scn.values["scenario"])
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
                     "linear_overshoot_pct": float(info["Overshoot"]), "placed_poles": design["placed"]},
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
               "placed_poles": design["placed"], "second_pole_ratio": design["m"],
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
    import control
    from matplotlib.figure import Figure

    s = control.tf("s")
    loop = (kp + ki / s + kd * n * s / (s + n)) * control.tf(plant)
    loci = control.root_locus_map(loop, np.logspace(-1.3, 1.3, 200)).loci
    fig = Figure(figsize=(7, 5.5), dpi=110)
    ax = fig.subplots()
    ax.plot(loci.real.ravel(), loci.imag.ravel(), ".", color="0.6", ms=2)
    design = closed_loop(plant, kp, ki, kd, n).poles()
    ax.plot(design.real, design.imag, "x", color="C3", ms=9, mew=2, label="design")
    ax.plot([target.real], [0.0], "o", mfc="none", color="C0", ms=11, label="dominant pole -1/tau_d")
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
