"""``attitude-sil fidelity``: every published number of papers 000-004 the model fixes, paper vs project.

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse

from attitude_sil.core.papers import PAPERS


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    fid = sub.add_parser("fidelity", help="every published number of papers 000-004 the model fixes, paper vs "
                         "project, with tolerance and PASS / FAIL / EXPLAINED (exit 1 on any FAIL)")
    fid.add_argument("--paper", action="append", choices=PAPERS, help="only this paper (repeatable; default: all)")
    fid.add_argument("--config", help="folder of the presets (default: the package's config/)")
    fid.add_argument("--json", action="store_true", help="also print the rows as one JSON list, last line")
    fid.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json

    from attitude_sil.tuning.fidelity import check, format_report

    results = check(tuple(args.paper) if args.paper else PAPERS, args.config)
    print(format_report(results))
    if args.json:
        print(json.dumps([r.as_dict() for r in results]))
    return 0 if all(r.status != "FAIL" for r in results) else 1
