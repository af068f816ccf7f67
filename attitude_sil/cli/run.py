"""``attitude-sil run``: run a scenario headless through the ROS 2 graph.

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
import math

from attitude_sil.core.control import registry
from attitude_sil.core.sim.lockstep import COMMAND_TIMINGS
from attitude_sil.errors import AttitudeSilError
from attitude_sil.ros.contract import ROLE_OUTPUTS
from attitude_sil.storage.foxglove import DEFAULT_HOST, DEFAULT_PORT, check_port


def port_number(text: str) -> int:
    """``--foxglove PORT``: an integer in 1..65535."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} out of range 1..65535")
    return port

def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    run = sub.add_parser("run", help="run a scenario headless through the ROS 2 graph")
    run.add_argument("scenario", help="scenario parameter YAML (config/*.yaml)")
    laws = ", ".join(registry.declared_names())
    run.add_argument("--controller", metavar="TYPE",
                     help=f"controller_type to start with: {laws} (plugins: docs/writing-a-law.md)")
    run.add_argument("--duration", type=float, help="episode length, s (default: plant.duration)")
    rec = run.add_mutually_exclusive_group()
    rec.add_argument("--record", metavar="DIR", help="bag directory (default bags/<scenario>_<time>)")
    rec.add_argument("--no-record", action="store_true", help="do not record a bag")
    run.add_argument("--json", action="store_true", help="print the metrics as one JSON object, last line")
    run.add_argument("--feedback", choices=("truth", "estimate"),
                     help="what the controller reads: the plant's truth, or the estimator's output fed by the "
                          "sensors node (default: the scenario's scenario.feedback, truth); docs/sensors.md")
    run.add_argument("--processes", action="store_true", help="one process per node (over DDS)")
    run.add_argument("--real-time", action="store_true", help="pace the plant at real time")
    run.add_argument("--quiet", action="store_true", help="no progress line, and the nodes log warnings and errors "
                     "only")
    run.add_argument("--params", help="parameter file laid over the scenario (e.g. a tuner's best.yaml)")
    run.add_argument("--namespace", help="run the whole graph, its /clock included, under this namespace")
    run.add_argument("--swap", action="append", metavar="TIME:TYPE",
                     help=f"swap controller_type at a sim time (repeatable), e.g. --swap 2.0:fuzzy_pid; TYPE: {laws}")
    run.add_argument("--external", action="append", metavar="NODE", choices=tuple(ROLE_OUTPUTS),
                     help=f"do not start this graph node ({', '.join(ROLE_OUTPUTS)}; repeatable): wait for a node of "
                     "yours that speaks its part of the topic contract, e.g. --external controller "
                     "(docs/flight-software.md)")
    run.add_argument("--external-timeout", type=float, default=60.0, metavar="S",
                     help="wall seconds to wait for the external node(s) (default 60)")
    run.add_argument("--external-timing", choices=COMMAND_TIMINGS,
                     help="how your controller runs: stamped (answers each step's inputs with their stamp; the "
                     "default), sim_timer (a timer on sim time: its commands take effect one period later, "
                     "deterministic) or wall (a timer on the wall clock, with --real-time: the newest command is "
                     "held); docs/flight-software.md")
    run.add_argument("--external-rate", type=float, metavar="HZ",
                     help="your controller's timer rate (default: the control rate); with sim_timer its period is a "
                     "whole number of control periods")
    run.add_argument("--foxglove", nargs="?", const=DEFAULT_PORT, type=port_number, metavar="PORT",
                     help=f"serve every topic live to Foxglove over WebSocket (default port {DEFAULT_PORT}); "
                     "paces the run at real time")
    run.add_argument("--foxglove-host", metavar="HOST",
                     help=f"address the Foxglove server listens on (default {DEFAULT_HOST}: this machine only)")
    run.add_argument("--foxglove-fast", action="store_true",
                     help="with --foxglove: do not pace the run at real time")
    run.add_argument("--wait-for-viewer", nargs="?", const=math.inf, type=float, metavar="S",
                     help="with --foxglove: hold step 0 until a client has subscribed, or S seconds have passed "
                     "(no S: no limit)")
    run.set_defaults(func=execute)


def _live_options(args: argparse.Namespace) -> tuple[str, float | None]:
    """The live view's flags checked (before any graph starts): (host, ``--wait-for-viewer`` s or None).

    Raises
    ------
    AttitudeSilError
        A live-view flag without ``--foxglove``, a limit that is not a
        number of seconds > 0, a port in use.
    """
    if args.foxglove is None and (args.foxglove_fast or args.foxglove_host is not None
                                  or args.wait_for_viewer is not None):
        raise AttitudeSilError("--foxglove-fast, --foxglove-host and --wait-for-viewer go with --foxglove [PORT]")
    wait = args.wait_for_viewer
    if wait is not None and wait != math.inf and not (math.isfinite(wait) and wait > 0):
        raise AttitudeSilError(f"--wait-for-viewer must be a finite number of seconds > 0 (or no value: no limit), "
                               f"got {wait}")
    host = DEFAULT_HOST if args.foxglove_host is None else args.foxglove_host
    if args.foxglove is not None:
        check_port(args.foxglove, host)
    return host, wait


def _command_timing(scn, args: argparse.Namespace):
    """``--external-timing`` and ``--external-rate`` laid over the scenario's ``wheels.command_timing`` and
    ``wheels.command_rate`` (the graph session checks them against ``--external``)."""
    if args.external_rate is not None:
        if not (math.isfinite(args.external_rate) and args.external_rate > 0):
            raise AttitudeSilError(f"--external-rate must be a finite rate in Hz > 0, got {args.external_rate}")
        if (args.external_timing or scn.param("wheels", "command_timing")) == "stamped":
            raise AttitudeSilError("--external-rate goes with --external-timing sim_timer or wall (a stamped "
                                   "controller answers every step)")
        scn = scn.with_values("wheels", command_rate=args.external_rate)
    if args.external_timing is not None:
        scn = scn.with_values("wheels", command_timing=args.external_timing)
    return scn


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json
    import sys
    from datetime import datetime
    from pathlib import Path

    from attitude_sil.cli.common import announce_domain, load_with_params
    from attitude_sil.cli.format import format_segments, format_table
    from attitude_sil.graph.session import run_graph
    from attitude_sil.storage.foxglove import FoxgloveLive
    from attitude_sil.tools.paramclient import GraphParameters

    scn = load_with_params(args.scenario, args.params)
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
    if args.feedback is not None:
        scn = scn.with_values("scenario", feedback=args.feedback)
    scn = _command_timing(scn, args)
    if not (math.isfinite(args.external_timeout) and args.external_timeout > 0):
        raise AttitudeSilError(f"--external-timeout must be a finite number of seconds > 0, got "
                               f"{args.external_timeout}")
    host, wait = _live_options(args)
    record = None
    if not args.no_record:
        record = Path(args.record) if args.record else Path("bags") / (
            f"{scn.name}_{datetime.now().strftime('%Y%m%d_%H%M%S')}")
    live = None

    def start() -> None:
        nonlocal live
        announce_domain()
        if args.foxglove is not None:
            live = FoxgloveLive(args.foxglove, host)
            # the Parameters panel: the package's nodes of the graph, through their parameter services
            own = [n for n in scn.nodes if n not in (args.external or ())]
            live.parameters = GraphParameters(args.namespace, own)
            pace = "as fast as it runs" if args.foxglove_fast else "at real time"
            print(f"Foxglove: open connection {live.url} (layout config/foxglove/attitude.json); the run is "
                  f"paced {pace}", file=sys.stderr, flush=True)

    try:
        result = run_graph(scn, duration=args.duration, controller=args.controller, record_dir=record,
                           processes=args.processes, real_time=args.real_time or (
                               args.foxglove is not None and not args.foxglove_fast),
                           progress=not args.quiet, namespace=args.namespace, before_start=start,
                           live=lambda: live, external=args.external or (), external_timeout=args.external_timeout,
                           quiet=args.quiet, wait_for_viewer=wait)
    finally:
        if live is not None:
            live.close()
    print(format_table(result.metrics))
    if result.metrics.get("segments"):
        print(format_segments(result.metrics["segments"]))
    if args.json:
        print(json.dumps(result.metrics))
    return 0
