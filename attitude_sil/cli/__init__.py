"""The command-line layer: ``attitude-sil`` (:mod:`attitude_sil.cli.main`) and what it prints.

The command imports the tuner's dependencies (pymoo, python-control,
matplotlib: the ``tune`` extra). Where they are not installed (a node-only
install) ``attitude-sil`` says so in one line and exits 2; the node
executables run without them.
"""

import sys

try:
    from attitude_sil.cli.main import build_parser, main
except ModuleNotFoundError as _exc:
    if (_exc.name or "").split(".")[0] not in ("pymoo", "control", "matplotlib"):
        raise
    _MISSING = _exc.name.split(".")[0]

    def build_parser():  # noqa: D103 - stands in for the real one
        raise ModuleNotFoundError(_MISSING)

    def main(argv: list[str] | None = None) -> int:
        """Say which dependency is missing; exit code 2."""
        print(f"attitude-sil: error: {_MISSING} is not installed; the attitude-sil command needs the tuner's "
              "dependencies: pip install 'attitude_sil[tune]' (the node executables run without them)",
              file=sys.stderr)
        return 2

__all__ = ["build_parser", "main"]
