"""Cost of a population of candidates: batch-engine runs and the papers' cost functions.

Every candidate of a population runs as one episode of one vectorised
:func:`attitude_sil.core.sim.engine.simulate` call per scenario and condition
(costs are summed over them); with ``workers > 1`` the population is split
over processes. A gene on a scalar parameter (``geometric.torque_limit``,
``output_limit``) is the exception: a law's parameter record holds a scalar
once for all its episodes (a list parameter has a row per episode), so the
candidates run in one call per distinct value, the value set in the
scenario (:func:`scalar_groups`). A candidate that diverges (non-finite state), runs a wheel
into its speed limit, or breaks a cost's rule gets :data:`PENALTY` and a
recorded reason; nothing raises.

Costs (``cost.name``):

* ``paper000_j`` — J = |tau - tau_d| + w_os OS (paper 000 eq. 19, OS in %),
  plus ``cost.w_ts`` Ts (settling time, s) and ``cost.w_itae`` ITAE (rad s^2)
  where they are given: J alone has no term for the error left at the end,
  so a design tuned on it can settle slowly (docs/tuning.md); both weights
  default to 0, the paper's J.
* ``paper001_fitness`` — Ts + beta Ce, i.e. -f of paper 001 eq. 8, with its
  death penalty (a command above ``cost.limit``, N m) and its rule that the
  entries of K differ. The law runs unsaturated so the command it asks for
  is what is judged; the actuator still saturates.
* ``mse`` — mean squared error (paper 002 eq. 10).
* ``paper004_objective`` — eq. 7, ``int_0^tf (w1 theta^2 + w2 u^2) dt + w3 tf``
  plus the two-level penalty of eq. 8 on theta(tf), q(tf); tf is the gene
  ``final_time``.
* ``ts_ce`` — the two objectives (Ts, Ce) for NSGA-II, with the death penalty.
* ``momentum`` — the peak wheel momentum |h_w| (N m s) plus ``cost.w_dipole``
  times the dipole effort (A m^2 s) of a scenario whose magnetorquers dump
  it (docs/orbit-and-field.md); the gene is ``momentum.gain``.

A robust-design cost (the spec's ``robust`` section: ``runs``, ``statistic``
``mean`` or ``max``, ``seed``, ``dispersions`` as a Monte Carlo spec's) runs
every candidate on the same ``runs`` dispersed plants and takes the mean or the
worst of its costs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from attitude_sil.core.analysis.metrics import summarize
from attitude_sil.core.control.momentum import PER_EPISODE_SCALARS
from attitude_sil.core.plant.quaternion import euler_from_quat
from attitude_sil.core.sim.build import episode_parameter_faults
from attitude_sil.core.sim.engine import simulate, simulate_summary
from attitude_sil.core.sim.params import spec_for
from attitude_sil.core.trajectory import EpisodeSummary, Trajectory

from .dispersions import episode_values
from .executor import Executor, InProcess, LocalProcesses
from .spec import TuningSpec, decode, is_scalar

__all__ = ["PENALTY", "Evaluation", "evaluate", "Evaluator", "scalar_groups", "scenario_with"]

#: cost of a failed candidate (finite, so rankings and medians stay defined)
PENALTY = 1.0e6


@dataclass
class Evaluation:
    """Costs of P candidates.

    Attributes
    ----------
    F : (P, n_obj) costs to minimise (penalised)
    terms : dict of (P,) arrays, the cost's ingredients
    reasons : list of str, '' for a valid candidate
    values : (P, n_genes) decoded gene values
    """

    F: np.ndarray
    terms: dict
    reasons: list
    values: np.ndarray

    @classmethod
    def concat(cls, parts: list[Evaluation]) -> Evaluation:
        """The evaluations of consecutive slices of a population, joined in order."""
        return cls(F=np.concatenate([p.F for p in parts]),
                   terms={k: np.concatenate([p.terms[k] for p in parts]) for k in parts[0].terms},
                   reasons=[r for p in parts for r in p.reasons],
                   values=np.concatenate([p.values for p in parts]))


def _condition(scn, cond: dict):
    for key, value in cond.items():
        node, _, name = key.partition(".")
        scn = scn.with_values(node, **{name: value})
    return scn


def _add(terms: dict, key: str, value: np.ndarray) -> None:
    terms[key] = terms.get(key, 0.0) + value


#: candidates simulated at once: a population is run in slices of this many episodes, so an
#: evaluation holds O(P) results plus at most one slice's trajectories, not O(P x K) (bench_tuner.py
#: measures it); runs the compiled driver summarises keep no trajectory at all
EPISODES_PER_SLICE = 128


def _runnable(params: dict[str, np.ndarray], n: int, fail) -> dict[str, np.ndarray]:
    """``params`` with the rows of the candidates that break a parameter's rule (failed here, in the controller
    node's words) set to the parameters' defaults: the engine refuses such values, and their cost is the penalty
    whatever they would give."""
    faults = episode_parameter_faults(params, n)
    if not faults:
        return params
    bad = np.zeros(n, dtype=bool)
    bad[list(faults)] = True
    for p, why in faults.items():
        fail(np.arange(n) == p, why)
    out = {}
    for name, v in params.items():
        v = np.array(v)
        v[bad] = spec_for("controller", name).default
        out[name] = v
    return out


def evaluate(spec: TuningSpec, x: np.ndarray, first: int = 0, threads: int | None = None) -> Evaluation:
    """Run and score the candidates ``x`` (P, n_var) in this process.

    Parameters
    ----------
    spec : TuningSpec
    x : (P, n_var)
    first : int
        Index of ``x[0]`` in the whole population: candidate i gets noise seed
        ``disturbance.noise.seed + first + i``, so results do not depend on how
        a population is split between workers or slices.
    threads : int, optional
        Threads of the compiled engine (1 inside worker processes).
    """
    x = np.atleast_2d(x)
    per = _slice_size(spec)
    if x.shape[0] > per:
        return Evaluation.concat([evaluate(spec, x[i:i + per], first + i, threads)
                                  for i in range(0, x.shape[0], per)])
    params, values = decode(spec, x)
    final_time = params.pop("final_time", None)
    n_cand = values.shape[0]
    robust = spec.robust
    reps = robust.get("runs", 1) if robust else 1
    if reps > 1 or robust:  # candidate i's runs are episodes i * reps .. i * reps + reps - 1
        params = {k: np.repeat(v, reps, axis=0) for k, v in params.items()}
        final_time = None if final_time is None else np.repeat(final_time, reps, axis=0)
    n = n_cand * reps
    groups = scalar_groups(params, n)
    params = {k: v for k, v in params.items() if not is_scalar(k) or k in PER_EPISODE_SCALARS}
    cost = spec.cost
    name = cost["name"]
    n_obj = 2 if name == "ts_ce" else 1
    F = np.zeros((n, n_obj))
    terms: dict[str, np.ndarray] = {}
    reasons = [""] * n

    def fail(mask, why):
        for p in np.nonzero(mask)[0]:
            if not reasons[p]:
                reasons[p] = why

    if "geometric.k" in params:
        k = params["geometric.k"]
        fail((k[:, 0] == k[:, 1]) | (k[:, 1] == k[:, 2]) | (k[:, 0] == k[:, 2]),
             "equal k_i (paper 001: the entries of K must differ)")
    params = _runnable(params, n, fail)
    for base in spec.scenarios:
        for cond in spec.conditions:
            scn = scenario_for(spec, base, cond)
            # candidate (first + i)'s noise seed, the same in each of its robust runs unless they disperse it
            seeds = scn.param("disturbance", "noise.seed") + np.repeat(first + np.arange(n_cand), reps)
            dispersed = None
            if robust:  # the same dispersed runs for every candidate (common random numbers)
                dispersed = {k: np.tile(v, (n_cand,) + (1,) * (np.ndim(v) - 1))
                             for k, v in episode_values(scn, robust["dispersions"], robust["seed"],
                                                        np.arange(reps)).items()}
            run = simulate if name == "paper004_objective" else simulate_summary  # eq. 7 needs the series
            for fixed, rows in groups:
                group = scenario_with(scn, fixed)
                result = run(group, rows.size, controller_params={k: v[rows] for k, v in params.items()},
                             controller=spec.controller, schedule=[], threads=threads, warn_nonfinite=False,
                             episode_values={"disturbance.noise.seed": seeds[rows],
                                             **{k: v[rows] for k, v in (dispersed or {}).items()}})
                _score_rows(spec, group, result, None if final_time is None else final_time[rows], rows,
                            (F, terms, fail))
    for p, why in enumerate(reasons):
        if why:
            F[p] = PENALTY
    F = np.nan_to_num(F, nan=PENALTY, posinf=PENALTY)
    terms = {k: np.asarray(v) for k, v in terms.items()}
    if robust:  # a candidate's cost: the mean or the worst of its runs
        reduce = np.max if robust["statistic"] == "max" else np.mean
        F = reduce(F.reshape(n_cand, reps, -1), axis=1)
        terms = {k: reduce(np.broadcast_to(v, (n,)).reshape(n_cand, reps), axis=1) for k, v in terms.items()}
        reasons = [next((f"robust run {j}: {reasons[i * reps + j]}" for j in range(reps) if reasons[i * reps + j]),
                        "") for i in range(n_cand)]
    return Evaluation(F=F, terms=terms, reasons=reasons, values=values)


def scalar_groups(params: dict[str, np.ndarray], n: int) -> list[tuple[dict[str, float | int], np.ndarray]]:
    """The episodes grouped by their values of the scalar parameters among ``params``.

    A law's parameter record holds a scalar parameter once for all its
    episodes, so the episodes of a group run as one batch with those values
    set in the scenario (:func:`scenario_with`), and a list parameter keeps
    its row per episode, and so does a scalar of the controller's magnetic
    channel (:data:`~attitude_sil.core.control.momentum.PER_EPISODE_SCALARS`).

    Parameters
    ----------
    params : dict
        Decoded genes, ``name -> (n, ...)``; the scalar parameters' are ``(n,)``.
    n : int
        Episodes.

    Returns
    -------
    list of (dict, ndarray)
        For each distinct set of scalar values, in order of first appearance:
        the values (ROS types: int for an integer parameter) and the indices
        of its episodes. Without scalar genes, one group of every episode.
    """
    names = [k for k in params if is_scalar(k) and k not in PER_EPISODE_SCALARS]
    if not names:
        return [({}, np.arange(n))]
    integer = {k: spec_for("controller", k).kind == "integer" for k in names}
    found: dict[tuple, list[int]] = {}
    for p in range(n):
        key = tuple(int(round(params[k][p])) if integer[k] else float(params[k][p]) for k in names)
        found.setdefault(key, []).append(p)
    return [(dict(zip(names, key, strict=True)), np.asarray(rows)) for key, rows in found.items()]


def scenario_with(scn, fixed: dict):
    """``scn`` with the controller's scalar gene values ``fixed`` set (unchanged when there are none)."""
    return scn.with_values("controller", **fixed) if fixed else scn


def _score_rows(spec: TuningSpec, scn, run, final_time, rows: np.ndarray, into: tuple) -> None:
    """:func:`score` of the episodes ``rows`` of a population, added into its ``(F, terms, fail)``."""
    F, terms, fail = into
    n = F.shape[0]
    part_f = np.zeros((rows.size, F.shape[1]))
    part_terms: dict = {}

    def part_fail(mask, why):
        full = np.zeros(n, dtype=bool)
        full[rows] = mask
        fail(full, why)

    score(spec, scn, run, final_time, part_f, part_terms, part_fail)
    F[rows] += part_f
    for key, value in part_terms.items():
        terms.setdefault(key, np.zeros(n))[rows] += value


def _slice_size(spec: TuningSpec) -> int:
    """Candidates per slice: :data:`EPISODES_PER_SLICE` episodes, a robust cost's runs counted."""
    return max(1, EPISODES_PER_SLICE // (spec.robust.get("runs", 1) if spec.robust else 1))


def scenario_for(spec: TuningSpec, base, cond: dict):
    """The scenario a candidate runs in: a condition applied, and for paper 001's
    costs the law left unsaturated (the actuator still saturates) so the death
    penalty sees what the law asks for."""
    scn = _condition(base, cond)
    if spec.cost["name"] in ("paper001_fitness", "ts_ce"):
        scn = scn.with_values("controller", **{"geometric.torque_limit": 1e3})
    return scn


def score(spec: TuningSpec, scn, run: EpisodeSummary | Trajectory, final_time, F: np.ndarray, terms: dict,
          fail) -> None:
    """Add the cost of P episodes to F and terms.

    ``run`` is their :class:`EpisodeSummary`, or their trajectories (batch
    arrays with a leading P axis: ``t``, ``q_BN``, ``q_RN``, ``omega_BN_B``,
    ``tau_c_B``, ``u_cmd`` and ``wheel_speed``, which may be None), which are
    summarised here; ``paper004_objective`` needs the trajectories.
    ``fail(mask, reason)`` records failures.
    """
    cost = spec.cost
    name = cost["name"]
    s = run if isinstance(run, EpisodeSummary) else summarize(run, scn.values["scenario"],
                                                              step_time=scn.param("guidance", "step_time"))
    law = spec.controller or scn.param("controller", "controller_type")
    fail(~s.finite, f"diverged: non-finite state under {law}")
    wheels = scn.values["wheels"]
    if wheels["actuator"] == "reaction_wheels" and s.peak_wheel_speed is not None:
        limit = wheels["motor.speed_max_rpm"] * 2 * np.pi / 60
        fail(s.peak_wheel_speed >= 0.999 * limit, "runaway wheel speed: a wheel reached its speed limit")
    m = s.metrics
    if name == "paper000_j":
        fail(~np.isfinite(m["cost_J"]), "never reached 63.2 % of the step")
        F[:, 0] += np.nan_to_num(m["cost_J"], nan=PENALTY)
        _add(terms, "time_constant_s", m["time_constant_s"])
        _add(terms, "overshoot_pct", m["overshoot_pct"])
        w_ts, w_itae = float(cost.get("w_ts", 0.0)), float(cost.get("w_itae", 0.0))
        if w_ts > 0.0:
            fail(~np.isfinite(m["settling_time_s"]), "never settled (cost.w_ts > 0)")
            F[:, 0] += w_ts * np.nan_to_num(m["settling_time_s"], nan=PENALTY)
            _add(terms, "settling_time_s", m["settling_time_s"])
        if w_itae > 0.0:
            F[:, 0] += w_itae * np.nan_to_num(m["itae"], nan=PENALTY)
            _add(terms, "itae", m["itae"])
    elif name in ("paper001_fitness", "ts_ce"):
        lim = float(cost.get("limit", scn.values["wheels"]["torque_limit"]))
        peak = s.peak_command
        fail(peak > lim, f"death penalty: commanded torque above {lim:g} N m")
        fail(~np.isfinite(m["settling_time_s"]), "never settled")
        ts = np.nan_to_num(m["settling_time_s"], nan=PENALTY)
        ce = m["control_effort_Nms"]
        if name == "ts_ce":
            F[:, 0] += ts
            F[:, 1] += ce
        else:
            F[:, 0] += ts + float(cost.get("beta", 1.0)) * ce
        _add(terms, "settling_time_s", ts)
        _add(terms, "control_effort_Nms", ce)
        _add(terms, "peak_command_Nm", peak)
    elif name == "mse":
        F[:, 0] += np.nan_to_num(m["mse"], nan=PENALTY)
        _add(terms, "mse", m["mse"])
        _add(terms, "settling_time_s", m["settling_time_s"])
    elif name == "paper004_objective":
        F[:, 0] += _paper004(run, scn, cost, final_time, terms)
    elif name == "momentum":
        peak, effort = m["wheel_momentum_peak_Nms"], m["dipole_effort_Am2s"]
        F[:, 0] += np.nan_to_num(peak, nan=PENALTY, posinf=PENALTY) + float(cost.get("w_dipole", 0.0)) * effort
        _add(terms, "wheel_momentum_peak_Nms", peak)
        _add(terms, "dipole_effort_Am2s", effort)


def _paper004(tr, scn, cost, final_time, terms) -> np.ndarray:
    """Paper 004 eq. 7 with the two-level penalty of eq. 8, per candidate."""
    axis = scn.values["scenario"]["metrics.axis"]
    theta = euler_from_quat(tr.q_BN)[..., axis]
    rate = tr.omega_BN_B[..., axis]
    u = tr.u_cmd[..., axis]
    dt = tr.t[1] - tr.t[0]
    n = theta.shape[0]
    tf = np.full(n, tr.t[-1]) if final_time is None else np.clip(final_time[:, 0], dt, tr.t[-1])
    k_f = np.minimum(np.round(tf / dt).astype(int), tr.t.size - 1)
    w1, w2, w3 = (float(cost.get(k, 1.0)) for k in ("w1", "w2", "w3"))
    k1, k2, big = float(cost.get("k1", 200.0)), float(cost.get("k2", 100.0)), float(cost.get("K", 100.0))
    theta_max = np.radians(float(cost.get("theta_max_deg", 30.0)))
    integrand = w1 * theta**2 + w2 * u**2
    f = np.array([np.sum(integrand[p, :k_f[p]]) * dt for p in range(n)]) + w3 * tf
    th_f = np.abs(theta[np.arange(n), k_f])
    q_f = np.abs(rate[np.arange(n), k_f])
    p0 = k1 * th_f + k2 * q_f
    pen = np.where(th_f <= theta_max / 4, p0, big * p0)
    _add(terms, "objective", f)
    _add(terms, "penalty", pen)
    _add(terms, "final_time_s", tf)
    return f + pen


class Evaluator:
    """Scores populations on an :class:`~attitude_sil.tuning.executor.Executor`.

    Without one, ``workers`` > 1 forks a pool of local processes (the
    default of batch mode), else everything runs in this process. A
    population is cut into consecutive slices that carry their index in the
    population (:func:`evaluate`'s ``first``), so every back-end gives the
    same costs bit for bit. Use as a context manager; the pool lives as long
    as the tuning run.
    """

    def __init__(self, spec: TuningSpec, workers: int = 1, executor: Executor | None = None) -> None:
        self.spec = spec
        self.workers = max(1, int(workers))
        self.executor = executor
        self.own = executor is None

    def __enter__(self) -> Evaluator:
        if self.executor is None:
            self.executor = LocalProcesses(self.workers) if self.workers > 1 else InProcess()
        return self

    def __exit__(self, *exc) -> None:
        if self.own and self.executor is not None:
            self.executor.close()
            self.executor = None

    def __call__(self, x: np.ndarray) -> Evaluation:
        x = np.atleast_2d(x)
        ex = self.executor or InProcess()
        if ex.name == "in-process" or (ex.name == "processes" and x.shape[0] < 2 * ex.workers):
            return evaluate(self.spec, x)
        per = _slice_size(self.spec)
        n_chunks = min(x.shape[0], max(ex.workers, -(-x.shape[0] // per)))
        chunks = np.array_split(x, n_chunks)
        firsts = np.cumsum([0] + [len(c) for c in chunks[:-1]]).tolist()
        # one engine thread per task: the workers are the parallelism (and a forked
        # child must not start the parent's OpenMP runtime)
        return Evaluation.concat(ex.map(evaluate, [(self.spec, c, f, ex.threads) for c, f in zip(chunks, firsts,
                                                                                                  strict=True)]))
