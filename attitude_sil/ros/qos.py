"""QoS profiles of the graph, and their rosbag2 ``offered_qos_profiles`` form.

One home for every profile a publisher, subscriber, recorder or replay uses,
so a recorded bag states the QoS the graph really offered.
"""

from __future__ import annotations

import yaml
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_parameter_events

from attitude_sil.ros.contract import PARAMETER_EVENTS
from attitude_sil.storage.writer import parse_qos_profiles, qos_profiles_yaml

__all__ = ["LOCKSTEP_QOS", "PARAMETER_EVENTS_QOS", "offered_qos_yaml", "publishers_qos_yaml", "recorded_qos",
           "volatile"]

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


def volatile(profile: QoSProfile) -> QoSProfile:
    """``profile`` with volatile durability: a reader that gets no history from transient-local publishers.

    A tool that joins a running graph (``record``, ``episode``) reads with it,
    so the samples of earlier episodes the lockstep publishers keep are not
    taken for the next one.
    """
    return QoSProfile(reliability=profile.reliability, durability=DurabilityPolicy.VOLATILE,
                      history=profile.history, depth=profile.depth)


_INFINITE_NS = 9223372036854775807


def _duration(ns: int) -> dict:
    if ns <= 0 or ns >= _INFINITE_NS:  # unspecified or infinite: as the ROS graph reports a default
        ns = _INFINITE_NS
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def publishers_qos_yaml(infos) -> str:
    """The ``offered_qos_profiles`` of a topic's publishers, as ``ros2 bag record`` writes it.

    Parameters
    ----------
    infos : list of rclpy.topic_endpoint_info.TopicEndpointInfo
        ``Node.get_publishers_info_by_topic(topic)``.

    Returns
    -------
    str
        A YAML list with one profile per publisher (empty list: ``''``, the default profile).
    """
    profiles = []
    for info in infos:
        q = info.qos_profile
        profiles.append({
            "history": q.history.name.lower(), "depth": int(q.depth),
            "reliability": q.reliability.name.lower(), "durability": q.durability.name.lower(),
            "deadline": _duration(q.deadline.nanoseconds), "lifespan": _duration(q.lifespan.nanoseconds),
            "liveliness": q.liveliness.name.lower(),
            "liveliness_lease_duration": _duration(q.liveliness_lease_duration.nanoseconds),
            "avoid_ros_namespace_conventions": bool(q.avoid_ros_namespace_conventions),
        })
    if not profiles:
        return ""
    return yaml.safe_dump(profiles, sort_keys=False, default_flow_style=False)


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
