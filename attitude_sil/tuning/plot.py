"""``attitude-sil plot RESULTS``: cost per generation and, for NSGA-II, the Pareto front."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .evaluate import PENALTY
from .spec import SpecError

__all__ = ["plot_results"]


def _json(path: Path):
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SpecError(f"{path}: not a results file of attitude-sil tune ({' '.join(str(exc).split())})") from None


def _rows(folder: Path) -> list[dict]:
    """The evaluated candidates (``evaluations.json``, else the log of a run still going or stopped)."""
    path = folder / "evaluations.json"
    if path.is_file():
        rows = _json(path)
    else:
        path = folder / "evaluations.jsonl"
        rows = []
        for line in path.read_bytes().decode("utf-8", errors="replace").splitlines():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                break  # a line torn by a stopped run ends the log
    good = isinstance(rows, list) and all(
        isinstance(r, dict) and isinstance(r.get("generation"), int) and isinstance(r.get("cost"), list)
        and r["cost"] and all(isinstance(c, (int, float)) for c in r["cost"]) for r in rows)
    if not good:
        raise SpecError(f"{path}: not a results file of attitude-sil tune (rows of generation, cost, ...)")
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
    summary = _json(folder / "summary.json") if (folder / "summary.json").is_file() else {}
    if not isinstance(summary, dict):
        raise SpecError(f"{folder / 'summary.json'}: not a results file of attitude-sil tune (expected an object)")
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
