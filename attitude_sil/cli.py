"""The ``attitude-sil`` command.

Subcommands (DESIGN.md section 5): ``run`` and ``param`` are implemented;
``tune``, ``replay``, ``bag`` and ``plot`` arrive with their issues and say
so. User errors print one line on stderr and exit 2; Ctrl-C exits 130 after
the bag is closed.
"""

from __future__ import annotations

import argparse
import json
import sys
from datetime import datetime
from pathlib import Path

__all__ = ["main"]


def _format_table(metrics: dict) -> str:
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


def _cmd_run(args: argparse.Namespace) -> int:
    from attitude_sil.core.scenario import load_scenario
    from attitude_sil.runner import run_graph

    scn = load_scenario(args.scenario)
    if args.duration is not None and args.duration <= 0:
        raise ValueError(f"--duration must be > 0, got {args.duration}")
    if args.swap:
        times = list(scn.param("scenario", "schedule.times"))
        kinds = list(scn.param("scenario", "schedule.controller_types"))
        for item in args.swap:
            t, _, kind = item.partition(":")
            try:
                times.append(float(t))
            except ValueError:
                raise ValueError(f"--swap takes TIME:TYPE, e.g. 2.0:fuzzy_pid; got {item!r}") from None
            kinds.append(kind)
        order = sorted(range(len(times)), key=times.__getitem__)
        scn = scn.with_values("scenario", **{"schedule.times": [times[i] for i in order],
                                             "schedule.controller_types": [kinds[i] for i in order]})
    record = None
    if not args.no_record:
        record = Path(args.record) if args.record else Path("bags") / (
            f"{scn.name}_{datetime.now().strftime('%Y%m%d_%H%M%S')}")
    result = run_graph(scn, duration=args.duration, controller=args.controller, record_dir=record,
                       processes=args.processes, real_time=args.real_time, progress=not args.quiet)
    print(_format_table(result.metrics))
    if result.metrics.get("segments"):
        print(_format_segments(result.metrics["segments"]))
    if args.json:
        print(json.dumps(result.metrics))
    return 0


def _format_segments(segments: list[dict]) -> str:
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


def _cmd_linearize(args: argparse.Namespace) -> int:
    from attitude_sil.core.scenario import load_scenario
    from attitude_sil.linearize import PAPER_000_COMPARISON_GAINS, format_table, rmse_table

    scn = load_scenario(args.scenario)
    if scn.param("plant", "model") not in ("rigid_body", "linearized"):
        raise ValueError(f"{args.scenario}: linearize needs a rigid-body scenario (plant.model), "
                         f"got {scn.param('plant', 'model')}")
    gains = tuple(args.gains) if args.gains else PAPER_000_COMPARISON_GAINS
    table = rmse_table(scn, args.angles, gains, duration=args.duration)
    print(format_table(args.angles, table))
    if args.json:
        print(json.dumps({"angles_deg": list(args.angles), "rmse_deg": table.tolist(), "gains": list(gains)}))
    return 0


def _cmd_param(args: argparse.Namespace) -> int:
    from attitude_sil.paramclient import param_command

    if args.action in ("get", "set") and not args.name:
        raise ValueError(f"param {args.action} needs a parameter NAME")
    if args.action == "set" and args.value is None:
        raise ValueError("param set needs a VALUE")
    print(param_command(args.action, args.node, args.name, args.value, timeout=args.timeout))
    return 0


def _not_yet(name: str):
    def run(args: argparse.Namespace) -> int:
        raise ValueError(f"'attitude-sil {name}' is not implemented yet")
    return run


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="attitude-sil", description="Spacecraft attitude-control SIL on ROS 2.")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scenario headless through the ROS 2 graph")
    run.add_argument("scenario", help="scenario parameter YAML (config/*.yaml)")
    run.add_argument("--controller", help="controller_type to start with")
    run.add_argument("--duration", type=float, help="episode length, s (default: plant.duration)")
    rec = run.add_mutually_exclusive_group()
    rec.add_argument("--record", metavar="DIR", help="bag directory (default bags/<scenario>_<time>)")
    rec.add_argument("--no-record", action="store_true", help="do not record a bag")
    run.add_argument("--json", action="store_true", help="print the metrics as one JSON object, last line")
    run.add_argument("--processes", action="store_true", help="one process per node (over DDS)")
    run.add_argument("--real-time", action="store_true", help="pace the plant at real time")
    run.add_argument("--quiet", action="store_true", help="no progress line")
    run.add_argument("--swap", action="append", metavar="TIME:TYPE",
                     help="swap controller_type at a sim time (repeatable), e.g. --swap 2.0:fuzzy_pid")
    run.set_defaults(func=_cmd_run)
    lin = sub.add_parser("linearize", help="nonlinear vs linearised model RMSE table (paper 000 Table 1)")
    lin.add_argument("scenario", help="rigid-body scenario YAML (e.g. config/hst_roll_step.yaml)")
    lin.add_argument("--angles", type=float, nargs="+", default=[3, 8, 15, 25, 35], help="commands, deg")
    lin.add_argument("--gains", type=float, nargs=4, metavar=("KP", "KI", "KD", "N"),
                     help="PID of the comparison (default: paper 000's 52.995 2.488 132.442 4.748)")
    lin.add_argument("--duration", type=float, help="episode length, s (default: the scenario's)")
    lin.add_argument("--json", action="store_true", help="also print the table as one JSON object")
    lin.set_defaults(func=_cmd_linearize)
    param = sub.add_parser("param", help="list, get or set parameters of a running node")
    param.add_argument("action", choices=("list", "get", "set"))
    param.add_argument("node", help="node name, e.g. controller")
    param.add_argument("name", nargs="?", help="parameter name")
    param.add_argument("value", nargs="?", help="new value, parsed as YAML (e.g. '[1.0, 2.0, 3.0]')")
    param.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the node")
    param.set_defaults(func=_cmd_param)
    for name in ("tune", "replay", "bag", "plot"):
        p = sub.add_parser(name, help="(not implemented yet)")
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=_not_yet(name))
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``attitude-sil``."""
    from attitude_sil.core.scenario import ScenarioError
    from attitude_sil.paramclient import ParamClientError
    from attitude_sil.runner import RunError

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("interrupted; everything recorded so far is kept", file=sys.stderr)
        return 130
    except (ScenarioError, RunError, ParamClientError, ValueError, FileNotFoundError) as exc:
        print(f"attitude-sil: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
