"""Figures of a Monte Carlo campaign: the dispersed responses and histograms of the metrics."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from attitude_sil.core.analysis.metrics import principal_angle
from attitude_sil.core.plant.quaternion import euler_from_quat
from attitude_sil.core.sim.engine import simulate

from .dispersions import FAULTS_KEY, episode_values, run_scenario
from .montecarlo import METRIC_KEYS, MonteCarloSpec

__all__ = ["plot_campaign"]

_AXES = ("roll", "pitch", "yaw")


def _sample(spec: MonteCarloSpec, sample: np.ndarray):
    """The trajectories (q_BN, q_RN, every ``plot.stride``-th step) of runs ``sample``: in one batch, or one
    run at a time where each run has faults of its own (``dispersions.faults``)."""
    scn = spec.scenario
    values = episode_values(scn, spec.dispersions, spec.seed, sample)
    seeds = scn.param("disturbance", "noise.seed") + sample
    options = {"controller": spec.controller, "stride": spec.plot["stride"], "keep": ("q_BN", "q_RN")}
    if FAULTS_KEY not in values:
        return simulate(scn, sample.size, episode_values={"disturbance.noise.seed": seeds, **values}, **options)
    runs = [simulate(run_scenario(scn, values, r), 1, episode_values={"disturbance.noise.seed": seeds[r:r + 1]},
                     **options) for r in range(sample.size)]
    return replace(runs[0], q_BN=np.concatenate([t.q_BN for t in runs]), q_RN=np.concatenate([t.q_RN for t in runs]))


def plot_campaign(spec: MonteCarloSpec, table: dict[str, np.ndarray], out: Path) -> list[Path]:
    """Write ``responses.png`` (the first ``plot.runs`` runs, every ``plot.stride``-th step) and
    ``histograms.png`` (each metric over every completed run, requirement limits dashed) into ``out``.

    The responses are re-simulated here from the runs' dispersions (bit for bit the campaign's runs);
    only that sample's trajectories are ever held. Returns the files written.
    """
    written = []
    runs = np.asarray(table.get("run", []), dtype=np.int64)
    sample = np.sort(runs)[:spec.plot["runs"]]
    scn = spec.scenario
    if sample.size:
        tr = _sample(spec, sample)
        fig = Figure(figsize=(9, 5), layout="constrained")
        ax = fig.add_subplot()
        if scn.param("scenario", "metrics.mode") == "tracking":
            y = np.maximum(np.degrees(principal_angle(tr.q_BN, tr.q_RN)), 1e-6)
            ax.set_yscale("log")
            limit = scn.param("scenario", "metrics.settling_angle_deg")
            ax.axhline(limit, ls="--", color="k", lw=0.8, label=f"settling limit {limit:g} deg")
            ax.set_ylabel("principal error angle, deg")
        else:
            axis = scn.param("scenario", "metrics.axis")
            y = np.degrees(euler_from_quat(tr.q_BN)[..., axis])
            r = np.degrees(euler_from_quat(tr.q_RN)[..., axis])
            for p in range(sample.size):
                ax.plot(tr.t, r[p], lw=0.5, alpha=0.4, color="C1", ls="--", label="setpoints" if p == 0 else None)
            ax.set_ylabel(f"{_AXES[axis]}, deg")
        for p in range(sample.size):
            ax.plot(tr.t, y[p], lw=0.5, alpha=0.35, color="C0", label="runs" if p == 0 else None)
        lo, mid, hi = np.percentile(y, [5, 50, 95], axis=0)
        ax.fill_between(tr.t, lo, hi, color="C2", alpha=0.25, label="5-95 % of the runs")
        ax.plot(tr.t, mid, color="C2", lw=1.5, label="median")
        ax.legend(fontsize=8, loc="best")
        ax.set_xlabel("t, s")
        ax.set_title(f"{spec.name}: {sample.size} of {runs.size} dispersed runs")
        ax.grid(alpha=0.3)
        path = out / "responses.png"
        fig.savefig(path, dpi=110)
        written.append(path)
    keys = [k for k in spec.requirements if k in table] + [k for k in METRIC_KEYS if k in table and k not in
                                                            spec.requirements]
    keys = [k for k in keys if np.isfinite(table[k].astype(float)).any()][:9]
    if keys:
        cols = 3
        rows = -(-len(keys) // cols)
        fig = Figure(figsize=(11, 3.0 * rows), layout="constrained")
        for i, key in enumerate(keys):
            ax = fig.add_subplot(rows, cols, i + 1)
            v = table[key].astype(float)
            fin = v[np.isfinite(v)]
            ax.hist(fin, bins=40, color="C0", alpha=0.8)
            for bound, value in spec.requirements.get(key, {}).items():
                ax.axvline(value, color="C3", ls="--", lw=1.0, label=f"{bound} {value:g}")
            never = v.size - fin.size
            ax.set_title(key + (f" ({never} never)" if never else ""), fontsize=9)
            if spec.requirements.get(key):
                ax.legend(fontsize=7)
        path = out / "histograms.png"
        fig.savefig(path, dpi=110)
        written.append(path)
    return written
