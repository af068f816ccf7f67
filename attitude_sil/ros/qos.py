"""QoS profiles of the graph, and their rosbag2 ``offered_qos_profiles`` form.

One home for every profile a publisher, subscriber, recorder or replay uses,
so a recorded bag states the QoS the graph really offered.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_parameter_events

from attitude_sil.ros.contract import PARAMETER_EVENTS
from attitude_sil.storage.writer import parse_qos_profiles, qos_profiles_yaml

__all__ = ["LOCKSTEP_QOS", "PARAMETER_EVENTS_QOS", "offered_qos_yaml", "recorded_qos"]

#: Lockstep topics: reliable, deep enough that a slow recorder never loses a
#: step, and transient-local so a reader whose match completes after the first
#: samples (discovery across processes is not symmetric in time) still gets
#: them; stale samples are refused by their stamps.
LOCKSTEP_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
)

#: ``/parameter_events``: rclpy's own profile
PARAMETER_EVENTS_QOS = qos_profile_parameter_events


def offered_qos_yaml(topic: str) -> str:
    """The ``offered_qos_profiles`` string a bag records for ``topic``."""
    if topic == PARAMETER_EVENTS:
        return qos_profiles_yaml(depth=1000)
    return qos_profiles_yaml(durability="transient_local", depth=LOCKSTEP_QOS.depth)


def recorded_qos(offered_qos_profiles: str) -> QoSProfile:
    """The QoS to offer a topic with on replay, from the profiles its bag recorded.

    As ``ros2 bag play`` adapts them: reliable only if every recorded
    publisher was, transient-local only if every one was; the recorded history
    and depth (the largest of them); deadline, lifespan and liveliness left at
    their defaults so no subscriber is refused over them.

    Parameters
    ----------
    offered_qos_profiles : str
        A topic's ``offered_qos_profiles`` as the bag holds it (empty: the
        default profile, reliable, volatile, keep-last 10).

    Returns
    -------
    rclpy.qos.QoSProfile

    Raises
    ------
    ValueError
        The profiles are not valid.
    """
    profiles = parse_qos_profiles(offered_qos_profiles)
    reliable = all(p["reliability"] == "reliable" for p in profiles)
    transient = all(p["durability"] == "transient_local" for p in profiles)
    keep_all = any(p["history"] == "keep_all" for p in profiles)
    depth = max(p["depth"] for p in profiles) or 10
    return QoSProfile(
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE,
        history=HistoryPolicy.KEEP_ALL if keep_all else HistoryPolicy.KEEP_LAST,
        depth=depth,
    )
