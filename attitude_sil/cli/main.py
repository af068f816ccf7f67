"""The ``attitude-sil`` command: one module per verb, assembled here.

Each verb (:mod:`attitude_sil.cli.run`, ``tune``, ``replay``, ...) adds its
own parser and runs in its ``execute``, which is where its imports are: the
parser is built without numba, rclpy or the tuner, so ``attitude-sil --help``
answers at once (bench/bench_cli_help.sh). The verbs and their flags are a
contract (docs/architecture.md, "Command line").
"""

from __future__ import annotations

import argparse
import functools
import signal
import sys

from attitude_sil.cli import (
    bag,
    engine,
    episode,
    fault,
    fidelity,
    linearize,
    metrics,
    montecarlo,
    param,
    plot,
    record,
    replay,
    robustness,
    run,
    tune,
)
from attitude_sil.errors import AttitudeSilError

__all__ = ["build_parser", "main", "VERBS"]

#: the verbs in the order ``--help`` lists them
VERBS = (run, record, episode, metrics, linearize, robustness, fidelity, param, fault, bag, plot, replay, tune,
         montecarlo, engine)

#: the tuner's dependencies (the ``tune`` extra): a node-only install lacks them
_TUNE_EXTRA = ("pymoo", "control", "matplotlib")


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error: ``attitude-sil run: error: ... (attitude-sil run --help)``, exit 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``attitude-sil`` argument parser with every subcommand."""
    parser = _Parser(prog="attitude-sil", description="Spacecraft attitude-control SIL on ROS 2.")
    sub = parser.add_subparsers(dest="command", required=True)
    for verb in VERBS:
        verb.add(sub)
    return parser


@functools.cache
def _parser() -> argparse.ArgumentParser:
    # built once per process: parsing leaves a parser as it was, and building it (every verb and its help) is
    # most of an in-process call that stops at bad input (test/cli/test_user_errors.py makes many)
    return build_parser()


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``attitude-sil``; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(argv)
    args.argv = argv  # the command line as typed, for a command that tells how to resume it
    try:
        return args.func(args)
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"interrupted ({signal.Signals(signum).name}); everything recorded so far is kept", file=sys.stderr)
        return 128 + int(signum)
    except ModuleNotFoundError as exc:
        missing = (exc.name or "").split(".")[0]
        if missing not in _TUNE_EXTRA:
            raise
        print(f"attitude-sil: error: {missing} is not installed; the attitude-sil command needs the tuner's "
              "dependencies: pip install 'attitude_sil[tune]' (the node executables run without them)",
              file=sys.stderr)
        return 2
    except (AttitudeSilError, OSError) as exc:
        print(f"attitude-sil: error: {exc}", file=sys.stderr)
        return 2
