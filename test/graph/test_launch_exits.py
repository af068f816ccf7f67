"""The launch file's nodes stop as ``ros2 launch`` expects: exit 0 on a requested shutdown, non-zero on a fault.

``ros2 launch`` sends SIGINT to every process on Ctrl-C (SIGTERM after a
timeout) and reports each that exits with another code than 0 as
``[ERROR] process has died``. The five nodes are started here as launch_ros
starts the launch file's ``Node`` actions (``launch`` is not on PyPI): the
executable with ``--ros-args -r __node:=NAME``, the ``params_file`` argument,
the node's parameter dict as ``-p`` and its remappings as ``-r``, read from the
launch description itself (:func:`conftest.launch_actions`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
import rclpy.executors
from rclpy.signals import SignalHandlerOptions

from attitude_sil.core.sim.scenario import GRAPH_NODES, SENSOR_NODES
from conftest import CONFIG, launch_actions

BIN = Path(sys.executable).parent


def _command(node, params_file: Path) -> list[str]:
    """The command line launch_ros gives a ``Node`` action (namespace and controller_type left at their defaults)."""
    cmd = [str(BIN / node.kwargs["executable"]), "--ros-args", "-r", f"__node:={node.kwargs['name']}"]
    for entry in node.kwargs["parameters"]:
        if isinstance(entry, dict):
            cmd += [x for k, v in entry.items() if not hasattr(v, "args") for x in ("-p", f"{k}:={str(v).lower()}")]
        else:
            cmd += ["--params-file", str(params_file)]
    for old, _ in node.kwargs["remappings"]:
        cmd += ["-r", f"{old}:={old}"]  # namespace '': /clock stays /clock
    return cmd


def _wait_for_nodes(names: set[str], procs, timeout: float = 60.0) -> None:
    """Spin a probe node until every name is on the ROS graph (by condition), or fail naming the missing."""
    context = rclpy.Context()
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    probe = rclpy.create_node("launch_probe", context=context)
    try:
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(probe)
        deadline = time.monotonic() + timeout
        while not names <= {n for n, _ in probe.get_node_names_and_namespaces()}:
            assert all(p.poll() is None for p in procs), "a node exited during start-up"
            assert time.monotonic() < deadline, f"not on the graph: {names - set(probe.get_node_names())}"
            executor.spin_once(timeout_sec=0.05)
    finally:
        probe.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_every_node_of_the_launch_file_exits_0_on_a_requested_shutdown(monkeypatch, sig):
    # every node (the sensing ones too: feedback:=estimate), the controller once (controller_type not given)
    nodes = [a for a in launch_actions(monkeypatch) if type(a).__name__ == "Node"
             and not (a.kwargs["name"] == "controller" and type(a.kwargs["condition"]).__name__ == "IfCondition")]
    assert {n.kwargs["name"] for n in nodes} >= set(GRAPH_NODES + SENSOR_NODES), nodes  # none missed below
    procs: list[subprocess.Popen] = []
    try:  # started inside: a node that cannot start (its script not installed) leaves none of the others running
        for n in nodes:
            procs.append(subprocess.Popen(_command(n, CONFIG / "hst_roll_step.yaml"), stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                          start_new_session=True))
        _wait_for_nodes({n.kwargs["name"] for n in nodes}, procs)
        for p in procs:
            p.send_signal(sig)
        codes = [p.wait(timeout=30) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    errors = {n.kwargs["name"]: p.stderr.read() for n, p in zip(nodes, procs, strict=True)}
    assert codes == [0] * len(nodes), errors
    assert not any("Traceback" in e for e in errors.values()), errors


def test_a_node_with_bad_parameters_exits_non_zero(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**/wheels:\n  ros__parameters:\n    motor.resistance: -1.0\n")
    proc = subprocess.run([str(BIN / "wheels_node"), "--ros-args", "--params-file", str(bad)],
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "motor.resistance" in proc.stderr, proc.stderr
