"""``attitude-sil bag``: bag tools: info.

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    bag = sub.add_parser("bag", help="bag tools")
    bag_sub = bag.add_subparsers(dest="bag_command", required=True)
    info = bag_sub.add_parser("info", help="duration, start, end, counts and types per topic (like ros2 bag info)")
    info.add_argument("bag", help="bag directory or .mcap file")
    info.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    from attitude_sil.storage.info import format_info
    from attitude_sil.storage.reader import open_bag

    print(format_info(open_bag(args.bag)))
    return 0
