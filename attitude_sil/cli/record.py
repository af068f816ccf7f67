"""``attitude-sil record``: record a running graph to a bag until Ctrl-C (like ros2 bag record).

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
import sys


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    rec = sub.add_parser("record", help="record a running graph to a bag until Ctrl-C (like ros2 bag record)")
    rec.add_argument("bag", nargs="?", help="bag directory to create")
    rec.add_argument("--topics", nargs="+", metavar="T",
                     help="topics to record (default: every topic of the graph and /parameter_events)")
    rec.add_argument("--namespace", help="the graph's namespace")
    rec.add_argument("--episode", action="store_true", help="stop at the end of the next episode")
    rec.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    from attitude_sil.errors import AttitudeSilError
    from attitude_sil.tools.live import check_topics, record_graph

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
