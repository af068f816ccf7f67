"""The ``attitude-sil`` command: subcommands, their arguments, and one-line errors.

Subcommands (docs/architecture.md, "Command line"): ``run``, ``tune``,
``montecarlo``, ``replay``, ``bag info``, ``plot``, ``param``, ``record``,
``episode``, ``metrics``, ``linearize``, ``robustness`` and ``fidelity``. Any
:class:`~attitude_sil.errors.AttitudeSilError` (every user error) prints one
line on stderr and exits 2; Ctrl-C exits 130 after the bag is closed. A
traceback means a bug.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
from datetime import datetime
from pathlib import Path

import rclpy
import yaml
from rclpy.signals import SignalHandlerOptions

from attitude_sil.cli.format import format_bar, format_campaign, format_segments, format_table
from attitude_sil.core import yaml12
from attitude_sil.core.control import registry
from attitude_sil.core.linearize import PAPER_000_COMPARISON_GAINS, PAPER_000_TABLE_1_DURATION, rmse_table
from attitude_sil.core.linearize import format_table as format_rmse_table
from attitude_sil.core.scenario import load_scenario, with_parameter_file
from attitude_sil.errors import AttitudeSilError
from attitude_sil.graph.session import run_graph
from attitude_sil.graph.tuner_node import TunerNode, tune
from attitude_sil.ros.environment import isolated_domain, localhost_environment
from attitude_sil.ros.signals import StopSignals
from attitude_sil.storage.foxglove import DEFAULT_HOST, DEFAULT_PORT, FoxgloveLive, check_port
from attitude_sil.storage.info import format_info
from attitude_sil.storage.reader import open_bag
from attitude_sil.tools.live import bag_metrics, check_topics, play_episode, record_graph, scenario_settings
from attitude_sil.tools.paramclient import param_command, param_dump, param_load
from attitude_sil.tools.plot import plot_bag
from attitude_sil.tools.replay import ReplayOptions, replay_bag
from attitude_sil.tools.verify import verify_controller
from attitude_sil.tuning.executor import check_scheduler_address, make_executor
from attitude_sil.tuning.fidelity import PAPERS, check, format_report
from attitude_sil.tuning.mcplot import plot_campaign
from attitude_sil.tuning.montecarlo import check_campaign_output, load_mc_spec, run_campaign, run_of, worst_runs
from attitude_sil.tuning.optimize import check_output
from attitude_sil.tuning.plot import plot_results
from attitude_sil.tuning.robustness import format_robustness, robustness
from attitude_sil.tuning.spec import apply_overrides, load_spec

__all__ = ["build_parser", "main"]


def _announce_domain() -> None:
    """Take a ROS domain of the run's own (unless the user set one) and say which, so tools can reach it."""
    domain, chosen = isolated_domain()
    if chosen:
        print(f"graph on ROS_DOMAIN_ID={domain} (its own; reach it with ROS_DOMAIN_ID={domain} attitude-sil param ...)",
              file=sys.stderr, flush=True)


def _cmd_run(args: argparse.Namespace) -> int:
    scn = _load_with_params(args.scenario, args.params)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise AttitudeSilError(f"--duration must be a finite number of seconds > 0, got {args.duration}")
    if args.swap:
        times = list(scn.param("scenario", "schedule.times"))
        kinds = list(scn.param("scenario", "schedule.controller_types"))
        for item in args.swap:
            t, colon, kind = item.partition(":")
            try:
                times.append(float(t))
            except ValueError:
                colon = ""
            if not colon:
                raise AttitudeSilError(f"--swap takes TIME:TYPE, e.g. 2.0:fuzzy_pid; got {item!r}")
            kinds.append(kind)
        order = sorted(range(len(times)), key=times.__getitem__)
        try:
            scn = scn.with_values("scenario", **{"schedule.times": [times[i] for i in order],
                                                 "schedule.controller_types": [kinds[i] for i in order]})
        except AttitudeSilError as exc:
            raise AttitudeSilError(f"--swap: {exc}") from None
    if args.foxglove is None and (args.foxglove_fast or args.foxglove_host is not None):
        raise AttitudeSilError("--foxglove-fast and --foxglove-host go with --foxglove [PORT]")
    host = DEFAULT_HOST if args.foxglove_host is None else args.foxglove_host
    if args.foxglove is not None:
        check_port(args.foxglove, host)
    record = None
    if not args.no_record:
        record = Path(args.record) if args.record else Path("bags") / (
            f"{scn.name}_{datetime.now().strftime('%Y%m%d_%H%M%S')}")
    live = None

    def start() -> None:
        nonlocal live
        _announce_domain()
        if args.foxglove is not None:
            live = FoxgloveLive(args.foxglove, host)
            pace = "as fast as it runs" if args.foxglove_fast else "at real time"
            print(f"Foxglove: open connection {live.url} (layout config/foxglove/attitude.json); the run is "
                  f"paced {pace}", file=sys.stderr, flush=True)

    try:
        result = run_graph(scn, duration=args.duration, controller=args.controller, record_dir=record,
                           processes=args.processes, real_time=args.real_time or (
                               args.foxglove is not None and not args.foxglove_fast),
                           progress=not args.quiet, namespace=args.namespace, before_start=start,
                           live=lambda: live)
    finally:
        if live is not None:
            live.close()
    print(format_table(result.metrics))
    if result.metrics.get("segments"):
        print(format_segments(result.metrics["segments"]))
    if args.json:
        print(json.dumps(result.metrics))
    return 0


def _check_timeout(timeout: float) -> None:
    if not (math.isfinite(timeout) and timeout > 0):
        raise AttitudeSilError(f"--timeout must be a finite number of seconds > 0, got {timeout}")


def _cmd_record(args: argparse.Namespace) -> int:
    topics = list(args.topics or [])
    bag = args.bag
    if bag is None and topics:  # "record --topics a b BAG": the list took the bag too
        bag = topics.pop()
    if bag is None:
        raise AttitudeSilError("record: give the bag directory to create, e.g. attitude-sil record bags/live")
    check_topics(topics)
    result = record_graph(bag, topics or None, namespace=args.namespace, episode=args.episode,
                          say=lambda line: print(line, file=sys.stderr, flush=True))
    total = sum(result.counts.values())
    print(f"recorded {total} messages on {len(result.counts)} topic(s) to {result.bag}"
          + ("" if result.snapshot else " (no parameter snapshot: the graph's nodes did not answer)"))
    return 0


def _cmd_episode(args: argparse.Namespace) -> int:
    _check_timeout(args.timeout)
    metrics = play_episode(args.namespace, args.scenario, timeout=args.timeout, progress=not args.quiet,
                           say=lambda line: print(line, file=sys.stderr, flush=True))
    print(format_table(metrics))
    if args.json:
        print(json.dumps(metrics))
    return 0


def _cmd_metrics(args: argparse.Namespace) -> int:
    scenario_settings(args.scenario)  # a bad file is refused before the bag is read
    metrics, notes = bag_metrics(args.bag, args.scenario)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    print(format_table(metrics))
    if args.json:
        print(json.dumps(metrics))
    return 0


def _port(text: str) -> int:
    """``--foxglove PORT``: an integer in 1..65535."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} out of range 1..65535")
    return port


def _cmd_linearize(args: argparse.Namespace) -> int:
    scn = load_scenario(args.scenario)
    if scn.param("plant", "model") not in ("rigid_body", "linearized"):
        raise AttitudeSilError(f"{args.scenario}: linearize needs a rigid-body scenario (plant.model), "
                         f"got {scn.param('plant', 'model')}")
    gains = tuple(args.gains) if args.gains else PAPER_000_COMPARISON_GAINS
    duration = PAPER_000_TABLE_1_DURATION if args.duration is None else args.duration
    table = rmse_table(scn, args.angles, gains, duration=duration)
    print(format_rmse_table(args.angles, table))
    if args.json:
        print(json.dumps({"angles_deg": list(args.angles), "rmse_deg": table.tolist(), "gains": list(gains)}))
    return 0


def _load_with_params(scenario: str, params: str | None):
    """A scenario with a controller parameter file (e.g. a tuner's best.yaml) laid over it."""
    scn = load_scenario(scenario)
    return with_parameter_file(scn, params) if params else scn


def _cmd_robustness(args: argparse.Namespace) -> int:

    rows = robustness(_load_with_params(args.scenario, args.params))
    print(format_robustness(rows))
    if args.json:
        print(json.dumps(rows))
    return 0


def _cmd_fidelity(args: argparse.Namespace) -> int:
    results = check(tuple(args.paper) if args.paper else PAPERS, args.config)
    print(format_report(results))
    if args.json:
        print(json.dumps([r.as_dict() for r in results]))
    return 0 if all(r.status != "FAIL" for r in results) else 1


def _cmd_param(args: argparse.Namespace) -> int:
    if args.action == "dump":
        text = param_dump(args.node, timeout=args.timeout)
        if args.file:
            Path(args.file).write_text(text)
            print(f"wrote {args.file}")
        else:
            print(text, end="")
        return 0
    if args.action == "load":
        report = param_load(args.node, args.file, timeout=args.timeout)
        for line, ok in report.lines:
            print(line, file=sys.stdout if ok else sys.stderr)
        if report.unchanged:
            print(f"{len(report.unchanged)} parameter(s) already at the file's value, not sent")
        return 2 if report.failed else 0
    print(param_command(args.action, args.node, getattr(args, "name", None), getattr(args, "value", None),
                        timeout=args.timeout, hide_type=getattr(args, "hide_type", False)))
    return 0


def _cmd_bag(args: argparse.Namespace) -> int:

    print(format_info(open_bag(args.bag)))
    return 0


def _check_png(out: str) -> None:
    """``-o`` must name a PNG file that can be created (refused before any bag is read)."""
    path = Path(out)
    if path.suffix.lower() != ".png" or path.is_dir():
        raise AttitudeSilError(f"-o {out}: give a .png file to write")
    parent = next((p for p in path.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise AttitudeSilError(f"-o {out}: {parent} is a file, not a directory")


def _cmd_plot(args: argparse.Namespace) -> int:
    _check_png(args.output)
    path = Path(args.path)
    if (path / "summary.json").is_file() or (path / "evaluations.jsonl").is_file():
        out = plot_results(path, args.output)
    else:
        out = plot_bag(path, args.output)
    print(f"wrote {out}")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    if args.verify_controller:
        result = verify_controller(args.bag, params_file=args.params, tolerance=args.tolerance)
        verdict = "PASS" if result.passed else "FAIL"
        print(f"{verdict}: {result.steps} steps, largest command deviation {result.max_deviation:.3g} "
              f"at t={result.worst_time_s:.3f} s (axis {result.worst_axis}), tolerance {result.tolerance:g}, "
              f"{result.swaps} recorded parameter change(s) applied")
        return 0 if result.passed else 1

    options = ReplayOptions(rate=args.rate, start=args.start, duration=args.duration, topics=args.topics,
                            loop=args.loop, namespace=args.namespace)

    # a \r progress line only where it redraws: on a terminal, not in a log or a pipe
    show = not args.quiet and sys.stderr.isatty()

    def progress(t, sent):
        if show:
            print(f"\rreplay t={t:8.2f} s  {sent} messages", end="", file=sys.stderr, flush=True)

    with StopSignals() as stop:
        sent = replay_bag(args.bag, options, on_progress=progress, should_stop=lambda: stop.requested)
    if show:
        print(file=sys.stderr)
    print(f"replayed {sent} messages" + (" (interrupted)" if stop.requested else ""))
    return stop.exit_code


def _cmd_tune(args: argparse.Namespace) -> int:
    overrides = {}
    for item in args.set or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise AttitudeSilError(f"--set takes KEY=VALUE, got {item!r}")
        try:
            overrides[key] = yaml12.load(value)
        except yaml.YAMLError:
            raise AttitudeSilError(f"--set {key}: {value!r} is not a YAML value") from None
    spec = apply_overrides(load_spec(args.spec), overrides)  # bad input is refused before ROS starts
    check_output(spec, args.resume)
    address = _scheduler(args)
    if address and spec.evaluation.get("mode", "batch") != "batch":
        raise AttitudeSilError(f"{spec.path}: --scheduler evaluates batch mode only (evaluation.mode is "
                               f"{spec.evaluation['mode']})")

    def on_first(signum: int) -> None:
        print(f"{signal.Signals(signum).name}: stopping after this generation (again to stop now)",
              file=sys.stderr, flush=True)

    _announce_domain()
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


def _scheduler(args: argparse.Namespace) -> str | None:
    """``--scheduler`` or ``$DASK_SCHEDULER_ADDRESS``, checked (one line if malformed), or None."""
    if args.scheduler is not None:
        return check_scheduler_address(args.scheduler)
    address = os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    if address is not None:
        try:
            check_scheduler_address(address)
        except AttitudeSilError as exc:
            raise AttitudeSilError(f"DASK_SCHEDULER_ADDRESS: {exc}") from None
    return address


def _cmd_montecarlo(args: argparse.Namespace) -> int:
    if args.workers is not None and args.workers < 1:
        raise AttitudeSilError(f"--workers must be >= 1, got {args.workers}")
    if args.runs is not None and args.runs < 1:
        raise AttitudeSilError(f"--runs must be >= 1, got {args.runs}")
    spec = load_mc_spec(args.spec, runs=args.runs)  # bad input is refused before anything runs
    check_campaign_output(spec, args.resume)
    address = _scheduler(args)
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

    with make_executor(address, workers, in_process=args.in_process) as executor, \
            StopSignals(on_first=on_first, second_stops_now=True) as stop:
        result = run_campaign(spec, executor, resume=args.resume, progress=progress,
                              should_stop=lambda: stop.requested)
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
                      before_start=(lambda: announced or (announced.append(1), _announce_domain())))
            bags.append(str(path))
    summary.update(output=str(out), plots=[str(f) for f in files], bags=bags)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(format_campaign(summary))
    if args.json:
        print(json.dumps(summary))
    return (stop.exit_code or 130) if result.interrupted else 0


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error: ``attitude-sil run: error: ... (attitude-sil run --help)``, exit 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``attitude-sil`` argument parser with every subcommand."""
    parser = _Parser(prog="attitude-sil", description="Spacecraft attitude-control SIL on ROS 2.")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scenario headless through the ROS 2 graph")
    run.add_argument("scenario", help="scenario parameter YAML (config/*.yaml)")
    laws = ", ".join(registry.names())
    run.add_argument("--controller", metavar="TYPE",
                     help=f"controller_type to start with: {laws} (plugins: docs/writing-a-law.md)")
    run.add_argument("--duration", type=float, help="episode length, s (default: plant.duration)")
    rec = run.add_mutually_exclusive_group()
    rec.add_argument("--record", metavar="DIR", help="bag directory (default bags/<scenario>_<time>)")
    rec.add_argument("--no-record", action="store_true", help="do not record a bag")
    run.add_argument("--json", action="store_true", help="print the metrics as one JSON object, last line")
    run.add_argument("--processes", action="store_true", help="one process per node (over DDS)")
    run.add_argument("--real-time", action="store_true", help="pace the plant at real time")
    run.add_argument("--quiet", action="store_true", help="no progress line")
    run.add_argument("--params", help="parameter file laid over the scenario (e.g. a tuner's best.yaml)")
    run.add_argument("--namespace", help="run the whole graph, its /clock included, under this namespace")
    run.add_argument("--swap", action="append", metavar="TIME:TYPE",
                     help=f"swap controller_type at a sim time (repeatable), e.g. --swap 2.0:fuzzy_pid; TYPE: {laws}")
    run.add_argument("--foxglove", nargs="?", const=DEFAULT_PORT, type=_port, metavar="PORT",
                     help=f"serve every topic live to Foxglove over WebSocket (default port {DEFAULT_PORT}); "
                     "paces the run at real time")
    run.add_argument("--foxglove-host", metavar="HOST",
                     help=f"address the Foxglove server listens on (default {DEFAULT_HOST}: this machine only)")
    run.add_argument("--foxglove-fast", action="store_true",
                     help="with --foxglove: do not pace the run at real time")
    run.set_defaults(func=_cmd_run)
    rec = sub.add_parser("record", help="record a running graph to a bag until Ctrl-C (like ros2 bag record)")
    rec.add_argument("bag", nargs="?", help="bag directory to create")
    rec.add_argument("--topics", nargs="+", metavar="T",
                     help="topics to record (default: every topic of the graph and /parameter_events)")
    rec.add_argument("--namespace", help="the graph's namespace")
    rec.add_argument("--episode", action="store_true", help="stop at the end of the next episode")
    rec.set_defaults(func=_cmd_record)
    epi = sub.add_parser("episode", help="start an episode on a running graph (plant/reset), wait for its end, "
                         "print its metrics")
    epi.add_argument("--namespace", help="the graph's namespace")
    epi.add_argument("--scenario", metavar="FILE",
                     help="scenario file whose metrics settings (scenario section) apply; nodes are asked for theirs")
    epi.add_argument("--json", action="store_true", help="print the metrics as one JSON object, last line")
    epi.add_argument("--timeout", type=float, default=20.0, help="seconds to wait for the graph (default 20)")
    epi.add_argument("--quiet", action="store_true", help="no progress line")
    epi.set_defaults(func=_cmd_episode)
    met = sub.add_parser("metrics", help="the metrics of the episode a bag holds (as run prints them)")
    met.add_argument("bag", help="bag directory or .mcap file")
    met.add_argument("--scenario", metavar="FILE",
                     help="scenario file for what the bag lacks (its metrics settings, or every parameter)")
    met.add_argument("--json", action="store_true", help="print the metrics as one JSON object, last line")
    met.set_defaults(func=_cmd_metrics)
    lin = sub.add_parser("linearize", help="nonlinear vs linearised model RMSE table (paper 000 Table 1)")
    lin.add_argument("scenario", help="rigid-body scenario YAML (e.g. config/hst_roll_step.yaml)")
    lin.add_argument("--angles", type=float, nargs="+", default=[3, 8, 15, 25, 35], help="commands, deg")
    lin.add_argument("--gains", type=float, nargs=4, metavar=("KP", "KI", "KD", "N"),
                     help="PID of the comparison (default: paper 000's 52.995 2.488 132.442 4.748)")
    lin.add_argument("--duration", type=float, help=f"episode length, s (default: {PAPER_000_TABLE_1_DURATION:g}, "
                     "the run length identified from paper 000's Table 1)")
    lin.add_argument("--json", action="store_true", help="also print the table as one JSON object")
    lin.set_defaults(func=_cmd_linearize)
    rob = sub.add_parser("robustness", help="a design on perturbed plants: inertia +-12.5 %% (paper 001) or the "
                         "flexible mismatch cases (paper 002)")
    rob.add_argument("scenario", help="scenario YAML")
    rob.add_argument("--params", help="controller parameters to evaluate (e.g. a tuner's best.yaml)")
    rob.add_argument("--json", action="store_true", help="also print the rows as JSON")
    rob.set_defaults(func=_cmd_robustness)
    fid = sub.add_parser("fidelity", help="every published number of papers 000-004 the model fixes, paper vs "
                         "project, with tolerance and PASS / FAIL / EXPLAINED (exit 1 on any FAIL)")
    fid.add_argument("--paper", action="append", choices=PAPERS, help="only this paper (repeatable; default: all)")
    fid.add_argument("--config", help="folder of the presets (default: the package's config/)")
    fid.add_argument("--json", action="store_true", help="also print the rows as one JSON list, last line")
    fid.set_defaults(func=_cmd_fidelity)
    param = sub.add_parser("param", help="list, get, set, dump or load parameters of a running node (like ros2 param)")
    param_sub = param.add_subparsers(dest="action", required=True)
    param_actions = {
        "list": "names of the node's parameters",
        "get": "a parameter's value ('Double value is: 1.0')",
        "set": "set a parameter (value parsed as YAML, typed as declared)",
        "dump": "every parameter as a ROS 2 parameter file (/node: ros__parameters:)",
        "load": "set parameters from a ROS 2 parameter file (e.g. a tuner's best.yaml); one line per parameter",
    }
    for action, text in param_actions.items():
        p = param_sub.add_parser(action, help=text, description=text)
        p.add_argument("node", help="node name, e.g. controller or /sat1/controller")
        if action in ("get", "set"):
            p.add_argument("name", help="parameter name, e.g. pid.kp")
        if action == "get":
            p.add_argument("--hide-type", action="store_true", help="print the value only")
        if action == "set":
            p.add_argument("value", help="new value, parsed as YAML (e.g. '[1.0, 2.0, 3.0]')")
        if action == "dump":
            p.add_argument("file", nargs="?", help="write the file here (default: print it)")
        if action == "load":
            p.add_argument("file", help="parameter YAML; every section that applies to the node counts")
        p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the node")
        p.set_defaults(func=_cmd_param)
    bag = sub.add_parser("bag", help="bag tools")
    bag_sub = bag.add_subparsers(dest="bag_command", required=True)
    info = bag_sub.add_parser("info", help="duration, start, end, counts and types per topic (like ros2 bag info)")
    info.add_argument("bag", help="bag directory or .mcap file")
    info.set_defaults(func=_cmd_bag)
    plot = sub.add_parser("plot", help="plot a bag, or the results folder of a tuning run")
    plot.add_argument("path", help="bag directory / .mcap file, or a tuning results folder")
    plot.add_argument("-o", "--output", required=True, help="PNG file to write")
    plot.set_defaults(func=_cmd_plot)
    rep = sub.add_parser("replay", help="republish a bag with its timing, or verify a controller against it")
    rep.add_argument("bag", help="bag directory or .mcap file")
    rep.add_argument("--rate", type=float, default=1.0, help="speed factor (0: as fast as possible)")
    rep.add_argument("--start", type=float, default=0.0, help="seconds into the bag to start from")
    rep.add_argument("--duration", type=float, help="seconds of the bag to play")
    rep.add_argument("--topics", nargs="+", help="topics to play (default: all but /parameter_events)")
    rep.add_argument("--loop", action="store_true", help="start again at the end")
    rep.add_argument("--namespace", help="publish under this namespace (not /clock)")
    rep.add_argument("--quiet", action="store_true", help="no progress line")
    rep.add_argument("--verify-controller", action="store_true",
                     help="feed the recorded plant topics to a fresh controller and compare its commands")
    rep.add_argument("--params", help="with --verify-controller: controller parameters from this YAML instead")
    rep.add_argument("--tolerance", type=float, default=1e-9, help="largest allowed command deviation")
    rep.set_defaults(func=_cmd_replay)
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
    tune.set_defaults(func=_cmd_tune)
    mc = sub.add_parser("montecarlo", help="a Monte Carlo campaign: one scenario and design over dispersed runs")
    mc.add_argument("spec", help="campaign spec YAML (config/mc_*.yaml)")
    mc.add_argument("--runs", type=int, help="number of runs (default: the spec's runs)")
    mc.add_argument("--resume", action="store_true", help="run only what the output folder does not hold yet")
    where = mc.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run the chunks on a Dask cluster, tcp://HOST:PORT or tls://HOST:PORT "
                       "(default: $DASK_SCHEDULER_ADDRESS, else local processes)")
    where.add_argument("--in-process", action="store_true", help="run every chunk in this process")
    mc.add_argument("--workers", type=int, help="local worker processes (default: one per core)")
    mc.add_argument("--no-bags", action="store_true", help="do not re-run the worst runs through the graph")
    mc.add_argument("--quiet", action="store_true", help="no progress bar")
    mc.add_argument("--json", action="store_true", help="print summary.json as one JSON object, last line")
    mc.set_defaults(func=_cmd_montecarlo)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``attitude-sil``; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"interrupted ({signal.Signals(signum).name}); everything recorded so far is kept", file=sys.stderr)
        return 128 + int(signum)
    except (AttitudeSilError, OSError) as exc:
        print(f"attitude-sil: error: {exc}", file=sys.stderr)
        return 2
