"""The command-line layer: ``attitude-sil`` (:mod:`attitude_sil.cli.main`) and what it prints."""

from attitude_sil.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
