"""``attitude-sil tune``: tune a controller with a spec (GA, PSO, NSGA-II, root locus).

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    tune = sub.add_parser("tune", help="tune a controller with a spec (GA, PSO, NSGA-II, root locus)")
    tune.add_argument("spec", help="tuning spec YAML (config/tune_*.yaml)")
    tune.add_argument("--resume", action="store_true", help="continue the run saved in the output folder")
    tune.add_argument("--set", action="append", metavar="KEY=VALUE",
                      help="override a spec entry, e.g. --set cost.beta=1000 --set algorithm.generations=5")
    tune.add_argument("--no-record", action="store_true", help="do not re-run bests through the graph")
    tune.add_argument("--quiet", action="store_true", help="no progress bar")
    tune.add_argument("--json", action="store_true", help="print the summary as one JSON object, last line")
    tune.add_argument("--scheduler", metavar="ADDRESS",
                      help="evaluate the populations on a Dask cluster, tcp://HOST:PORT or tls://HOST:PORT "
                      "(default: $DASK_SCHEDULER_ADDRESS, else the spec's evaluation.workers)")
    tune.set_defaults(func=execute)



def _generations_kept(log: Path) -> int:
    """How many generations ``evaluations.jsonl`` holds (a line cut short ends the count)."""
    import json

    generations = set()
    for line in log.read_text().splitlines() if log.is_file() else []:
        try:
            generations.add(json.loads(line)["generation"])
        except (ValueError, KeyError, TypeError):
            break
    return len(generations)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json

    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from attitude_sil.cli.common import announce_domain, resume_command, scheduler_address, set_overrides
    from attitude_sil.cli.format import format_bar
    from attitude_sil.errors import AttitudeSilError, SchedulerLostError
    from attitude_sil.graph.tuner_node import TunerNode, tune
    from attitude_sil.ros.environment import localhost_environment
    from attitude_sil.ros.signals import StopSignals
    from attitude_sil.tuning.optimize import check_output
    from attitude_sil.tuning.spec import apply_overrides, load_spec

    overrides = set_overrides(args.set)
    spec = apply_overrides(load_spec(args.spec), overrides)  # bad input is refused before ROS starts
    check_output(spec, args.resume)
    address = scheduler_address(args)
    if address and spec.evaluation.get("mode", "batch") != "batch":
        raise AttitudeSilError(f"{spec.path}: --scheduler evaluates batch mode only (evaluation.mode is "
                               f"{spec.evaluation['mode']})")

    def on_first(signum: int) -> None:
        print(f"{signal.Signals(signum).name}: stopping after this generation (again to stop now)",
              file=sys.stderr, flush=True)

    announce_domain()
    localhost_environment()
    context = rclpy.Context()
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = TunerNode(context=context)

    def progress(stats: dict) -> None:
        node.publish(stats)
        if not args.quiet:
            print(format_bar(stats), file=sys.stderr, flush=True)

    try:
        with StopSignals(on_first=on_first, second_stops_now=True) as stop:
            outcome = tune(spec, resume=args.resume, overrides=overrides, record=not args.no_record,
                           on_progress=progress, should_stop=lambda: stop.requested, scheduler=address)
    except SchedulerLostError as exc:
        # every scored generation is in evaluations.jsonl: the resume command replays them and scores the rest
        here = "drop --scheduler" if args.scheduler is not None else "unset DASK_SCHEDULER_ADDRESS"
        raise SchedulerLostError(
            f"{exc} after {_generations_kept(spec.output / 'evaluations.jsonl')} generation(s); nothing finished "
            f"is lost: {resume_command(args)} finishes the tuning run (start the scheduler again, or {here} to "
            "finish here)", exc.address) from None
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    out = outcome.spec.output
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else {}
    summary.update(wall_time_s=outcome.wall_time_s, interrupted=outcome.result.interrupted,
                   evaluations=outcome.result.evaluations, output=str(out))
    best = summary.get("best_cost", [float("nan")])
    print(f"tuning {summary.get('name')}: best cost {', '.join(f'{v:.6g}' for v in best)} after "
          f"{summary.get('evaluations')} evaluations in {summary['wall_time_s']:.1f} s"
          + (" (interrupted: --resume continues)" if summary.get("interrupted") else ""))
    for name, value in (summary.get("best_parameters") or {}).items():
        print(f"  {name}: {value}")
    print(f"results in {summary['output']} (evaluations.csv/.json, best.yaml, summary.json, bags/)")
    if args.json:
        print(json.dumps(summary))
    return (stop.exit_code or 130) if summary.get("interrupted") else 0
