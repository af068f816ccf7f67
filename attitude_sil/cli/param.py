"""``attitude-sil param``: list, get, set, dump or load parameters of a running node (like ros2 param).

The verb's own imports are inside :func:`execute`, so ``attitude-sil --help``
builds every parser without loading numba, rclpy or the tuner.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    param = sub.add_parser("param", help="list, get, set, dump or load parameters of a running node (like ros2 param)")
    param_sub = param.add_subparsers(dest="action", required=True)
    param_actions = {
        "list": "names of the node's parameters",
        "get": "a parameter's value ('Double value is: 1.0')",
        "set": "set a parameter (value parsed as YAML, typed as declared)",
        "dump": "every parameter as a ROS 2 parameter file (/node: ros__parameters:)",
        "load": "set parameters from a ROS 2 parameter file (e.g. a tuner's best.yaml); one line per parameter",
    }
    for action, text in param_actions.items():
        p = param_sub.add_parser(action, help=text, description=text)
        p.add_argument("node", help="node name, e.g. controller or /sat1/controller")
        if action in ("get", "set"):
            p.add_argument("name", help="parameter name, e.g. pid.kp")
        if action == "get":
            p.add_argument("--hide-type", action="store_true", help="print the value only")
        if action == "set":
            p.add_argument("value", help="new value, parsed as YAML (e.g. '[1.0, 2.0, 3.0]')")
        if action == "dump":
            p.add_argument("file", nargs="?", help="write the file here (default: print it)")
        if action == "load":
            p.add_argument("file", help="parameter YAML; every section that applies to the node counts")
        p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the node")
        p.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    from attitude_sil.tools.paramclient import param_command, param_dump, param_load

    if args.action == "dump":
        text = param_dump(args.node, timeout=args.timeout)
        if args.file:
            Path(args.file).write_text(text)
            print(f"wrote {args.file}")
        else:
            print(text, end="")
        return 0
    if args.action == "load":
        report = param_load(args.node, args.file, timeout=args.timeout)
        for line, ok in report.lines:
            print(line, file=sys.stdout if ok else sys.stderr)
        if report.unchanged:
            print(f"{len(report.unchanged)} parameter(s) already at the file's value, not sent")
        return 2 if report.failed else 0
    print(param_command(args.action, args.node, getattr(args, "name", None), getattr(args, "value", None),
                        timeout=args.timeout, hide_type=getattr(args, "hide_type", False)))
    return 0
