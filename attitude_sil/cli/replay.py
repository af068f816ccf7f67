"""``attitude-sil replay``: republish a bag with its timing, or verify a controller against it.

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
import sys


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
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
    rep.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    from attitude_sil.ros.signals import StopSignals
    from attitude_sil.tools.replay import ReplayOptions, replay_bag
    from attitude_sil.tools.verify import verify_controller

    if args.verify_controller:
        result = verify_controller(args.bag, params_file=args.params, tolerance=args.tolerance,
                                   say=lambda line: print(line, file=sys.stderr, flush=True))
        verdict = "PASS" if result.passed else "FAIL"
        print(f"{verdict}: {result.steps} steps, largest command deviation {result.max_deviation:.3g} "
              f"at t={result.worst_time_s:.3f} s (axis {result.worst_axis}), tolerance {result.tolerance:g}, "
              f"{result.swaps} recorded parameter change(s) applied"
              + (f"; {result.dipole_steps} dipoles, largest deviation {result.dipole_deviation:.3g} A m^2"
                 if result.dipole_steps else ""))
        return 0 if result.passed else 1

    options = ReplayOptions(rate=args.rate, start=args.start, duration=args.duration, topics=args.topics,
                            loop=args.loop, namespace=args.namespace)

    # a \r progress line only where it redraws: on a terminal, not in a log or a pipe
    show = not args.quiet and sys.stderr.isatty()

    def progress(t, sent):
        if show:
            print(f"\rreplay t={t:8.2f} s  {sent} messages", end="", file=sys.stderr, flush=True)

    with StopSignals() as stop:
        sent = replay_bag(args.bag, options, on_progress=progress, should_stop=lambda: stop.requested,
                          say=lambda line: print(line, file=sys.stderr, flush=True))
    if show:
        print(file=sys.stderr)
    print(f"replayed {sent} messages" + (" (interrupted)" if stop.requested else ""))
    return stop.exit_code
