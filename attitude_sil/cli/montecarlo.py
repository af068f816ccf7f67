"""``attitude-sil montecarlo``: a Monte Carlo campaign: one scenario and design over dispersed runs.

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
    mc = sub.add_parser("montecarlo", help="a Monte Carlo campaign: one scenario and design over dispersed runs")
    mc.add_argument("spec", help="campaign spec YAML (config/mc_*.yaml)")
    mc.add_argument("--runs", type=int, help="number of runs (default: the spec's runs)")
    mc.add_argument("--resume", action="store_true", help="run only what the output folder does not hold yet")
    mc.add_argument("--output", metavar="DIR", help="the results folder (default: the spec's output)")
    mc.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help="override a spec entry, e.g. --set seed=7 --set requirements.settling_time_s.max=15 "
                    "--set set.disturbance.noise.power=[1e-7,1e-7,1e-7]")
    where = mc.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run the chunks on a Dask cluster, tcp://HOST:PORT or tls://HOST:PORT "
                       "(default: $DASK_SCHEDULER_ADDRESS, else local processes)")
    where.add_argument("--in-process", action="store_true", help="run every chunk in this process")
    mc.add_argument("--workers", type=int, help="local worker processes (default: one per core)")
    mc.add_argument("--no-bags", action="store_true", help="do not re-run the worst runs through the graph")
    mc.add_argument("--quiet", action="store_true", help="no progress bar")
    mc.add_argument("--json", action="store_true", help="print summary.json as one JSON object, last line")
    mc.set_defaults(func=execute)



def _chunks_kept(log: Path) -> int:
    """How many whole chunk lines ``chunks.jsonl`` holds after its header (a line cut short ends the count)."""
    import json

    count = 0
    for line in log.read_text().splitlines()[1:] if log.is_file() else []:
        try:
            json.loads(line)
        except ValueError:
            break
        count += 1
    return count


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json
    import os

    from attitude_sil.cli.common import announce_domain, resume_command, scheduler_address, set_overrides
    from attitude_sil.cli.format import format_campaign
    from attitude_sil.errors import AttitudeSilError, SchedulerLostError
    from attitude_sil.graph.session import run_graph
    from attitude_sil.ros.signals import StopSignals
    from attitude_sil.tuning.executor import make_executor
    from attitude_sil.tuning.mcplot import plot_campaign
    from attitude_sil.tuning.montecarlo import check_campaign_output, load_mc_spec, run_campaign, run_of, worst_runs

    if args.workers is not None and args.workers < 1:
        raise AttitudeSilError(f"--workers must be >= 1, got {args.workers}")
    if args.runs is not None and args.runs < 1:
        raise AttitudeSilError(f"--runs must be >= 1, got {args.runs}")
    overrides = set_overrides(args.set)
    if args.output is not None:
        overrides["output"] = args.output
    spec = load_mc_spec(args.spec, runs=args.runs, overrides=overrides)  # bad input is refused before anything runs
    check_campaign_output(spec, args.resume)
    address = scheduler_address(args)
    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    show = not args.quiet and sys.stderr.isatty()

    def on_first(signum: int) -> None:
        print(f"\n{signal.Signals(signum).name}: stopping after the running chunks (again to stop now); "
              "finished runs are kept, --resume continues", file=sys.stderr, flush=True)

    def progress(done: int, total: int, wall: float) -> None:
        if show:
            width = 30
            fill = int(width * done / total)
            rate = f"  {done / wall:7.0f} runs/s" if wall > 0 and done else ""
            print(f"\r[{'#' * fill}{'.' * (width - fill)}] {done}/{total} runs{rate}", end="", file=sys.stderr,
                  flush=True)

    try:
        with make_executor(address, workers, in_process=args.in_process) as executor, \
                StopSignals(on_first=on_first, second_stops_now=True) as stop:
            result = run_campaign(spec, executor, resume=args.resume, progress=progress,
                                  should_stop=lambda: stop.requested)
    except SchedulerLostError as exc:
        if show:
            print(file=sys.stderr)  # end the progress bar's line
        # every finished chunk is in chunks.jsonl: the resume command runs only the others, anywhere
        here = "drop --scheduler" if args.scheduler is not None else "add --in-process"
        raise SchedulerLostError(
            f"{exc} after {_chunks_kept(spec.output / 'chunks.jsonl')} of {len(spec.chunks())} chunks; nothing "
            f"finished is lost: {resume_command(args)} finishes the campaign (start the scheduler again, or "
            f"{here} to finish here)", exc.address) from None
    if show:
        print(file=sys.stderr)
    out = spec.output
    summary = result.summary
    files = plot_campaign(spec, result.table, out) if result.table else []
    bags = []
    if not result.interrupted and not args.no_bags:
        announced = []
        for rank, row in enumerate(worst_runs(spec, result.table), start=1):
            run = int(result.table["run"][row])
            path = out / "bags" / f"worst_{rank:02d}_run{run:06d}"
            if path.exists():
                bags.append(str(path))
                continue
            run_graph(run_of(spec, run), controller=spec.controller, record_dir=path, progress=False,
                      before_start=(lambda: announced or (announced.append(1), announce_domain())))
            bags.append(str(path))
    summary.update(output=str(out), plots=[str(f) for f in files], bags=bags)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(format_campaign(summary))
    if args.json:
        print(json.dumps(summary))
    return (stop.exit_code or 130) if result.interrupted else 0
