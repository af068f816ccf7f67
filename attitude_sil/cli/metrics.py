"""``attitude-sil metrics``: the metrics of the episode a bag holds (as run prints them).

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
import sys


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    met = sub.add_parser("metrics", help="the metrics of the episode a bag holds (as run prints them)")
    met.add_argument("bag", help="bag directory or .mcap file")
    met.add_argument("--scenario", metavar="FILE",
                     help="scenario file for what the bag lacks (its metrics settings, or every parameter)")
    met.add_argument("--json", action="store_true", help="print the metrics as one JSON object, last line")
    met.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json

    from attitude_sil.cli.format import format_table
    from attitude_sil.tools.live import bag_metrics, scenario_settings

    scenario_settings(args.scenario)  # a bad file is refused before the bag is read
    metrics, notes = bag_metrics(args.bag, args.scenario)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    print(format_table(metrics))
    if args.json:
        print(json.dumps(metrics))
    return 0
