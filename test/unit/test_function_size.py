"""No funnels: no function of the package (nor of the code it generates) takes more than 12 parameters or
runs over 80 lines.

A long list of loose arguments is how a concept ends up spelled in several
places that must agree (the batch loop once took 91); a record or a split
along a real seam keeps it in one. Lines count from ``def`` to the last line,
docstring included; parameters count every positional, keyword-only,
``*args`` and ``**kwargs`` parameter but ``self``/``cls``.
"""

from __future__ import annotations

import ast
from pathlib import Path

from attitude_sil.core.control import compiled, registry

PACKAGE = Path(__file__).resolve().parents[2] / "attitude_sil"
MAX_PARAMETERS = 12
MAX_LINES = 80


def oversized(source: str, where: str) -> list[str]:
    """``where:line name (n parameters, m lines)`` for every function of ``source`` over a limit."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
            if a.args and a.args[0].arg in ("self", "cls"):
                n -= 1
            lines = node.end_lineno - node.lineno + 1
            if n > MAX_PARAMETERS or lines > MAX_LINES:
                out.append(f"{where}:{node.lineno} {node.name} ({n} parameters, {lines} lines)")
    return out


def test_no_function_of_the_package_is_a_funnel():
    found = [x for path in sorted(PACKAGE.rglob("*.py"))
             for x in oversized(path.read_text(), str(path.relative_to(PACKAGE.parent)))]
    assert not found, "over 12 parameters or 80 lines:\n" + "\n".join(found)


def test_no_generated_function_is_a_funnel():
    laws = [registry.get(name) for name in registry.names()]
    assert not oversized(compiled.dispatch_source(laws), "generated dispatch")


def test_the_check_sees_a_funnel():
    wide = "def f(" + ", ".join(f"a{i}" for i in range(13)) + "):\n    pass\n"
    long = "def g():\n" + "    x = 1\n" * 80
    method = "class C:\n    def m(self, " + ", ".join(f"a{i}" for i in range(12)) + "):\n        pass\n"
    assert [x.split()[1] for x in oversized(wide + long + method, "t")] == ["f", "g"]
