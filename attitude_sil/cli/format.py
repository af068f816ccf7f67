"""Text the ``attitude-sil`` command prints: metric tables, swap segments, tuning progress."""

from __future__ import annotations

import math

__all__ = ["format_table", "format_segments", "format_bar"]


def format_table(metrics: dict) -> str:
    """The ``run`` metrics as an aligned two-column table."""
    rows = [
        ("controller" + (" (at start)" if metrics.get("segments") else ""), metrics["controller_type"], ""),
        ("sim time", metrics["sim_time_s"], "s"),
        ("wall time", metrics["wall_time_s"], "s"),
        ("real-time factor", metrics["real_time_factor"], "x"),
        ("time constant (63.2 %)", metrics["time_constant_s"], "s"),
        ("rise time (10-90 %)", metrics["rise_time_s"], "s"),
        ("settling time", metrics["settling_time_s"], "s"),
        ("overshoot", metrics["overshoot_pct"], "%"),
        ("steady-state error", metrics["steady_state_error_rad"], "rad"),
        ("control effort Ce", metrics["control_effort_Nms"], "N m s"),
        ("cost J (eq. 19)", metrics["cost_J"], ""),
        ("IAE", metrics["iae"], "rad s"),
        ("ISE", metrics["ise"], "rad^2 s"),
        ("ITAE", metrics["itae"], "rad s^2"),
    ]
    extra = [("MSE (paper 002 eq. 10)", "mse", "rad^2"), ("max |error|", "max_abs_error_rad", "rad"),
             ("fitness f (paper 001 eq. 8)", "fitness_f", ""),
             ("final error angle", "final_error_rad", "rad")]
    rows += [(label, metrics[key], unit) for label, key, unit in extra if key in metrics]
    lines = [f"scenario {metrics['scenario']}"]
    for label, value, unit in rows:
        if value is None:
            text = "n/a"
        elif isinstance(value, float):
            text = f"{value:.6g} {unit}".rstrip()
        else:
            text = str(value)
        lines.append(f"  {label:<24} {text}")
    if metrics.get("bag"):
        lines.append(f"  {'bag':<24} {metrics['bag']}")
    return "\n".join(lines)


def format_segments(segments: list[dict]) -> str:
    """Per-controller metrics of a run with scheduled swaps, one column per segment."""
    rows = [("controller", "controller_type", "{}"), ("from", "t_start_s", "{:.2f} s"), ("to", "t_end_s", "{:.2f} s"),
            ("IAE", "iae", "{:.4g} rad s"), ("ISE", "ise", "{:.4g} rad^2 s"),
            ("max |error|", "max_abs_error_rad", "{:.4g} rad"), ("RMS error", "rms_error_rad", "{:.4g} rad"),
            ("control effort Ce", "control_effort_Nms", "{:.4g} N m s"), ("max |command|", "max_abs_command", "{:.4g}")]
    width = 22
    lines = ["per controller (scheduled swaps):"]
    for label, key, fmt in rows:
        cells = [fmt.format(seg[key]) if seg.get(key) is not None else "n/a" for seg in segments]
        lines.append(f"  {label:<20}" + "".join(f"{c:>{width}}" for c in cells))
    return "\n".join(lines)



def format_bar(stats: dict, width: int = 24) -> str:
    """One line of tuning progress: generation, a bar, best and median cost, failures, speed."""
    done = stats["generation"] / max(stats["generations"], 1)
    fill = int(round(done * width))
    median = stats["median"]
    med = "n/a" if not math.isfinite(median) else f"{median:.4g}"
    return (f"gen {stats['generation']:>3}/{stats['generations']} [{'#' * fill}{'.' * (width - fill)}] "
            f"best {stats['best']:.5g}  median {med}  failed {stats['failed']}  "
            f"{stats['evals_per_s']:.0f} evals/s" + ("  (from the saved run)" if stats.get("cached") else ""))
