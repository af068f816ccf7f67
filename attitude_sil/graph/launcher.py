"""Start and stop the five graph nodes, and wait until they are wired.

``launch`` is not on PyPI, so this is the project's own launcher. Two ways:

* :func:`start_nodes`: every node in this process, in one rclpy context and
  executor (the ``EventsExecutor``: about 7x less overhead per message than
  the ``SingleThreadedExecutor`` here);
* :func:`start_processes`: one process per node (their console-script
  modules) given a ``--params-file``, talking over DDS.

:func:`wait_connected` waits by condition (matched publisher and subscription
counts), never by sleeping.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter

from attitude_sil.core.sim.paramfile import node_key
from attitude_sil.core.sim.params import spec_for
from attitude_sil.core.sim.scenario import Scenario, derived_values
from attitude_sil.errors import RunError
from attitude_sil.nodes.controller_node import ControllerNode
from attitude_sil.nodes.disturbance_node import DisturbanceNode
from attitude_sil.nodes.estimator_node import EstimatorNode
from attitude_sil.nodes.guidance_node import GuidanceNode
from attitude_sil.nodes.magnetorquers_node import MagnetorquersNode
from attitude_sil.nodes.plant_node import PlantNode
from attitude_sil.nodes.recorder_node import Recorder
from attitude_sil.nodes.sensors_node import SensorsNode
from attitude_sil.nodes.wheels_node import WheelsNode
from attitude_sil.ros.contract import (
    OUTSIDE_ONLY,
    PRODUCERS,
    ROLE_OUTPUTS,
    STEP_TOPICS,
    clock_remap,
    feedback_remap,
    graph_subscribers,
)
from attitude_sil.ros.parameters import typed_parameter

__all__ = ["NODE_CLASSES", "namespace_kwargs", "node_overrides", "start_nodes", "start_processes", "stop_processes",
           "wait_connected", "wait_external"]

#: the node class of each graph node name
NODE_CLASSES = {"plant": PlantNode, "wheels": WheelsNode, "disturbance": DisturbanceNode,
                "guidance": GuidanceNode, "controller": ControllerNode, "sensors": SensorsNode,
                "estimator": EstimatorNode, "magnetorquers": MagnetorquersNode}


def namespace_kwargs(namespace: str | None) -> dict:
    """Node keyword arguments that put a node, and its ``/clock``, under ``namespace``."""
    if not namespace:
        return {}
    return {"namespace": "/" + namespace, "cli_args": ["--ros-args", *clock_remap(namespace)]}


def node_overrides(scn: Scenario, node: str, extra: dict[str, Any]) -> dict[str, Any]:
    """What node ``node`` is given: the scenario's explicit values and those it derives from other nodes
    (:func:`~attitude_sil.core.sim.scenario.derived_values`), then ``extra`` where it declares them."""
    values = {**scn.explicit.get(node, {}), **derived_values(scn, node)}
    values.update({k: v for k, v in extra.items() if k in scn.values[node]})
    return values


def start_nodes(scn: Scenario, extra: dict[str, Any], context, executor, nodes: list[Node],
                node_kwargs: dict | None = None, skip=(), quiet: bool = False) -> PlantNode | None:
    """Create the graph's nodes in this process, add them to ``executor`` and ``nodes``; return the plant.

    The nodes named in ``skip`` are not created (``run --external``: a node of the user's plays each);
    ``quiet`` nodes log warnings and errors only (``run --quiet``).

    Raises
    ------
    RunError
        A node refused its parameters.
    """
    plant = None
    for name in (n for n in scn.nodes if n not in skip):
        values = node_overrides(scn, name, extra)
        # an empty list cannot be typed through an override; every empty value is a default here
        overrides = [typed_parameter(spec_for(name, k), v) for k, v in values.items() if v != []]
        overrides.append(Parameter("use_sim_time", Parameter.Type.BOOL, True))
        kwargs = dict(node_kwargs or {})
        if name == "controller" and feedback_remap(scn.feedback):  # it reads the estimate
            args = kwargs.get("cli_args") or ["--ros-args"]
            kwargs["cli_args"] = [*args, *feedback_remap(scn.feedback)]
        try:
            node = NODE_CLASSES[name](context=context, parameter_overrides=overrides, **kwargs)
        except ValueError as exc:
            raise RunError(str(exc)) from None
        if quiet:
            node.get_logger().set_level(LoggingSeverity.WARN)
        nodes.append(node)
        executor.add_node(node)
        if name == "plant":
            plant = node
    return plant


def start_processes(scn: Scenario, extra: dict[str, Any], tmp: Path,
                    namespace: str | None = None, skip=(), quiet: bool = False) -> list[subprocess.Popen]:
    """Start one process per node but those in ``skip``, each with a parameter file written to ``tmp``;
    ``quiet`` processes log warnings and errors only."""
    children = []
    for name in (n for n in scn.nodes if n not in skip):
        values = {k: v for k, v in node_overrides(scn, name, extra).items() if v != []}
        values["use_sim_time"] = True
        path = tmp / f"{name}.yaml"
        # /**/name: a plain "name:" key would not apply to the node under a namespace
        path.write_text(yaml.safe_dump({node_key(name): {"ros__parameters": values}}))
        cmd = [sys.executable, "-m", f"attitude_sil.nodes.{name}_node", "--ros-args", "--params-file", str(path)]
        if namespace:
            cmd += ["-r", f"__ns:=/{namespace}", *clock_remap(namespace)]
        if quiet:
            cmd += ["--log-level", "warn"]
        if name == "controller":
            cmd += feedback_remap(scn.feedback)
        children.append(subprocess.Popen(cmd, stdin=subprocess.DEVNULL))
    return children


def stop_processes(children: list[subprocess.Popen], timeout: float = 5.0) -> None:
    """SIGINT every node process, then kill what has not exited after ``timeout`` s.

    A stopped process (SIGSTOP, a debugger, Ctrl-Z) is continued after the
    SIGINT, so it takes it at once instead of being killed at the timeout.
    """
    for child in children:
        if child.poll() is None:
            child.send_signal(signal.SIGINT)
            child.send_signal(signal.SIGCONT)
    deadline = time.monotonic() + timeout
    for child in children:
        try:
            child.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def check_children(children: list[subprocess.Popen], when: str = "") -> None:
    """Raise RunError if a node process has exited."""
    for child in children:
        if child.poll() is not None:
            raise RunError(f"node process {child.args[2]} exited with code {child.returncode}{when}")


def wait_connected(recorder: Recorder, spin: Callable[[float], None], nodes: list[Node],
                   children: list[subprocess.Popen], timeout: float, external=(), feedback: str | None = None,
                   magnetic: bool = False) -> None:
    """Spin until every publisher has met every subscriber it should (matched, not merely seen).

    ``external``: the graph nodes not started here, whose topics and
    subscriptions are not waited for (:func:`wait_external` waits for them);
    ``feedback``: ``truth`` or ``estimate`` when the sensing loop runs, else None; ``magnetic`` where the
    magnetorquers fly.

    Raises
    ------
    RunError
        Discovery did not complete within ``timeout`` s, or a node process exited.
    """
    deadline = time.monotonic() + timeout

    def in_process_ready() -> bool:
        subs_per_topic: dict[str, int] = {}
        pubs_per_topic: dict[str, int] = {}
        for node in nodes + [recorder]:
            for s in node.subscriptions:
                subs_per_topic[s.topic_name] = subs_per_topic.get(s.topic_name, 0) + 1
            for p in node.publishers:
                pubs_per_topic[p.topic_name] = pubs_per_topic.get(p.topic_name, 0) + 1
        for node in nodes:
            for p in node.publishers:
                if p.get_subscription_count() < subs_per_topic.get(p.topic_name, 0):
                    return False
        for node in nodes + [recorder]:
            for s in node.subscriptions:
                if s.get_publisher_count() < pubs_per_topic.get(s.topic_name, 0):
                    return False
        return True

    def multi_process_ready() -> bool:
        for name, sub in recorder.subs.items():
            if name in STEP_TOPICS and name not in OUTSIDE_ONLY and PRODUCERS[name] not in external \
                    and sub.get_publisher_count() < 1:
                return False
        for name, n in graph_subscribers(external, feedback, magnetic).items():
            if recorder.count_subscribers(recorder.resolved[name]) < n + 1:
                return False
        return True

    ready = multi_process_ready if children else in_process_ready
    while not ready():
        check_children(children, " during start-up")
        if time.monotonic() > deadline:
            raise RunError(f"the graph did not connect within {timeout:g} s (DDS discovery)")
        spin(0.02)


def wait_external(recorder: Recorder, spin: Callable[[float], None], nodes: list[Node],
                  children: list[subprocess.Popen], external, timeout: float) -> None:
    """Spin until a node outside the package publishes, matched, what each role in ``external`` owes the graph.

    What a role owes is :data:`~attitude_sil.ros.contract.ROLE_OUTPUTS` (the
    controller: ``voltage_cmd`` or ``torque_cmd``); the recorder's volatile
    subscription on the topic matching it is the sign. In this process the
    graph's own publishers must also have matched every subscriber discovered
    on their topics (the outside node's among them), so its first step is not
    written before it can be read.

    Raises
    ------
    RunError
        Nothing publishes a role's outputs within ``timeout`` s (the message
        names the topics and how to start such a node), a publisher's QoS
        cannot match, or a node process exited.
    """
    deadline = time.monotonic() + timeout

    def missing() -> list[str]:
        return [f"{role} ({' or '.join(alt)})" for role in external for alt in ROLE_OUTPUTS[role]
                if not any(recorder.subs[t].get_publisher_count() > 0 for t in alt)]

    def own_publishers_matched() -> bool:
        return all(p.get_subscription_count() >= recorder.count_subscribers(p.topic_name)
                   for node in nodes for p in node.publishers if p.topic_name in recorder.resolved.values())

    while (gaps := missing()) or not own_publishers_matched():
        if recorder.qos_problems:
            raise RunError(recorder.qos_problems[0])
        check_children(children, " while waiting for the external node(s)")
        if time.monotonic() > deadline:
            what = ", ".join(gaps) or "the graph's publishers to match the external node's subscriptions"
            raise RunError(f"no external node within {timeout:g} s: waiting for {what}; start yours on this "
                           "ROS domain (docs/flight-software.md)")
        spin(0.05)
