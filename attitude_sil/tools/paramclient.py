"""``attitude-sil param``: list, get and set parameters of a running node.

The project's stand-in for ``ros2 param`` (ros2cli is not on PyPI), built on
rclpy's ``AsyncParameterClient``. Values given on the command line are parsed
as YAML and converted to the parameter's declared type (so ``[1, 2, 3]``
sets a double array). A refusal prints the node's reason and exits non-zero.
"""

from __future__ import annotations

import math
import time
from typing import Any

import rclpy
import yaml
from rcl_interfaces.msg import ParameterType as T
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from attitude_sil.core import yaml12
from attitude_sil.errors import ParamClientError
from attitude_sil.ros.contract import check_node_name, check_parameter_name
from attitude_sil.ros.environment import localhost_environment

__all__ = ["ParamClientError", "param_command"]


def _coerce(value: Any, ptype) -> Any:
    """YAML value -> the declared parameter type (ints become floats for doubles)."""
    def num(v, kind):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ParamClientError(f"expected a number, got {v!r}")
        return float(v) if kind == "double" else v

    if ptype == T.PARAMETER_DOUBLE:
        return num(value, "double")
    if ptype == T.PARAMETER_DOUBLE_ARRAY:
        if not isinstance(value, list):
            raise ParamClientError(f"expected a list of numbers, got {value!r}")
        return [num(v, "double") for v in value]
    if ptype == T.PARAMETER_INTEGER_ARRAY:
        if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise ParamClientError(f"expected a list of integers, got {value!r}")
        return value
    if ptype == T.PARAMETER_STRING and not isinstance(value, str):
        return str(value)
    return value


def _format(value: Any) -> str:
    if isinstance(value, (list, tuple)) or type(value).__name__ == "array":
        return "[" + ", ".join(str(v) for v in list(value)) + "]"
    return str(value)


def param_command(action: str, node_name: str, name: str | None = None, value: str | None = None,
                  timeout: float = 10.0) -> str:
    """Run one ``param`` action against ``node_name``; return the text to print.

    Raises
    ------
    ParamClientError
        Node not found, unknown parameter, bad value or refusal.
    """
    if not (isinstance(timeout, (int, float)) and math.isfinite(timeout) and timeout > 0):
        raise ParamClientError(f"--timeout must be a finite number of seconds > 0, got {timeout}")
    check_node_name(node_name)
    if name is not None:
        check_parameter_name(name)
    localhost_environment()
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node(f"attitude_sil_param_{int(time.time() * 1000) % 100000}", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def wait(future):
        deadline = time.monotonic() + timeout
        while not future.done():
            if time.monotonic() > deadline:
                raise ParamClientError(f"node {node_name} did not answer within {timeout:g} s")
            executor.spin_once(timeout_sec=0.05)
        return future.result()

    try:
        client = AsyncParameterClient(node, node_name)
        deadline = time.monotonic() + timeout
        while not client.services_are_ready():
            if time.monotonic() > deadline:
                raise ParamClientError(
                    f"node {node_name} not found within {timeout:g} s (is the graph running, on this ROS_DOMAIN_ID?)")
            executor.spin_once(timeout_sec=0.05)
        if action == "list":
            names = sorted(wait(client.list_parameters()).result.names)
            return "\n".join(names)
        assert name is not None
        desc = wait(client.describe_parameters([name])).descriptors
        if not desc or desc[0].type == 0:
            raise ParamClientError(f"node {node_name} has no parameter {name!r}")
        if action == "get":
            values = wait(client.get_parameters([name])).values
            return _format(parameter_value_to_python(values[0]))
        if action == "set":
            try:
                parsed = yaml12.load(value) if value is not None else None
            except yaml.YAMLError:
                raise ParamClientError(f"value {value!r} is not valid YAML") from None
            try:
                typed = _coerce(parsed, desc[0].type)
            except ParamClientError as exc:
                raise ParamClientError(f"{node_name}.{name}: {exc}") from None
            result = wait(client.set_parameters([Parameter(name, value=typed)])).results[0]
            if not result.successful:
                raise ParamClientError(f"set refused: {result.reason}")
            return f"set {node_name}.{name} = {_format(typed)}"
        raise ParamClientError(f"unknown action {action!r}")
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
