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
    fid.add_argument("--json", action="store_true",
                     help="print one JSON object instead of the table: the rows (with their evidence kind), the "
                     "counts by evidence and status, and the identified constants with the rows they were "
                     "fitted on")
    fid.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json
    import sys

    from attitude_sil.tuning.fidelity import check, format_report, report_dict

    results = check(tuple(args.paper) if args.paper else PAPERS, args.config,
                    progress=lambda paper, i, n: print(f"fidelity: paper {paper} ({i} of {n})", file=sys.stderr,
                                                       flush=True))
    if args.json:  # one JSON object and nothing else on stdout, so it pipes
        print(json.dumps(report_dict(results)))
    else:
        print(format_report(results))
    return 0 if all(r.status != "FAIL" for r in results) else 1
