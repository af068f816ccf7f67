"""The ROS contract of DESIGN.md section 3 as data: topic names and message types.

No rclpy import, so the bag tools and tests can use it anywhere.
"""

from __future__ import annotations

import importlib

__all__ = ["STEP_TOPICS", "COMMAND_TOPICS", "MODEL_TOPICS", "RECORDED_TOPICS", "message_class"]

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

#: published only by some plant models (paper 002's flexible mode: x = alpha rad, y = d alpha/dt rad/s)
MODEL_TOPICS: dict[str, str] = {"flexible_mode": "geometry_msgs/msg/Vector3Stamped"}

#: everything a run records
RECORDED_TOPICS: dict[str, str] = {**STEP_TOPICS, **MODEL_TOPICS,
                                   "/parameter_events": "rcl_interfaces/msg/ParameterEvent"}


def message_class(type_name: str):
    """``pkg/msg/Name`` -> the generated Python message class.

    Raises
    ------
    ValueError
        If the type cannot be imported.
    """
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise ValueError(f"not a message type name: {type_name!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f"message type {type_name} is not installed") from None
