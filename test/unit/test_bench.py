"""The benchmarks run against today's engine, and the laws' vector loops are SIMD code.

``make bench`` is not part of ``make test``; a benchmark that calls an engine entry point since removed
fails only when someone runs it (the controller bank's old ``lanes_stage`` did so for a stop). The laws'
table is the benchmark's part that reaches into the generated module, so it runs here on a small block.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from attitude_sil.core.control.registry import names as law_names
from attitude_sil.core.sim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench_engine():
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        yield importlib.import_module("bench_engine")
    finally:
        sys.path.remove(str(ROOT / "bench"))


def test_the_laws_table_runs_and_the_branch_free_laws_vector_loops_are_packed(bench_engine, capsys):
    scn = load_scenario(ROOT / "config" / "hst_roll_step.yaml")
    table = bench_engine.law_lanes(scn, n_episodes=4, steps=2)
    assert set(table) == set(law_names())
    assert all(row > 0 and vec > 0 for row, vec, _ in table.values())
    # the PID, the geometric law and the plugin law have no branch LLVM cannot select: their vector loops
    # are 43-47 % packed (ymm/zmm) instructions on AVX2 and AVX-512 machines; a loop that went scalar
    # (an aliasing check given up, a reference count in the step) reads 0 %
    for kind in ("pid", "geometric", "quat_pd"):
        assert table[kind][2] > 0.25, f"{kind}'s vector loop is {table[kind][2]:.0%} packed"
    assert "packed share" in capsys.readouterr().out
