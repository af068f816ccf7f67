"""``attitude-sil plot``: plot a bag, or the results folder of a tuning run.

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from attitude_sil.errors import AttitudeSilError


def check_png(out: str) -> None:
    """``-o`` must name a PNG file that can be created (refused before any bag is read)."""
    path = Path(out)
    if path.suffix.lower() != ".png" or path.is_dir():
        raise AttitudeSilError(f"-o {out}: give a .png file to write")
    parent = next((p for p in path.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise AttitudeSilError(f"-o {out}: {parent} is a file, not a directory")

def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    plot = sub.add_parser("plot", help="plot a bag, or the results folder of a tuning run")
    plot.add_argument("path", help="bag directory / .mcap file, or a tuning results folder")
    plot.add_argument("-o", "--output", required=True, help="PNG file to write")
    plot.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    from attitude_sil.tools.plot import plot_bag
    from attitude_sil.tuning.plot import plot_results

    check_png(args.output)
    path = Path(args.path)
    if (path / "summary.json").is_file() or (path / "evaluations.jsonl").is_file():
        out = plot_results(path, args.output)
    else:
        out = plot_bag(path, args.output)
    print(f"wrote {out}")
    return 0
