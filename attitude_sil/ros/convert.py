"""Message <-> numpy conversions: the one place the project turns ROS messages into arrays.

Every node, the recorder's episode decoder, replay, verify and the bag plots
use these functions. The ``*_to_array`` readers only read attributes, so they
take rclpy messages and the messages ``mcap_ros2`` decodes from a bag alike.
The nodes publish their step messages as CDR bytes
(:func:`attitude_sil.storage.cdr.stamped_vector_cdr`, the same bytes on the
wire, a fourth of the cost); the ``*_msg`` builders here make rclpy messages
for everything else (tools, tests that publish as a foreign node would).

Conventions (docs/architecture.md, "ROS contract"): quaternions in ROS order
``(x, y, z, w)``, Hamilton; vectors in SI units; stamps are integer
nanoseconds of sim time.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, JointState, MagneticField

from attitude_sil.ros.contract import RECORDED_TOPICS, message_class

__all__ = [
    "magnetic_field_msg",
    "odometry_msg",
    "stamp_to_ns",
    "ns_to_stamp",
    "quaternion_to_array",
    "vector_to_array",
    "message_to_array",
    "quaternion_msg",
    "vector_msg",
    "joint_state_msg",
    "decode_step_messages",
    "imu_msg",
    "star_tracker_msg",
    "imu_rate",
    "imu_orientation",
    "ABSENT",
]

#: REP 145: a field a sensor does not measure has element 0 of its covariance set to this
ABSENT = -1.0


def stamp_to_ns(stamp) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(t_ns: int) -> Time:
    """Integer nanoseconds -> ``builtin_interfaces/Time``."""
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def quaternion_to_array(msg) -> np.ndarray:
    """A ``QuaternionStamped`` -> (4,) array ``(x, y, z, w)``."""
    q = msg.quaternion
    return np.array([q.x, q.y, q.z, q.w], dtype=float)


def vector_to_array(msg) -> np.ndarray:
    """A ``Vector3Stamped`` -> (3,) array ``(x, y, z)``."""
    v = msg.vector
    return np.array([v.x, v.y, v.z], dtype=float)


def message_to_array(msg) -> np.ndarray:
    """A stamped quaternion (4,), vector (3,) or magnetic field (3,) message as an array."""
    if hasattr(msg, "magnetic_field"):
        b = msg.magnetic_field
        return np.array([b.x, b.y, b.z], dtype=float)
    return quaternion_to_array(msg) if hasattr(msg, "quaternion") else vector_to_array(msg)


def quaternion_msg(q: Iterable[float], t_ns: int, frame_id: str) -> QuaternionStamped:
    """(4,) ``(x, y, z, w)`` -> ``QuaternionStamped`` stamped ``t_ns`` in ``frame_id``."""
    m = QuaternionStamped()
    m.header.stamp = ns_to_stamp(t_ns)
    m.header.frame_id = frame_id
    m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w = (float(v) for v in q)
    return m


def vector_msg(v: Iterable[float], t_ns: int, frame_id: str) -> Vector3Stamped:
    """(3,) (or (2,), z = 0) -> ``Vector3Stamped`` stamped ``t_ns`` in ``frame_id``."""
    m = Vector3Stamped()
    m.header.stamp = ns_to_stamp(t_ns)
    m.header.frame_id = frame_id
    values = [float(x) for x in v] + [0.0] * 3
    m.vector.x, m.vector.y, m.vector.z = values[:3]
    return m


def joint_state_msg(names: list[str], position: np.ndarray, velocity: np.ndarray, effort: np.ndarray,
                    t_ns: int) -> JointState:
    """Per-wheel angle (rad), speed (rad/s) and motor torque (N m), each (n,), as a ``JointState``."""
    js = JointState()
    js.header.stamp = ns_to_stamp(t_ns)
    js.name = list(names)
    js.position = [float(x) for x in position]
    js.velocity = [float(x) for x in velocity]
    js.effort = [float(x) for x in effort]
    return js


def decode_step_messages(topic: str, items: Iterable[tuple[int, bytes]]) -> tuple[np.ndarray, np.ndarray]:
    """Serialized messages of one step topic -> (stamps ns (n,), values (n, 3|4)), ordered by stamp.

    The first copy of a stamp wins, as in the nodes (a later one is a stray).

    Parameters
    ----------
    topic : str
        A relative topic name of :data:`~attitude_sil.ros.contract.RECORDED_TOPICS`
        carrying a stamped quaternion or vector (a step topic, or the estimator's).
    items : iterable of (int, bytes)
        ``(stamp ns, CDR bytes)``.
    """
    by_t: dict[int, bytes] = {}
    for t, data in items:
        by_t.setdefault(t, data)
    cls = message_class(RECORDED_TOPICS[topic])
    times = sorted(by_t)
    rows = [message_to_array(deserialize_message(by_t[t], cls)) for t in times]
    width = 4 if RECORDED_TOPICS[topic].endswith("QuaternionStamped") else 3
    values = np.array(rows, dtype=float) if rows else np.empty((0, width))
    return np.array(times, dtype=np.int64), values


def _diag(values) -> list[float]:
    v = [float(x) for x in values]
    return [v[0], 0.0, 0.0, 0.0, v[1], 0.0, 0.0, 0.0, v[2]]


def _absent() -> list[float]:
    return [ABSENT] + [0.0] * 8


def imu_msg(omega_B: Iterable[float], variance: Iterable[float], t_ns: int, frame_id: str = "body") -> Imu:
    """A gyro reading as ``sensor_msgs/Imu``: angular velocity (3,) rad/s with its per-sample white-noise
    variance (3,) (rad/s)^2 on the diagonal; orientation and linear acceleration absent (REP 145)."""
    m = Imu()
    m.header.stamp = ns_to_stamp(t_ns)
    m.header.frame_id = frame_id
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(v) for v in omega_B)
    m.angular_velocity_covariance = _diag(variance)
    m.orientation_covariance = _absent()
    m.linear_acceleration_covariance = _absent()
    return m


def odometry_msg(r_N: Iterable[float], v_N: Iterable[float], t_ns: int, frame_id: str = "inertial") -> Odometry:
    """The centre of mass on its orbit as ``nav_msgs/Odometry``: position (3,) m and velocity (3,) m/s in
    ``frame_id``, the child frame the same (the velocity is expressed in it), orientation the identity,
    covariances zero (the truth)."""
    m = Odometry()
    m.header.stamp = ns_to_stamp(t_ns)
    m.header.frame_id = m.child_frame_id = frame_id
    p, v = m.pose.pose.position, m.twist.twist.linear
    p.x, p.y, p.z = (float(x) for x in r_N)
    v.x, v.y, v.z = (float(x) for x in v_N)
    m.pose.pose.orientation.w = 1.0
    return m


#: how a fault's status message begins while it is active
FAULT_PREFIX = "fault: "


def fault_diagnostics_msg(changes, t_ns: int, node: str) -> DiagnosticArray:
    """The faults of ``node`` (its name, e.g. ``wheels``) that became active or ended at step ``t_ns`` as a
    ``diagnostic_msgs/DiagnosticArray``: ``changes`` is ``[(Fault, active), ...]``
    (:func:`attitude_sil.core.faults.changes_at`). Each status is named ``node: target``, its level ERROR
    while the fault is active and OK once it ended, its hardware_id the target, its values the fault's mode,
    value (where it has one), start and duration (s; ``end`` where it lasts)."""
    m = DiagnosticArray()
    m.header.stamp = ns_to_stamp(t_ns)
    for fault, active in changes:
        s = DiagnosticStatus()
        s.level = DiagnosticStatus.ERROR if active else DiagnosticStatus.OK
        s.name = f"{node}: {fault.target}"
        s.hardware_id = fault.target
        s.message = f"{FAULT_PREFIX if active else 'fault ended: '}{fault}"
        pairs = [("mode", fault.mode)] + ([] if fault.value is None else [("value", f"{fault.value:g}")])
        pairs += [("at_s", f"{fault.time_s:g}"),
                  ("for_s", f"{fault.duration_s:g}" if fault.duration_s is not None else
                   "one reading" if fault.mode == "spike" else "end")]
        s.values = [KeyValue(key=k, value=v) for k, v in pairs]
        m.status.append(s)
    return m


def isolation_diagnostics_msg(wheel: int, t_ns: int, reallocated: bool, node: str = "wheels") -> DiagnosticArray:
    """The wheels' FDIR isolating ``wheel`` (1..n) at step ``t_ns`` as a ``diagnostic_msgs/DiagnosticArray``:
    one WARN status (the assembly runs on, degraded) named ``node: fdir``, its hardware_id the wheel, its values
    the wheel, the time and whether the allocation dropped it (``wheels.reallocate_on_fault``)."""
    m = DiagnosticArray()
    m.header.stamp = ns_to_stamp(t_ns)
    s = DiagnosticStatus()
    s.level = DiagnosticStatus.WARN
    s.name = f"{node}: fdir"
    s.hardware_id = f"wheel{wheel}"
    t_s = f"{t_ns * 1e-9:g}"
    s.message = f"isolated wheel{wheel} at {t_s}" + ("; reallocated over the others" if reallocated else "")
    s.values = [KeyValue(key=k, value=v) for k, v in (("wheel", str(wheel)), ("at_s", t_s),
                                                       ("reallocated", "true" if reallocated else "false"))]
    m.status.append(s)
    return m


def fault_lines(data: bytes) -> list[str]:
    """The faults a ``/diagnostics`` message (CDR) says became active: the line of each ERROR status of
    :func:`fault_diagnostics_msg` (``wheel1 stuck at 2``); other nodes' statuses are not faults of ours."""
    m = deserialize_message(data, DiagnosticArray)
    return [s.message.removeprefix(FAULT_PREFIX) for s in m.status
            if s.level == DiagnosticStatus.ERROR and s.message.startswith(FAULT_PREFIX)]


def magnetic_field_msg(b_B: Iterable[float], variance: Iterable[float], t_ns: int,
                       frame_id: str = "body") -> MagneticField:
    """A field (3,) tesla as ``sensor_msgs/MagneticField`` with its per-axis variance (3,) tesla^2 on the
    covariance's diagonal (all zero: the true field, no noise)."""
    m = MagneticField()
    m.header.stamp = ns_to_stamp(t_ns)
    m.header.frame_id = frame_id
    m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = (float(v) for v in b_B)
    m.magnetic_field_covariance = _diag(variance)
    return m


def star_tracker_msg(q: Iterable[float], variance: Iterable[float] | None, t_ns: int, frame_id: str = "body") -> Imu:
    """A star tracker report as ``sensor_msgs/Imu``: orientation (x, y, z, w) with its noise variance (3,)
    rad^2 per body axis on the diagonal, stamped with the exposure time; ``variance=None``: no attitude (an
    outage: orientation absent too); angular velocity and linear acceleration absent (REP 145)."""
    m = Imu()
    m.header.stamp = ns_to_stamp(t_ns)
    m.header.frame_id = frame_id
    if variance is None:
        m.orientation.w = 1.0
        m.orientation_covariance = _absent()
    else:
        m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = (float(v) for v in q)
        m.orientation_covariance = _diag(variance)
    m.angular_velocity_covariance = _absent()
    m.linear_acceleration_covariance = _absent()
    return m


def imu_rate(msg) -> tuple[np.ndarray, np.ndarray]:
    """An ``Imu``'s angular velocity (3,) rad/s and the diagonal (3,) of its covariance."""
    w = msg.angular_velocity
    c = np.asarray(msg.angular_velocity_covariance, dtype=float)
    return np.array([w.x, w.y, w.z], dtype=float), c[[0, 4, 8]]


def imu_orientation(msg) -> tuple[np.ndarray, np.ndarray] | None:
    """An ``Imu``'s orientation (4,) and the diagonal (3,) of its covariance, or None where it is absent."""
    c = np.asarray(msg.orientation_covariance, dtype=float)
    if c[0] == ABSENT:
        return None
    o = msg.orientation
    return np.array([o.x, o.y, o.z, o.w], dtype=float), c[[0, 4, 8]]
