"""Test session set-up: a ROS domain of its own and discovery kept on this machine.

Set before anything imports rclpy, so no test hears another session's graph: the
domain is claimed with the lock files every attitude-sil run uses
(:func:`attitude_sil.ros.environment.isolated_domain`).
"""

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config"
sys.path.insert(0, str(ROOT))

from attitude_sil.ros.environment import discovery_profile, isolated_domain  # noqa: E402 - ROS-free, no rclpy

# a domain no other attitude-sil process holds (runs started without ROS_DOMAIN_ID take free ones too)
os.environ.pop("ROS_DOMAIN_ID", None)
isolated_domain()
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
for var in ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
    os.environ.pop(var, None)
discovery_profile()  # the package's profile, as every attitude-sil process uses it
os.environ.pop("ROS_STATIC_PEERS", None)


@pytest.fixture
def cli(capfd, monkeypatch):
    """``cli(*args)``: ``attitude_sil.cli.main(args)`` in this process, as a CompletedProcess.

    The code of a real ``attitude-sil`` process without its 2 s of interpreter
    and import start-up; the working directory is the repository, as for the
    tests' subprocesses (``cwd=ROOT``).
    """
    import subprocess

    from attitude_sil.cli import main

    monkeypatch.chdir(ROOT)

    def call(*args) -> subprocess.CompletedProcess:
        capfd.readouterr()
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse's own errors
            code = exc.code
        out, err = capfd.readouterr()
        return subprocess.CompletedProcess(list(args), code, out, err)

    return call


LAUNCH_FILE = ROOT / "launch" / "sim.launch.py"


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def launch_actions(monkeypatch) -> list:
    """The actions of ``launch/sim.launch.py``'s description, built with stand-ins of ``launch`` and
    ``launch_ros`` (not on PyPI) that record their arguments: ``type(a).__name__``, ``a.args``, ``a.kwargs``."""
    import runpy
    import types

    names = {"launch": ["LaunchDescription"], "launch.actions": ["DeclareLaunchArgument"],
             "launch.conditions": ["IfCondition", "UnlessCondition"],
             "launch.substitutions": ["LaunchConfiguration", "PathJoinSubstitution", "PythonExpression"],
             "launch_ros": [], "launch_ros.actions": ["Node"], "launch_ros.substitutions": ["FindPackageShare"]}
    for module, classes in names.items():
        mod = types.ModuleType(module)
        for cls in classes:
            setattr(mod, cls, type(cls, (_Recorded,), {}))
        monkeypatch.setitem(sys.modules, module, mod)
    return runpy.run_path(str(LAUNCH_FILE))["generate_launch_description"]().args[0]


#: the example law plugin, the base of the broken ones (test_plugin_checks, test_plugin_faults)
EXAMPLE = (ROOT / "examples" / "custom_law" / "quat_pd.py").read_text()

#: law name -> (the example's line, its broken replacement): one break each
BREAKS = {
    "bad_default": ('double_array("kp", [50.0] * 3,', 'double_array("kp", [-1.0] * 3,'),
    "dict_record": ('    return Params(lanes(values["kp"], n), lanes(values["kd"], n), float(values["output_limit"]))',
                    '    return {"kp": lanes(values["kp"], n)}'),
    "bad_shape": ('double_array("kd", [50.0] * 3, "rate gain per body axis, V s/rad", lengths=(3,),',
                  'double_array("kd", [50.0] * 2, "rate gain per body axis, V s/rad",'),
    "no_compile": ("        raw = par.kp[p, i] * e[i]", "        raw = par.gain[p, i] * e[i]"),
}


def write_plugin(folder: Path, name: str) -> None:
    """The example law as module ``name`` with the break of that name, in ``folder``."""
    old, new = BREAKS.get(name, ("", ""))
    source = EXAMPLE.replace('name="quat_pd"', f'name="{name}"')
    assert old in source, (name, old)
    (folder / f"{name}.py").write_text(source.replace(old, new))


def start_python(args: list[str], **kw):
    """A Python process of the tests' (``args`` after the interpreter), in a session of its own, its stderr piped."""
    import subprocess

    return subprocess.Popen([sys.executable, *args], cwd=ROOT, stdin=subprocess.DEVNULL, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **kw)


def stop_processes(procs: list) -> list[int]:
    """SIGINT each process (a requested shutdown), then SIGKILL what is left after 10 s; the exit codes."""
    import signal
    import subprocess

    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    codes = []
    for p in procs:
        try:
            codes.append(p.wait(timeout=10))
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            codes.append(p.wait())
    return codes
