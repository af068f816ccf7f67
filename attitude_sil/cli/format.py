"""Text the ``attitude-sil`` command prints: metric tables, swap segments, tuning progress."""

from __future__ import annotations

import math
from pathlib import Path

__all__ = ["format_table", "format_segments", "format_bar", "format_campaign"]


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
             ("final error angle", "final_error_rad", "rad"),
             ("controller latency mean", "controller_latency_mean_ms", "ms"),
             ("controller latency p99", "controller_latency_p99_ms", "ms"),
             ("controller latency max", "controller_latency_max_ms", "ms"),
             ("controller timing", "command_timing", ""), ("controller period", "command_period_ms", "ms"),
             ("command delay (sim)", "command_delay_ms", "ms"), ("commands received", "command_count", ""),
             ("steps with a stale cmd", "command_stale_steps", ""),
             ("missed periods", "command_missed_periods", "")]
    rows += [(label, metrics[key], unit) for label, key, unit in extra if key in metrics]
    if metrics.get("faults"):
        rows.append(("faults", "; ".join(metrics["faults"]), ""))
    lines = [f"scenario {metrics['scenario']}"]
    for label, value, unit in rows:
        if value is None:
            text = "n/a"
        elif isinstance(value, float):
            text = f"{value:.6g} {unit}".rstrip()
        else:
            text = str(value)
        lines.append(f"  {label:<24} {text}")
    arcsec = math.degrees(1.0) * 3600.0
    if metrics.get("ake_rms_rad") is not None:  # the sensing loop ran: the pointing budget (--json: always APE)
        for label, key in (("APE RMS (x, y, z)", "ape_rms_rad"), ("APE 99 %", "ape_p99_rad"),
                           ("AKE RMS (x, y, z)", "ake_rms_rad"), ("AKE 99 %", "ake_p99_rad")):
            # per body axis, shown in arcsec (the JSON keeps rad)
            lines.append(f"  {label:<24} " + " ".join(f"{v * arcsec:.4g}" for v in metrics[key]) + " arcsec")
        lines.append(f"  {'pointing figures from':<24} {metrics['pointing_from_s']:.6g} s")
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


def _fdir_lines(f: dict) -> list[str]:
    """The campaign's FDIR figures (:func:`attitude_sil.core.plant.fdir.fdir_report`), a few lines."""
    by_mode = ", ".join(f"{m} {f['failed_by_mode'][m] - f['missed_by_mode'][m]}/{f['failed_by_mode'][m]}"
                        for m in f["failed_by_mode"])
    lines = [f"  fdir: {f['detected']} of {f['failed_runs']} failures detected ({by_mode or 'none failed'}), "
             f"{f['missed']} missed, {f['false_alarms']} false alarm(s) in {f['runs']} runs "
             f"({f['false_alarms_per_hour']:.3g} an hour of healthy flight)"]
    if "latency_s" in f:
        lat = f["latency_s"]
        lines.append(f"  fdir latency: p50 {lat['p50']:.3g} s, p90 {lat['p90']:.3g} s, max {lat['max']:.3g} s")
    return lines


def format_campaign(summary: dict) -> str:
    """The end of ``attitude-sil montecarlo``: runs, rate, percentiles, pass rates, worst runs, outputs."""
    lines = [f"campaign {summary['name']}: {summary['completed_runs']} of {summary['runs']} runs"
             + (" (interrupted: --resume continues)" if summary.get("interrupted") else "")
             + (f" in {summary['wall_time_s']:.1f} s on {summary.get('executor')} ({summary.get('workers')} "
                f"worker(s))" if summary.get("wall_time_s") is not None else "")]
    if summary.get("metrics"):
        lines.append(f"  {'metric':<24}{'p50':>12}{'p90':>12}{'p99':>12}{'never':>7}")
        for key, st in summary["metrics"].items():
            cells = "".join(f"{st[k]:>12.5g}" if k in st else f"{'-':>12}" for k in ("p50", "p90", "p99"))
            lines.append(f"  {key:<24}{cells}{st['never']:>7}")
    for key, req in summary.get("requirements", {}).items():
        rule = " and ".join(f"{'<=' if b == 'max' else '>='} {req[b]:g}" for b in ("min", "max") if b in req)
        rate = "n/a" if req.get("pass_rate") is None else f"{100 * req['pass_rate']:.1f} %"
        lines.append(f"  requirement {key} {rule}: {rate} pass")
    if "pass_rate" in summary:
        lines.append(f"  all requirements: {100 * summary['pass_rate']:.1f} % pass, "
                     f"{summary.get('diverged_runs', 0)} diverged")
    if "fdir" in summary:
        lines += _fdir_lines(summary["fdir"])
    for w in summary.get("worst", []):
        lines.append("  worst: " + ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}"
                                             for k, v in w.items()))
    lines.append(f"results in {summary.get('output')} (runs.csv/.json, summary.json"
                 + "".join(f", {Path(p).name}" for p in summary.get("plots", []))
                 + (", bags/" if summary.get("bags") else "") + ")")
    return "\n".join(lines)
