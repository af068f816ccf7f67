"""``attitude-sil robustness``: a design on perturbed plants (paper 001 inertia, paper 002 mismatch cases).

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    rob = sub.add_parser("robustness", help="a design on perturbed plants: inertia +-12.5 %% (paper 001) or the "
                         "flexible mismatch cases (paper 002)")
    rob.add_argument("scenario", help="scenario YAML")
    rob.add_argument("--params", help="controller parameters to evaluate (e.g. a tuner's best.yaml)")
    rob.add_argument("--json", action="store_true", help="also print the rows as JSON")
    rob.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json

    from attitude_sil.cli.common import load_with_params
    from attitude_sil.tuning.robustness import format_robustness, robustness

    rows = robustness(load_with_params(args.scenario, args.params))
    print(format_robustness(rows))
    if args.json:
        print(json.dumps(rows))
    return 0
