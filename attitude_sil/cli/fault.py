"""``attitude-sil fault``: inject a fault into a running graph (docs/faults.md).

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    p = sub.add_parser("fault", help="inject a fault into a running graph (TARGET MODE [VALUE], e.g. wheel1 stuck)",
                       description="Add a fault to the running graph's fault list, from its next step; it is "
                                   "said on /diagnostics. Targets and modes: docs/faults.md.")
    p.add_argument("target", help="wheel<n>, gyro.x|y|z, star_tracker, magnetometer, magnetorquers or controller")
    p.add_argument("mode", help="what goes wrong, e.g. lost or stuck for a wheel")
    p.add_argument("value", nargs="?", help="its size, where the mode has one (e.g. friction 3)")
    p.add_argument("--namespace", default=None, help="the graph's namespace (run --namespace)")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the node and the fault")
    p.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    from attitude_sil.tools.faultclient import fault_command

    print(fault_command(args.target, args.mode, args.value, args.namespace, args.timeout))
    return 0
