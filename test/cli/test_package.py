"""The package installs as a ROS 2 package: its dependencies are declared, its launch file starts the graph.

Read from the source (``ast``, ``package.xml``, ``setup.py`` run with
``setuptools.setup`` captured), so nothing needs ``colcon``, ``launch`` or
``rosdep``: every import of the package is declared in package.xml and in
setup.py's requirements; the node executables import without the tuner's
dependencies; ``launch/sim.launch.py`` (run against stand-ins of ``launch``
and ``launch_ros``) starts every graph node the runner starts, on sim time.
"""

import ast
import os
import re
import runpy
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest
import setuptools

from attitude_sil.core.sim.scenario import GRAPH_NODES, MAGNETIC_NODES, SENSOR_NODES
from attitude_sil.ros.contract import FEEDBACK_REMAP
from conftest import LAUNCH_FILE, ROOT, launch_actions

#: import name -> (package.xml key, or None where only a comment can say it is pip-only;
#: pip requirement, or None for a ROS package, which a ROS 2 install or the Makefile's wheels provide)
DEPENDENCIES = {
    "numpy": ("python3-numpy", "numpy"),
    "scipy": ("python3-scipy", "scipy"),
    "yaml": ("python3-yaml", "pyyaml"),
    "numba": ("python3-numba", "numba"),
    "mcap": (None, "mcap"),  # comes with mcap-ros2-support
    "mcap_ros2": ("mcap-ros2-support", "mcap-ros2-support"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "control": ("python-control-pip", "control"),
    "pymoo": (None, "pymoo"),
    "foxglove": (None, "foxglove-sdk"),
    "websockets": (None, "websockets"),
    "ppigrf": (None, "ppigrf"),
    "dask": (None, "dask"),
    "distributed": (None, "distributed"),
    "pytest": ("python3-pytest", "pytest"),
    "rosbags": ("python3-rosbags-pip", "rosbags"),
    "setuptools": ("python3-setuptools", None),  # builds the package (test_package.py runs setup.py)
    **{name: (name, None) for name in (
        "rclpy", "rcl_interfaces", "builtin_interfaces", "std_msgs", "geometry_msgs", "sensor_msgs", "nav_msgs",
        "std_srvs",
        "rosgraph_msgs", "diagnostic_msgs", "visualization_msgs", "ament_index_python", "launch", "launch_ros")},
}
TUNER_ONLY = ("pymoo", "control", "matplotlib")


def _third_party(paths) -> dict[str, str]:
    """Top-level names of every import (function-level ones included) outside the stdlib and the package."""
    found = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in ("attitude_sil", "conftest"):
                    found.setdefault(top, str(path.relative_to(ROOT)))
    return found


def _package_xml() -> tuple[dict[str, set[str]], list[str]]:
    tree = ET.parse(ROOT / "package.xml")
    tags: dict[str, set[str]] = {}
    for element in tree.getroot():
        if isinstance(element.tag, str) and element.text:
            tags.setdefault(element.tag, set()).add(element.text.strip())
    return tags, re.findall(r"<!--(.*?)-->", (ROOT / "package.xml").read_text(), re.S)


@pytest.fixture(scope="module")
def setup_kwargs():
    captured = {}
    real = setuptools.setup
    setuptools.setup = lambda **kw: captured.update(kw)
    cwd = os.getcwd()
    try:
        os.chdir(ROOT)  # setup.py globs its data files
        runpy.run_path(str(ROOT / "setup.py"))
    finally:
        setuptools.setup = real
        os.chdir(cwd)
    return captured


def _requirement_names(reqs) -> set[str]:
    return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower().replace("_", "-") for r in reqs}


def undeclared(imports: dict[str, str], depend_tags: tuple[str, ...], requirements: set[str]) -> list[str]:
    """What is wrong with the declarations of ``imports``: one line per problem."""
    tags, comments = _package_xml()
    declared = set().union(*(tags.get(t, set()) for t in depend_tags))
    problems = []
    for name, where in sorted(imports.items()):
        if name not in DEPENDENCIES:
            problems.append(f"{where} imports {name}: declare it in package.xml and setup.py, and map it here")
            continue
        key, pip = DEPENDENCIES[name]
        if key is not None and key not in declared:
            problems.append(f"{where} imports {name}: package.xml lacks <{depend_tags[0]}>{key}<")
        if key is None and not any(re.search(rf"\b{re.escape(pip)}\b", c) and "pip" in c for c in comments):
            problems.append(f"{where} imports {name}: package.xml lacks a comment saying {pip} is pip-only")
        if pip is not None and pip not in requirements:
            problems.append(f"{where} imports {name}: setup.py does not require {pip}")
    return problems


def test_every_folder_of_the_package_is_installed():
    # a folder of modules without __init__.py is left out of a non-editable install (pip install ., colcon)
    from setuptools import find_packages

    found = set(find_packages(str(ROOT), exclude=["test", "test.*", "bench", "examples", "examples.*"]))
    folders = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "attitude_sil").rglob("*.py")
               if "__pycache__" not in p.parts}
    assert folders <= found, f"not installed: {sorted(folders - found)}"


def test_every_import_of_the_package_is_declared(setup_kwargs):
    imports = _third_party(sorted((ROOT / "attitude_sil").rglob("*.py")))
    assert {"rclpy", "numpy", "yaml", "numba", "pymoo"} <= set(imports)  # the scan sees them
    requirements = _requirement_names(setup_kwargs["install_requires"]) | _requirement_names(
        setup_kwargs["extras_require"]["tune"])
    assert undeclared(imports, ("exec_depend", "depend"), requirements) == []


def test_every_import_of_the_tests_and_the_launch_file_is_declared(setup_kwargs):
    imports = _third_party(sorted((ROOT / "test").rglob("*.py")))
    test_requirements = _requirement_names(setup_kwargs["install_requires"]) | _requirement_names(
        setup_kwargs["extras_require"]["test"])
    assert undeclared(imports, ("test_depend", "exec_depend", "depend", "buildtool_depend"),
                      test_requirements) == []
    assert undeclared(_third_party([LAUNCH_FILE]), ("exec_depend",), set()) == []


def test_an_undeclared_import_is_caught(setup_kwargs):
    requirements = _requirement_names(setup_kwargs["install_requires"])
    assert undeclared({"requests": "x.py"}, ("exec_depend",), requirements)
    # a known one that setup.py stops requiring is caught too
    assert undeclared({"numba": "x.py"}, ("exec_depend",), requirements - {"numba"})
    assert undeclared({"pymoo": "x.py"}, ("exec_depend",), requirements) == [
        "x.py imports pymoo: setup.py does not require pymoo"]


def test_the_tuner_dependencies_are_an_extra_the_default_test_install_includes(setup_kwargs):
    base = _requirement_names(setup_kwargs["install_requires"])
    assert not base & set(TUNER_ONLY)
    assert set(TUNER_ONLY) <= _requirement_names(setup_kwargs["extras_require"]["tune"])
    assert set(TUNER_ONLY) <= _requirement_names(setup_kwargs["extras_require"]["test"])  # make test: all


def test_node_executables_import_without_the_tuner_dependencies():
    block = f"import sys\nfor m in {TUNER_ONLY!r}: sys.modules[m] = None\n"
    nodes = "".join(f"import attitude_sil.nodes.{n}_node\n" for n in GRAPH_NODES + SENSOR_NODES)
    proc = subprocess.run([sys.executable, "-c", block + nodes], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr
    # the verbs import what they need when they run: run works without the tuner, tune says what is missing
    run = subprocess.run([sys.executable, "-c", block + "from attitude_sil.cli import main\n"
                          "raise SystemExit(main(['run', 'config/hst_roll_step.yaml', '--duration', '0.05', "
                          "'--no-record', '--quiet']))"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert run.returncode == 0, run.stderr
    cli = subprocess.run([sys.executable, "-c", block + "from attitude_sil.cli import main\n"
                          "raise SystemExit(main(['tune', 'config/tune_hst_pid_ga.yaml']))"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert cli.returncode == 2 and "Traceback" not in cli.stderr, cli.stderr
    assert cli.stderr.count("\n") == 1 and "pip install 'attitude_sil[tune]'" in cli.stderr


def test_launch_file_starts_the_runner_graph_on_sim_time(setup_kwargs, monkeypatch):
    tree = ast.parse(LAUNCH_FILE.read_text())
    assert "generate_launch_description" in {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    actions = launch_actions(monkeypatch)
    arguments = {a.args[0]: a.kwargs["default_value"] for a in actions if type(a).__name__ == "DeclareLaunchArgument"}
    assert set(arguments) == {"namespace", "params_file", "controller_type", "feedback", "sensors", "magnetorquers"}
    assert (arguments["feedback"], arguments["sensors"], arguments["magnetorquers"]) == ("truth", "false", "false")
    nodes = [a for a in actions if type(a).__name__ == "Node"]
    scripts = {s.split("=")[0].strip() for s in setup_kwargs["entry_points"]["console_scripts"]}
    assert {n.kwargs["executable"] for n in nodes} == {f"{n}_node" for n in GRAPH_NODES + SENSOR_NODES
                                                       + MAGNETIC_NODES}
    assert {n.kwargs["executable"] for n in nodes} <= scripts
    for node in nodes:
        assert node.kwargs["package"] == "attitude_sil" and node.kwargs["name"] + "_node" == node.kwargs["executable"]
        assert {"use_sim_time": True} in node.kwargs["parameters"]
        assert node.kwargs["parameters"][0].args == ("params_file",)  # the params_file argument
        assert node.kwargs["namespace"].args == ("namespace",)
        remapped = [r[0] for r in node.kwargs["remappings"]]
        assert remapped == (["/clock", *FEEDBACK_REMAP] if node.kwargs["name"] == "controller" else ["/clock"])
    # the sensing nodes start on a condition (feedback:=estimate or sensors:=true), the magnetorquers on
    # magnetorquers:=true, which the plant and the controller are told; the others always
    assert {n.kwargs["name"] for n in nodes if "condition" in n.kwargs} == {"controller", *SENSOR_NODES,
                                                                          *MAGNETIC_NODES}
    told = [n.kwargs["name"] for n in nodes for p in n.kwargs["parameters"][1:] if "magnetorquers" in p]
    assert sorted(told) == ["controller", "controller", "plant"]
    feedback = [r[1] for n in nodes if n.kwargs["name"] == "controller" for r in n.kwargs["remappings"][1:]]
    assert all(type(f).__name__ == "PythonExpression" for f in feedback)
    assert any("estimate/attitude" in str(f.args) for f in feedback)
    # controller_type: when given, one controller with it; else one on the file's
    controllers = [n for n in nodes if n.kwargs["name"] == "controller"]
    assert sorted(type(c.kwargs["condition"]).__name__ for c in controllers) == ["IfCondition", "UnlessCondition"]
    given = next(c for c in controllers if type(c.kwargs["condition"]).__name__ == "IfCondition")
    assert given.kwargs["parameters"][-1]["controller_type"].args == ("controller_type",)
    # every default file it names exists and is installed
    parts = arguments["params_file"].args[0]
    assert parts[0].args == ("attitude_sil",) and (ROOT.joinpath(*parts[1:])).is_file()
    installed = {dest: files for dest, files in setup_kwargs["data_files"]}
    assert "/".join(parts[1:]) in installed["share/attitude_sil/" + parts[1]]
    assert "launch/sim.launch.py" in installed["share/attitude_sil/launch"]
