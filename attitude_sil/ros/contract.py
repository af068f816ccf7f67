"""The topic contract as data: names, message types, who publishes and who listens.

Names and types are contracts (docs/architecture.md, "ROS contract"): bags,
replays and other tools depend on them. Nodes, the recorder, the graph tools
and the tests take topic names from here instead of writing literals. All
topics are relative names (a namespace moves a whole graph), except
``/clock`` and ``/parameter_events``.
"""

from __future__ import annotations

import importlib

from attitude_sil.errors import AttitudeSilError

__all__ = ["STEP_TOPICS", "COMMAND_TOPICS", "COMMAND_TOPIC", "CONTROLLER_INPUTS", "MODEL_TOPICS", "RECORDED_TOPICS",
           "GRAPH_SUBSCRIBERS", "PARAMETER_EVENTS", "message_class"]

#: topics of the lockstep (relative names, except /clock); one message per step each,
#: except the command topics, of which exactly one carries each step
STEP_TOPICS: dict[str, str] = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "attitude": "geometry_msgs/msg/QuaternionStamped",
    "body_rate": "geometry_msgs/msg/Vector3Stamped",
    "attitude_setpoint": "geometry_msgs/msg/QuaternionStamped",
    "rate_setpoint": "geometry_msgs/msg/Vector3Stamped",
    "voltage_cmd": "geometry_msgs/msg/Vector3Stamped",
    "torque_cmd": "geometry_msgs/msg/Vector3Stamped",
    "wheel_torque": "geometry_msgs/msg/Vector3Stamped",
    "wheel_momentum": "geometry_msgs/msg/Vector3Stamped",
    "wheel_state": "sensor_msgs/msg/JointState",
    "disturbance_torque": "geometry_msgs/msg/Vector3Stamped",
    "attitude_error": "geometry_msgs/msg/Vector3Stamped",
}

#: the controller publishes one of these per step, depending on its law
COMMAND_TOPICS = ("voltage_cmd", "torque_cmd")

#: the command topic of each kind of law (:data:`attitude_sil.core.controllers.OUTPUT_KIND`)
COMMAND_TOPIC = {"voltage": "voltage_cmd", "torque": "torque_cmd"}

#: what the controller needs, all stamped t_k, before it computes step k's command
CONTROLLER_INPUTS = ("attitude", "body_rate", "attitude_setpoint", "rate_setpoint")

#: how many graph nodes subscribe to each topic (the recorder comes on top)
GRAPH_SUBSCRIBERS = {
    "attitude": 2, "body_rate": 1, "attitude_setpoint": 1, "rate_setpoint": 1, "voltage_cmd": 1, "torque_cmd": 1,
    "wheel_torque": 1, "wheel_momentum": 1, "disturbance_torque": 1, "/clock": 1,
}

PARAMETER_EVENTS = "/parameter_events"

#: published only by some plant models (paper 002's flexible mode: x = alpha rad, y = d alpha/dt rad/s)
MODEL_TOPICS: dict[str, str] = {"flexible_mode": "geometry_msgs/msg/Vector3Stamped"}

#: everything a run records
RECORDED_TOPICS: dict[str, str] = {**STEP_TOPICS, **MODEL_TOPICS,
                                   PARAMETER_EVENTS: "rcl_interfaces/msg/ParameterEvent"}


def message_class(type_name: str):
    """``pkg/msg/Name`` -> the generated Python message class.

    Raises
    ------
    ValueError
        If the type cannot be imported.
    """
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise AttitudeSilError(f"not a message type name: {type_name!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError):
        raise AttitudeSilError(f"message type {type_name} is not installed") from None
