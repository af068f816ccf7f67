"""``attitude-sil linearize``: nonlinear vs linearised model RMSE table (paper 000 Table 1).

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse

from attitude_sil.core.papers import PAPER_000_TABLE_1_DURATION


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    lin = sub.add_parser("linearize", help="nonlinear vs linearised model RMSE table (paper 000 Table 1)")
    lin.add_argument("scenario", help="rigid-body scenario YAML (e.g. config/hst_roll_step.yaml)")
    lin.add_argument("--angles", type=float, nargs="+", default=[3, 8, 15, 25, 35], help="commands, deg")
    lin.add_argument("--gains", type=float, nargs=4, metavar=("KP", "KI", "KD", "N"),
                     help="PID of the comparison (default: paper 000's 52.995 2.488 132.442 4.748)")
    lin.add_argument("--duration", type=float, help=f"episode length, s (default: {PAPER_000_TABLE_1_DURATION:g}, "
                     "the run length identified from paper 000's Table 1)")
    lin.add_argument("--json", action="store_true", help="also print the table as one JSON object")
    lin.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import json

    from attitude_sil.core.papers import PAPER_000_COMPARISON_GAINS
    from attitude_sil.core.sim.scenario import load_scenario
    from attitude_sil.errors import AttitudeSilError
    from attitude_sil.tuning.linearize import format_table as format_rmse_table
    from attitude_sil.tuning.linearize import rmse_table

    scn = load_scenario(args.scenario)
    if scn.param("plant", "model") not in ("rigid_body", "linearized"):
        raise AttitudeSilError(f"{args.scenario}: linearize needs a rigid-body scenario (plant.model), "
                         f"got {scn.param('plant', 'model')}")
    gains = tuple(args.gains) if args.gains else PAPER_000_COMPARISON_GAINS
    duration = PAPER_000_TABLE_1_DURATION if args.duration is None else args.duration
    table = rmse_table(scn, args.angles, gains, duration=duration)
    print(format_rmse_table(args.angles, table))
    if args.json:
        print(json.dumps({"angles_deg": list(args.angles), "rmse_deg": table.tolist(), "gains": list(gains)}))
    return 0
