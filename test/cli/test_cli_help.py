"""``--help`` works for the command and every subcommand (a ``%`` in a help string once crashed it)."""

import argparse
import subprocess
import sys

import pytest

from attitude_sil.cli import build_parser
from conftest import ROOT


def _subcommands(parser: argparse.ArgumentParser, prefix=()) -> list[tuple[str, ...]]:
    """Every subcommand path, nested ones included (``bag info``)."""
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.append(prefix + (name,))
                out += _subcommands(sub, prefix + (name,))
    return out


SUBCOMMANDS = _subcommands(build_parser())


def test_every_contract_subcommand_exists():
    names = {" ".join(s) for s in SUBCOMMANDS}
    assert {"run", "tune", "replay", "bag", "bag info", "plot", "param"} <= names


@pytest.mark.parametrize("path", SUBCOMMANDS, ids=[" ".join(s) for s in SUBCOMMANDS])
def test_subcommand_help(path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args([*path, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: attitude-sil " + " ".join(path))
    assert "options:" in out


def test_top_level_help_in_a_fresh_process():
    proc = subprocess.run([sys.executable, "-m", "attitude_sil.cli", "--help"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    for name in ("run", "tune", "replay", "bag", "plot", "param", "linearize", "robustness", "fidelity"):
        assert name in proc.stdout
