"""The topic contract as data: names, message types, who publishes and who listens.

Names and types are contracts (docs/architecture.md, "ROS contract"): bags,
replays and other tools depend on them. Nodes, the recorder, the graph tools
and the tests take topic names from here instead of writing literals. All
topics are relative names (a namespace moves a whole graph), except
``/clock`` and ``/parameter_events``.
"""

from __future__ import annotations

import importlib
import re

from attitude_sil.errors import AttitudeSilError

__all__ = ["CLOCK", "ATTITUDE", "BODY_RATE", "ATTITUDE_SETPOINT", "RATE_SETPOINT", "VOLTAGE_CMD", "TORQUE_CMD",
           "WHEEL_CMD", "WHEEL_STATUS", "WHEEL_TORQUE", "WHEEL_MOMENTUM", "WHEEL_STATE", "DISTURBANCE_TORQUE",
           "ATTITUDE_ERROR", "FLEXIBLE_MODE",
           "PLANT_INPUTS", "clock_remap",
           "STEP_TOPICS", "COMMAND_TOPICS", "COMMAND_TOPIC", "APPLIED_COMMAND_TOPIC", "APPLIED_TOPICS",
           "CONTROLLER_INPUTS", "MODEL_TOPICS", "RECORDED_TOPICS",
           "graph_subscribers", "PRODUCERS", "OUTSIDE_ONLY",
           "PARAMETER_EVENTS", "DIAGNOSTICS", "message_class", "check_namespace",
           "check_node_name",
           "check_parameter_name", "ROLE_OUTPUTS", "OPTIONAL_TOPICS", "ROLE_INPUTS", "episode_topics", "EXTERNAL",
           "UNKNOWN_NODE", "IMU", "STAR_TRACKER", "WHEEL_SPEED", "ESTIMATE_ATTITUDE", "ESTIMATE_BODY_RATE",
           "ESTIMATE_GYRO_BIAS", "ESTIMATE_ATTITUDE_SIGMA", "SENSING_TOPICS", "SENSING_STEP_TOPICS", "FEEDBACK_REMAP",
           "feedback_remap", "recorded_topics", "SENSING_ROLES", "TF", "BODY_MODEL", "VIEW_TOPICS", "ORBIT_TOPIC",
           "MAGNETIC_FIELD", "MAGNETOMETER", "ENVIRONMENT_TOPICS", "DIPOLE_CMD", "MAGNETIC_TORQUE", "MAGNETIC_TOPICS",
           "DUMPING_INPUTS", "plant_inputs"]

# -- name rules (ROS 2: a token is a letter or _ then letters, digits, _) -----------------
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def check_namespace(namespace: str | None) -> str | None:
    """A namespace without its outer ``/`` (None for none, ``""`` and ``/`` included), or AttitudeSilError.

    Checked before any ROS context starts, so a bad ``--namespace`` is one line, not rclpy's three.
    """
    ns = (namespace or "").strip("/")
    if not ns:
        return None
    bad = [t for t in ns.split("/") if not _TOKEN.fullmatch(t)]
    if bad:
        raise AttitudeSilError(f"namespace {namespace!r}: {bad[0]!r} is not a ROS name (a letter or _, then "
                               "letters, digits and _; tokens separated by one /)")
    return ns


def check_node_name(name: str) -> str:
    """A node name, optionally with its namespace (``controller``, ``/sat1/controller``), or AttitudeSilError."""
    tokens = name[1:].split("/") if name.startswith("/") else name.split("/")
    if not all(_TOKEN.fullmatch(t) for t in tokens):
        raise AttitudeSilError(f"node name {name!r} is not a ROS node name (e.g. controller or /sat1/controller)")
    return name


def check_parameter_name(name: str) -> str:
    """A parameter name (``pid.kp``, ``use_sim_time``), or AttitudeSilError."""
    if not all(_TOKEN.fullmatch(t) for t in name.split(".")):
        raise AttitudeSilError(f"parameter name {name!r} is not a ROS parameter name (e.g. pid.kp)")
    return name


# -- names (relative, except /clock and /parameter_events) ----------------------------
CLOCK = "/clock"
ATTITUDE = "attitude"
BODY_RATE = "body_rate"
ATTITUDE_SETPOINT = "attitude_setpoint"
RATE_SETPOINT = "rate_setpoint"
VOLTAGE_CMD = "voltage_cmd"
TORQUE_CMD = "torque_cmd"
#: each wheel's own command (a user's allocation): ``sensor_msgs/msg/JointState`` stamped t_k, ``name`` the
#: wheels' (``wheel_1`` ... as ``wheel_state``; empty: in that order), ``effort`` each wheel's motor torque, N m
#: (positive spins the wheel up along its axis; the body takes the reaction), ``position`` and ``velocity`` empty
WHEEL_CMD = "wheel_cmd"
#: which wheels a user's flight software declares failed (level ERROR) or sound again (OK):
#: ``diagnostic_msgs/msg/DiagnosticArray``, a status per wheel with ``hardware_id`` ``wheel<n>``, stamped t_k;
#: the wheels node takes it into its ``available`` parameter from the step after the stamp
WHEEL_STATUS = "wheel_status"
WHEEL_TORQUE = "wheel_torque"
WHEEL_MOMENTUM = "wheel_momentum"
WHEEL_STATE = "wheel_state"
DISTURBANCE_TORQUE = "disturbance_torque"
ATTITUDE_ERROR = "attitude_error"
FLEXIBLE_MODE = "flexible_mode"
PARAMETER_EVENTS = "/parameter_events"
# the sensing loop (docs/sensors.md): the sensors node's and the estimator's
IMU = "imu"
STAR_TRACKER = "star_tracker"
WHEEL_SPEED = "wheel_speed"
ESTIMATE_ATTITUDE = "estimate/attitude"
ESTIMATE_BODY_RATE = "estimate/body_rate"
ESTIMATE_GYRO_BIAS = "estimate/gyro_bias"
ESTIMATE_ATTITUDE_SIGMA = "estimate/attitude_sigma"
ORBIT_TOPIC = "orbit"
MAGNETIC_FIELD = "magnetic_field"
MAGNETOMETER = "magnetometer"
# the magnetorquers (docs/orbit-and-field.md): the controller's dipole command and the rods' torque
DIPOLE_CMD = "dipole_cmd"
MAGNETIC_TORQUE = "magnetic_torque"

#: topics of the lockstep (relative names, except /clock); one message per step each,
#: except the command topics, of which exactly one carries each step
STEP_TOPICS: dict[str, str] = {
    CLOCK: "rosgraph_msgs/msg/Clock",
    ATTITUDE: "geometry_msgs/msg/QuaternionStamped",
    BODY_RATE: "geometry_msgs/msg/Vector3Stamped",
    ATTITUDE_SETPOINT: "geometry_msgs/msg/QuaternionStamped",
    RATE_SETPOINT: "geometry_msgs/msg/Vector3Stamped",
    VOLTAGE_CMD: "geometry_msgs/msg/Vector3Stamped",
    TORQUE_CMD: "geometry_msgs/msg/Vector3Stamped",
    WHEEL_CMD: "sensor_msgs/msg/JointState",
    WHEEL_TORQUE: "geometry_msgs/msg/Vector3Stamped",
    WHEEL_MOMENTUM: "geometry_msgs/msg/Vector3Stamped",
    WHEEL_STATE: "sensor_msgs/msg/JointState",
    DISTURBANCE_TORQUE: "geometry_msgs/msg/Vector3Stamped",
    ATTITUDE_ERROR: "geometry_msgs/msg/Vector3Stamped",
}

#: the controller publishes one of these per step, depending on its law (``wheel_cmd``: a user's flight software
#: that shares the command among the wheels itself)
COMMAND_TOPICS = (VOLTAGE_CMD, TORQUE_CMD, WHEEL_CMD)

#: the command topic of each kind of law (:meth:`attitude_sil.core.control.bank.ControllerBank.kind_of`)
COMMAND_TOPIC = {"voltage": VOLTAGE_CMD, "torque": TORQUE_CMD}

#: the command the wheels applied over each step, stamped t_k, when the controller runs on a timer of its own
#: (``command_timing`` ``sim_timer`` or ``wall``: its commands come at its ticks, not one per step); a run's
#: metrics read these where a bag has them
APPLIED_COMMAND_TOPIC = {"voltage": "applied/voltage_cmd", "torque": "applied/torque_cmd"}
APPLIED_TOPICS: dict[str, str] = {t: "geometry_msgs/msg/Vector3Stamped" for t in APPLIED_COMMAND_TOPIC.values()}

#: what the plant needs, all stamped t_k, before it integrates to t_k+1
PLANT_INPUTS = (WHEEL_TORQUE, WHEEL_MOMENTUM, DISTURBANCE_TORQUE)

def plant_inputs(magnetorquers: bool) -> tuple[str, ...]:
    """What the plant waits for each step: :data:`PLANT_INPUTS`, and ``magnetic_torque`` where the
    magnetorquers fly (``magnetorquers``)."""
    return PLANT_INPUTS + ((MAGNETIC_TORQUE,) if magnetorquers else ())


#: what the controller's momentum management reads, stamped t_k, before it commands step k's dipole: the
#: wheels' momentum (after the step's command) and the field (the magnetometer's with feedback estimate)
DUMPING_INPUTS = (WHEEL_MOMENTUM, MAGNETIC_FIELD)

#: what the controller needs, all stamped t_k, before it computes step k's command
CONTROLLER_INPUTS = (ATTITUDE, BODY_RATE, ATTITUDE_SETPOINT, RATE_SETPOINT)

#: the sensing loop's topics, published when a scenario runs the sensors and the estimator: the gyro (every
#: step, orientation absent), the star tracker (at its rate, stamped with its exposure, angular velocity absent;
#: REP 145: an absent field has element 0 of its covariance -1), the wheel tachometers, the estimate, and the
#: magnetometer (where the plant publishes a field: the field in B with its noise variance on the diagonal)
SENSING_TOPICS: dict[str, str] = {
    IMU: "sensor_msgs/msg/Imu",
    STAR_TRACKER: "sensor_msgs/msg/Imu",
    WHEEL_SPEED: "sensor_msgs/msg/JointState",
    ESTIMATE_ATTITUDE: "geometry_msgs/msg/QuaternionStamped",
    ESTIMATE_BODY_RATE: "geometry_msgs/msg/Vector3Stamped",
    ESTIMATE_GYRO_BIAS: "geometry_msgs/msg/Vector3Stamped",
    ESTIMATE_ATTITUDE_SIGMA: "geometry_msgs/msg/Vector3Stamped",
    MAGNETOMETER: "sensor_msgs/msg/MagneticField",
}

#: the sensing topics with one message per step (the star tracker has its own rate)
SENSING_STEP_TOPICS = (IMU, WHEEL_SPEED, ESTIMATE_ATTITUDE, ESTIMATE_BODY_RATE, ESTIMATE_GYRO_BIAS,
                       ESTIMATE_ATTITUDE_SIGMA)

#: ``feedback: estimate``: the controller's state inputs remapped to the estimator's outputs
FEEDBACK_REMAP = {ATTITUDE: ESTIMATE_ATTITUDE, BODY_RATE: ESTIMATE_BODY_RATE, MAGNETIC_FIELD: MAGNETOMETER}


def feedback_remap(feedback: str) -> list[str]:
    """``--ros-args`` remap rules that make the controller read ``feedback`` (``truth``: none)."""
    if feedback != "estimate":
        return []
    return [arg for src, dst in FEEDBACK_REMAP.items() for arg in ("-r", f"{src}:={dst}")]


#: step topics only a node outside the package publishes (a user's flight software in the controller's role)
OUTSIDE_ONLY = frozenset({WHEEL_CMD})

#: the one node of the graph that publishes each step topic (docs/architecture.md, "ROS contract")
PRODUCERS = {
    CLOCK: "plant", ATTITUDE: "plant", BODY_RATE: "plant", ATTITUDE_SETPOINT: "guidance", RATE_SETPOINT: "guidance",
    VOLTAGE_CMD: "controller", TORQUE_CMD: "controller", WHEEL_CMD: "controller", WHEEL_TORQUE: "wheels",
    WHEEL_MOMENTUM: "wheels",
    WHEEL_STATE: "wheels", DISTURBANCE_TORQUE: "disturbance", ATTITUDE_ERROR: "controller",
    IMU: "sensors", STAR_TRACKER: "sensors", WHEEL_SPEED: "sensors", ESTIMATE_ATTITUDE: "estimator",
    ESTIMATE_BODY_RATE: "estimator", ESTIMATE_GYRO_BIAS: "estimator", ESTIMATE_ATTITUDE_SIGMA: "estimator",
    MAGNETOMETER: "sensors",
    **{t: "wheels" for t in APPLIED_TOPICS}, ORBIT_TOPIC: "plant", MAGNETIC_FIELD: "plant",
    DIPOLE_CMD: "controller", MAGNETIC_TORQUE: "magnetorquers",
}

#: the nodes that publish the sensing loop's topics (the sensors and the estimator)
SENSING_ROLES = tuple(dict.fromkeys(PRODUCERS[t] for t in SENSING_TOPICS))

#: what each node of the graph must publish for the others, every step: a tuple of alternatives each (the
#: controller publishes one command topic, of its law's kind); what a node started in place of a built-in one
#: (``run --external NODE``) must provide (docs/flight-software.md)
ROLE_OUTPUTS: dict[str, tuple[tuple[str, ...], ...]] = {
    "plant": ((CLOCK,), (ATTITUDE,), (BODY_RATE,)),
    "wheels": ((WHEEL_TORQUE,), (WHEEL_MOMENTUM,)),
    "disturbance": ((DISTURBANCE_TORQUE,),),
    "guidance": ((ATTITUDE_SETPOINT,), (RATE_SETPOINT,)),
    "controller": (COMMAND_TOPICS,),
    "sensors": ((IMU,), (STAR_TRACKER,)),
    "estimator": ((ESTIMATE_ATTITUDE,), (ESTIMATE_BODY_RATE,)),
}

#: what each node may read, all stamped t_k, for step k
ROLE_INPUTS: dict[str, tuple[str, ...]] = {
    "plant": PLANT_INPUTS, "wheels": COMMAND_TOPICS, "disturbance": (ATTITUDE,), "guidance": (ATTITUDE,),
    "controller": CONTROLLER_INPUTS,
    "sensors": (ATTITUDE, BODY_RATE, WHEEL_STATE),
    "estimator": (IMU, STAR_TRACKER),
    "magnetorquers": (DIPOLE_CMD, MAGNETIC_FIELD),
}

#: what each node reads besides :data:`ROLE_INPUTS` where the magnetorquers fly (``magnetorquers``)
MAGNETIC_INPUTS: dict[str, tuple[str, ...]] = {"plant": (MAGNETIC_TORQUE,), "controller": DUMPING_INPUTS}


def graph_subscribers(external=(), feedback: str | None = None, magnetic: bool = False) -> dict[str, int]:
    """How many of the package's graph nodes subscribe to each topic (the recorder comes on top), the nodes
    named in ``external`` (played from outside) left out; ``feedback`` (``truth`` or ``estimate``) when the
    sensing loop runs, else None; ``magnetic`` where the magnetorquers fly."""
    out: dict[str, int] = {}
    for role, inputs in ROLE_INPUTS.items():
        if role in external or (feedback is None and role in SENSING_ROLES) \
                or (not magnetic and role == "magnetorquers"):
            continue
        for topic in inputs + (MAGNETIC_INPUTS.get(role, ()) if magnetic else ()):
            if role == "controller" and feedback == "estimate":
                topic = FEEDBACK_REMAP.get(topic, topic)
            out[topic] = out.get(topic, 0) + 1
    return out


#: the names rmw gives an endpoint whose node is not discovered yet (a node of another process, just started)
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"

#: what a report names as the controller_type of a controller outside the package
EXTERNAL = "external"

#: step topics no other node reads: the built-in nodes publish them for the record (the controller's error,
#: the wheels' joint state); a node in their place may leave them out, and the tools then do without them
OPTIONAL_TOPICS = (ATTITUDE_ERROR, WHEEL_STATE)


def episode_topics(external=()) -> list[str]:
    """The step topics an episode fills, one message per step each (commands aside: one of them carries each
    step), when the nodes named in ``external`` are not the package's own (their optional topics left out)."""
    return [t for t in STEP_TOPICS if t not in COMMAND_TOPICS
            and not (t in OPTIONAL_TOPICS and PRODUCERS[t] in external)]


#: the plant's environment topics: the orbit (``nav_msgs/msg/Odometry``: the centre of mass in ``inertial``,
#: position m and velocity m/s, frame and child frame ``inertial``, orientation the identity, covariances zero)
#: and the true geomagnetic field at the spacecraft in B (``sensor_msgs/msg/MagneticField``, tesla, frame
#: ``body``, covariance zero), the latter where ``environment.magnetic_field.model`` is not ``none``
ENVIRONMENT_TOPICS: dict[str, str] = {ORBIT_TOPIC: "nav_msgs/msg/Odometry",
                                      MAGNETIC_FIELD: "sensor_msgs/msg/MagneticField"}

#: the magnetorquers' topics (where they fly): the dipole the controller commands (A m^2 in B) and the rods'
#: torque on the body (N m in B, m x B), both stamped t_k and held over the step
MAGNETIC_TOPICS: dict[str, str] = {DIPOLE_CMD: "geometry_msgs/msg/Vector3Stamped",
                                   MAGNETIC_TORQUE: "geometry_msgs/msg/Vector3Stamped"}

#: published only by some plant models (paper 002's flexible mode: x = alpha rad, y = d alpha/dt rad/s)
MODEL_TOPICS: dict[str, str] = {FLEXIBLE_MODE: "geometry_msgs/msg/Vector3Stamped"}

#: the 3D view's topics (relative names): the frames (``tf2_msgs/msg/TFMessage``: ``body`` in ``inertial`` each
#: step, and ``lvlh`` in ``inertial`` where the scenario has an orbit) and the body model drawn in ``body``
#: (``visualization_msgs/msg/MarkerArray``). No node publishes them on the graph (tf2_msgs has no wheel on PyPI):
#: the recorder writes them, from each step's ``attitude`` and the scenario (core/plant/scene.py), to the bag and
#: the live view
TF = "tf"
BODY_MODEL = "body_model"
VIEW_TOPICS: dict[str, str] = {TF: "tf2_msgs/msg/TFMessage", BODY_MODEL: "visualization_msgs/msg/MarkerArray"}

#: faults as they become active and end (the ROS convention for health, absolute as ``diagnostic_updater``
#: publishes it): a ``DiagnosticArray`` stamped at the step, one status per fault, published by the node whose
#: target it is (docs/faults.md, :func:`attitude_sil.ros.convert.fault_diagnostics_msg`)
DIAGNOSTICS = "/diagnostics"

#: everything a run records
RECORDED_TOPICS: dict[str, str] = {**STEP_TOPICS, **MODEL_TOPICS, **SENSING_TOPICS, **APPLIED_TOPICS,
                                   **ENVIRONMENT_TOPICS, **MAGNETIC_TOPICS,
                                   DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
                                   PARAMETER_EVENTS: "rcl_interfaces/msg/ParameterEvent"}


def recorded_topics(sensing: bool, applied: bool = False, field: bool = False,
                    magnetic: bool = False) -> dict[str, str]:
    """What a run records: :data:`RECORDED_TOPICS`, the sensing loop's topics only where it runs (a run
    without it has no empty ``imu``, ``estimate/*``, ... channels in its bag), the wheels' applied
    commands (:data:`APPLIED_TOPICS`) with ``applied`` (a controller on a timer of its own), and
    ``magnetic_field`` (and, with the sensing loop, ``magnetometer``) with ``field`` (the scenario has a field
    model), and the magnetorquers' topics (:data:`MAGNETIC_TOPICS`) with ``magnetic``."""
    return {k: v for k, v in RECORDED_TOPICS.items()
            if (sensing or k not in SENSING_TOPICS) and (applied or k not in APPLIED_TOPICS)
            and (field or k not in (MAGNETIC_FIELD, MAGNETOMETER)) and (magnetic or k not in MAGNETIC_TOPICS)}


def message_class(type_name: str):
    """``pkg/msg/Name`` -> the generated Python message class.

    Raises
    ------
    AttitudeSilError
        If the type cannot be imported.
    """
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise AttitudeSilError(f"not a message type name: {type_name!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError):
        raise AttitudeSilError(f"message type {type_name} is not installed") from None


def clock_remap(namespace: str | None) -> list[str]:
    """``--ros-args`` remap rules that move ``/clock`` under ``namespace`` (empty without one)."""
    return ["-r", f"{CLOCK}:=/{namespace}{CLOCK}"] if namespace else []
