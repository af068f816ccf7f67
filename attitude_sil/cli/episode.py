"""``attitude-sil episode``: start an episode on a running graph (plant/reset), wait for its end, print its metrics.

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
import math
import sys

from attitude_sil.errors import AttitudeSilError


def check_timeout(timeout: float) -> None:
    if not (math.isfinite(timeout) and timeout > 0):
        raise AttitudeSilError(f"--timeout must be a finite number of seconds > 0, got {timeout}")

def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    epi = sub.add_parser("episode", help="start an episode on a running graph (plant/reset), wait for its end, "
                         "print its metrics")
    epi.add_argument("--namespace", help="the graph's namespace")
    epi.add_argument("--scenario", metavar="FILE",
                     help="scenario file whose metrics settings (scenario section) apply; nodes are asked for theirs")
    epi.add_argument("--json", action="store_true", help="print the metrics as one JSON object, last line")
    epi.add_argument("--timeout", type=float, default=20.0, help="seconds to wait for the graph (default 20)")
    epi.add_argument("--quiet", action="store_true", help="no progress line")
    epi.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json

    from attitude_sil.cli.format import format_table
    from attitude_sil.tools.live import play_episode

    check_timeout(args.timeout)
    metrics = play_episode(args.namespace, args.scenario, timeout=args.timeout, progress=not args.quiet,
                           say=lambda line: print(line, file=sys.stderr, flush=True))
    print(format_table(metrics))
    if args.json:
        print(json.dumps(metrics))
    return 0
