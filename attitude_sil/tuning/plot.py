"""``attitude-sil plot RESULTS``: cost per generation and, for NSGA-II, the Pareto front."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .evaluate import PENALTY
from .spec import SpecError

__all__ = ["plot_results"]


def _rows(folder: Path) -> list[dict]:
    path = folder / "evaluations.json"
    if path.is_file():
        return json.loads(path.read_text())
    log = folder / "evaluations.jsonl"
    rows = []
    for line in log.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            break
    return rows


def plot_results(folder: str | Path, out_png: str | Path) -> Path:
    """Best and median cost per generation (log scale); the (Ts, Ce) front for two objectives.

    Raises
    ------
    SpecError
        The folder holds no evaluations.
    """

    folder = Path(folder)
    rows = _rows(folder)
    if not rows:
        raise SpecError(f"{folder}: no evaluations to plot")
    summary = json.loads((folder / "summary.json").read_text()) if (folder / "summary.json").is_file() else {}
    gens = sorted({r["generation"] for r in rows})
    costs = {g: np.array([r["cost"][0] for r in rows if r["generation"] == g]) for g in gens}
    best_so_far = np.minimum.accumulate([c.min() for c in costs.values()])
    gen_best = np.array([c.min() for c in costs.values()])
    median = np.array([np.median(c[c < PENALTY]) if np.any(c < PENALTY) else np.nan for c in costs.values()])
    failed = np.array([np.sum(c >= PENALTY) for c in costs.values()])
    two = len(rows[0]["cost"]) == 2
    fig = Figure(figsize=(12 if two else 8, 4.6), dpi=110)
    axes = fig.subplots(1, 2 if two else 1, squeeze=False)
    ax = axes[0, 0]
    ax.plot(gens, best_so_far, "-", lw=2, label="best so far")
    ax.plot(gens, gen_best, ".", ms=4, label="best of generation")
    ax.plot(gens, median, "--", label="median of generation (valid)")
    if np.all(best_so_far > 0):
        ax.set_yscale("log")
    ax.set_xlabel("generation")
    ax.set_ylabel("cost" + (" (first objective, Ts s)" if two else ""))
    ax.grid(True, which="both", alpha=0.3)
    if failed.any():
        ax2 = ax.twinx()
        ax2.bar(gens, failed, alpha=0.15, color="red", label="failed (penalised)")
        ax2.set_ylabel("failed candidates")
        ax2.legend(loc="center right", fontsize=8)
        ax.set_zorder(ax2.get_zorder() + 1)  # lines over the bars
        ax.patch.set_visible(False)
    ax.legend(loc="upper center", fontsize=8)
    algo = summary.get("algorithm", {}).get("name", "")
    ax.set_title(f"{summary.get('name', folder.name)}: {algo}, {len(rows)} evaluations")
    if two:
        ax = axes[0, 1]
        valid = np.array([r["cost"] for r in rows if not r["failure"]])
        if valid.size:
            ax.scatter(valid[:, 0], valid[:, 1], s=6, c="0.7", label="evaluated")
        front = np.array([f["cost"] for f in summary.get("pareto_front", [])])
        if front.size:
            ax.plot(front[:, 0], front[:, 1], "o-", color="C3", ms=4, label="Pareto front")
        ax.set_xlabel("settling time Ts (s)")
        ax.set_ylabel("control effort Ce (N m s)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title("trade-off (paper 001 probes it with beta = 1 and 1000)")
    fig.tight_layout()
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    return out
