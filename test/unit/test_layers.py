"""The package's layers: imports flow one way, the ROS-free layers stay ROS-free, no import cycles.

Read from the source with ``ast`` (nothing is imported), so the test fails the
moment someone adds an upward arrow, a cycle, or an import hidden inside a
function to dodge one. The layout is described in docs/architecture.md.
"""

import ast
from pathlib import Path

from conftest import ROOT

PACKAGE = ROOT / "attitude_sil"

#: layer -> the layers it may import from (itself included)
ALLOWED = {
    "errors": {"errors"},
    "core": {"errors", "core"},
    "storage": {"errors", "storage"},
    "tuning": {"errors", "core", "tuning"},
    "ros": {"errors", "core", "storage", "ros"},
    "nodes": {"errors", "core", "storage", "ros", "nodes"},
    "graph": {"errors", "core", "storage", "tuning", "ros", "nodes", "graph"},
    "tools": {"errors", "core", "storage", "ros", "nodes", "graph", "tools"},
    "cli": {"errors", "core", "storage", "tuning", "ros", "nodes", "graph", "tools", "cli"},
}
ROS_FREE = ("errors", "core", "storage", "tuning")

#: inside core: sub-package -> the sub-packages it may import from ("root": core/*.py, the base)
CORE_ALLOWED = {
    "root": {"root"},
    "plant": {"root", "plant"},
    "control": {"root", "plant", "control"},
    "analysis": {"root", "plant", "analysis"},
    "sensing": {"root", "plant", "sensing"},
    "environment": {"root", "plant", "environment"},
    "sim": {"root", "plant", "control", "analysis", "sensing", "environment", "sim"},
}
ROS_PACKAGES = ("rclpy", "rcl_interfaces", "builtin_interfaces", "geometry_msgs", "sensor_msgs", "std_msgs",
                "std_srvs", "rosgraph_msgs", "diagnostic_msgs", "rosidl_runtime_py", "nav_msgs")


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _imports(name: str, path: Path) -> list[tuple[str, bool]]:
    """(imported module, at function level?) for every import of a module."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            nested = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                found.extend((a.name, in_function) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")[: len(package.split(".")) - child.level + 1]
                    mod = ".".join(base + ([child.module] if child.module else []))
                else:
                    mod = child.module
                found.append((mod, in_function))
                # "from pkg import module" imports a module too
                found.extend((f"{mod}.{a.name}", in_function) for a in child.names)
            visit(child, nested)

    visit(tree, False)
    return found


def _layer(module: str) -> str:
    return module.split(".")[1] if module.count(".") else "package"


MODULES = _modules()
IMPORTS = {name: _imports(name, path) for name, path in MODULES.items()}


def test_every_module_is_in_a_layer():
    assert {_layer(m) for m in MODULES} <= set(ALLOWED) | {"package"}
    assert len([m for m in MODULES if _layer(m) == "package"]) == 1  # only attitude_sil/__init__.py


def test_imports_flow_one_way():
    wrong = []
    for name, imports in IMPORTS.items():
        src = _layer(name)
        for mod, _ in imports:
            if mod in MODULES and mod != "attitude_sil" and _layer(mod) not in ALLOWED.get(src, set(ALLOWED)):
                wrong.append(f"{name} -> {mod}")
    assert not wrong, "imports against the layering:\n" + "\n".join(wrong)


def _core_part(module: str) -> str:
    parts = module.split(".")
    return parts[2] if len(parts) > 3 else "root"


def test_core_sub_packages_import_one_way():
    # plant < control, analysis < sim; the root modules (paramspec, yaml12, trajectory, papers) under all
    wrong = []
    for name, imports in IMPORTS.items():
        if _layer(name) != "core":
            continue
        src = _core_part(name)
        assert src in CORE_ALLOWED, f"{name}: core has no sub-package {src!r} (add it to CORE_ALLOWED)"
        for mod, _ in imports:
            if mod in MODULES and _layer(mod) == "core" and mod != "attitude_sil.core":
                if _core_part(mod) not in CORE_ALLOWED[src]:
                    wrong.append(f"{name} -> {mod}")
    assert not wrong, "imports against core's order (plant < control, analysis < sim):\n" + "\n".join(wrong)


def test_ros_free_layers_import_no_ros():
    wrong = [f"{name} -> {mod}" for name, imports in IMPORTS.items() if _layer(name) in ROS_FREE
             for mod, _ in imports if mod.split(".")[0] in ROS_PACKAGES]
    assert not wrong, "\n".join(wrong)


def _verb_bodies(path: Path) -> set[int]:
    """Line numbers inside a command-line verb's ``execute``: the one place imports wait for use."""
    tree = ast.parse(path.read_text())
    return {line for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == "execute"
            for line in range(node.lineno, node.end_lineno + 1)}


def test_no_project_import_inside_a_function():
    # the exception: a verb of the command line imports in its execute(), so --help loads nothing heavy
    # (the layering test above still sees those imports)
    wrong = []
    for name, imports in IMPORTS.items():
        lazy = _verb_bodies(MODULES[name]) if _layer(name) == "cli" else set()
        lines = _import_lines(MODULES[name])
        for (mod, in_function), line in zip(imports, lines, strict=True):
            if in_function and line not in lazy and (mod.startswith("attitude_sil")
                                                     or mod.split(".")[0] in ROS_PACKAGES):
                wrong.append(f"{name} -> {mod}")
    assert not wrong, "function-level imports (they hide cycles and layer breaks):\n" + "\n".join(wrong)


def _import_lines(path: Path) -> list[int]:
    """The line of each entry :func:`_imports` returns, in the same order."""
    out = []

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                out.extend(child.lineno for _ in child.names)
            elif isinstance(child, ast.ImportFrom):
                out.extend(child.lineno for _ in range(1 + len(child.names)))
            visit(child)

    visit(ast.parse(path.read_text()))
    return out


def test_no_import_cycles():
    graph = {name: {mod for mod, _ in imports if mod in MODULES and mod != name} for name, imports in IMPORTS.items()}
    # a package's __init__ re-exporting its own modules is not a cycle of behaviour
    for name in graph:
        if MODULES[name].name == "__init__.py":
            graph[name] = {m for m in graph[name] if not m.startswith(name + ".")}
    state: dict[str, int] = {}
    stack: list[str] = []

    def dfs(node):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(nxt):] + [nxt]))
            if nxt not in state:
                dfs(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            dfs(node)


def test_the_checker_sees_a_planted_violation(tmp_path):
    # the rules above are only worth something if the parser finds imports where they hide
    src = tmp_path / "x.py"
    src.write_text("import os\n\ndef f():\n    from attitude_sil.graph import session\n")
    assert ("attitude_sil.graph", True) in _imports("attitude_sil.core.x", src)
    assert ("os", False) in _imports("attitude_sil.core.x", src)
