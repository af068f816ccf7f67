"""The command-line layer: ``attitude-sil`` (:mod:`attitude_sil.cli.main`), one module per verb.

The verbs import what they need when they run, so ``attitude-sil --help``
loads none of numba, rclpy or the tuner. A verb that needs the tuner's
dependencies (pymoo, python-control, matplotlib: the ``tune`` extra) on a
node-only install says so in one line and exits 2; the node executables run
without them.
"""

from attitude_sil.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
