"""The ``attitude-sil`` command.

Subcommands (DESIGN.md section 5): ``run`` is implemented here; ``tune``,
``replay``, ``bag``, ``plot`` and ``param`` arrive with their issues and say
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
        ("controller", metrics["controller_type"], ""),
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
    record = None
    if not args.no_record:
        record = Path(args.record) if args.record else Path("bags") / (
            f"{scn.name}_{datetime.now().strftime('%Y%m%d_%H%M%S')}")
    result = run_graph(scn, duration=args.duration, controller=args.controller, record_dir=record,
                       processes=args.processes, real_time=args.real_time, progress=not args.quiet)
    print(_format_table(result.metrics))
    if args.json:
        print(json.dumps(result.metrics))
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
    run.set_defaults(func=_cmd_run)
    for name in ("tune", "replay", "bag", "plot", "param"):
        p = sub.add_parser(name, help="(not implemented yet)")
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(func=_not_yet(name))
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``attitude-sil``."""
    from attitude_sil.core.scenario import ScenarioError
    from attitude_sil.runner import RunError

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("interrupted; everything recorded so far is kept", file=sys.stderr)
        return 130
    except (ScenarioError, RunError, ValueError, FileNotFoundError) as exc:
        print(f"attitude-sil: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
