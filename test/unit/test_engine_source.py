"""The compiled engine that runs is the package's own source: the loop, the laws' loops, and a table of names."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np

from attitude_sil.cli.main import main
from attitude_sil.core.control import compiled, dispatch, registry
from attitude_sil.core.sim import batch, batch_loop
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario

PACKAGE = Path(__file__).resolve().parents[2] / "attitude_sil"
CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_the_loop_that_runs_is_the_file_of_the_package():
    tr = simulate(load_scenario(CONFIG / "hst_roll_step.yaml"), n_episodes=3, duration=0.05, driver="compiled")
    assert np.isfinite(tr.q_BN).all()
    # the batch engine ran batch_loop.chunk itself, compiled for the registered laws, from the file
    block, _ = batch.loop_of(registry.dispatch_module())
    assert block.py_func is batch_loop.chunk and block.signatures, "the compiled driver did not run batch_loop.chunk"
    assert Path(inspect.getsourcefile(block.py_func)).resolve() == PACKAGE / "core/sim/batch_loop.py"


def test_the_generated_table_holds_names_not_behaviour():
    source = compiled.dispatch_source([registry.get(n) for n in registry.names()])
    tree = ast.parse(source)
    defs = [node for node in tree.body if isinstance(node, ast.FunctionDef)]
    assert len(defs) == 3 * len(registry.names())  # vector_, rows_, enter_ per law
    for node in defs:
        # one statement: a call of a loop of core/control/dispatch.py with the law's step bound
        assert len(node.body) == 1 and isinstance(node.body[0], ast.Expr), node.name
        callee = node.body[0].value.func.id
        assert callee in dispatch.__all__, (node.name, callee)
    assert not [n for n in tree.body if isinstance(n, (ast.For, ast.While, ast.If, ast.ClassDef))]


def test_engine_source_prints_the_table(capsys):
    assert main(["engine", "--source"]) == 0
    out = capsys.readouterr().out
    assert out == compiled.dispatch_source([registry.get(n) for n in registry.names()])
    assert main(["engine"]) == 0
    out = capsys.readouterr().out
    assert str(PACKAGE / "core/sim/batch_loop.py") in out and "attitude_sil_laws_" in out


def test_no_stub_that_raises_in_the_package():
    found = [f"{path.relative_to(PACKAGE.parent)}:{node.lineno}"
             for path in sorted(PACKAGE.rglob("*.py"))
             for node in ast.walk(ast.parse(path.read_text()))
             if isinstance(node, ast.Raise) and "NotImplementedError" in ast.unparse(node)]
    assert not found, f"stubs that raise: {found}"


def test_a_swap_to_a_law_without_enter_is_bumpless():
    """The generic entry (core/control/dispatch.py): the state zeroed, the first command equal to the last."""
    from attitude_sil.core.sim.build import law_bank

    q = np.array([[0.0, 0.0, np.sin(0.05), np.cos(0.05)]])
    args = (q, np.zeros((1, 3)), np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)))
    for old, new in (("pid", "ga_flc"), ("fuzzy_pid", "ga_flc")):
        bank = law_bank(old, 1)
        u_last = bank.compute(*args, 0)
        bank.request(new)
        u = bank.compute(*args, 1)
        assert bank.has_offset[0] and abs(u_last[0, 2]) > 1.0
        assert np.allclose(u, u_last, rtol=0.0, atol=1e-9), (old, new, u, u_last)
