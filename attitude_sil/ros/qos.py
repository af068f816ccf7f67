"""QoS profiles of the graph, and their rosbag2 ``offered_qos_profiles`` form.

One home for every profile a publisher, subscriber, recorder or replay uses,
so a recorded bag states the QoS the graph really offered.

The rule that lets any ROS node into the lockstep (docs/flight-software.md):
the nodes *publish* reliable and transient-local (:data:`LOCKSTEP_QOS`: a
late transient-local reader, a recorder, gets the history) and *read*
reliable and volatile (:data:`INPUT_QOS`). DDS matches a volatile reader with
a transient-local writer and with a volatile one alike, so a node publishing
with rclpy's or rclcpp's default QoS (reliable, volatile, depth 10) is heard,
and the default subscriber, ``ros2 topic echo`` and rosbag2 hear the nodes.
What a volatile reader gives up is the samples written before it matched:
the runner starts an episode only once every publisher of its graph has
matched every subscriber (:func:`attitude_sil.graph.launcher.wait_connected`),
and its own recorder reads its own nodes' topics with the history, so a
step 0 written before a match across processes still reaches the bag.
An endpoint that cannot match (a best-effort publisher, a reader asking for
more than a node offers) is named in one line by :func:`qos_event_callbacks`.
"""

from __future__ import annotations

import time

import yaml
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSCompatibility,
    QoSProfile,
    ReliabilityPolicy,
    qos_check_compatible,
    qos_profile_parameter_events,
)

from attitude_sil.ros.contract import BODY_MODEL, PARAMETER_EVENTS, TF, UNKNOWN_NODE
from attitude_sil.storage.writer import parse_qos_profiles, qos_profiles_yaml

__all__ = ["LOCKSTEP_QOS", "INPUT_QOS", "PARAMETER_EVENTS_QOS", "offered_qos_yaml", "publishers_qos_yaml",
           "recorded_qos", "volatile", "incompatible_peers", "qos_event_callbacks"]

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


#: what the nodes read with: the lockstep profile, volatile (module docstring)
INPUT_QOS = volatile(LOCKSTEP_QOS)


def incompatible_peers(node, topic: str, qos: QoSProfile, readers: bool) -> list[str]:
    """``/ns/node (reason)`` of each endpoint on ``topic`` that cannot match an endpoint of ours with ``qos``.

    Parameters
    ----------
    node : rclpy.node.Node
    topic : str
        The resolved topic name.
    qos : QoSProfile
        Our endpoint's profile.
    readers : bool
        True: ours is a subscription, the peers are the topic's publishers; False: the other way round.
    """
    infos = node.get_publishers_info_by_topic(topic) if readers else node.get_subscriptions_info_by_topic(topic)
    out = []
    for info in infos:
        pub, sub = (info.qos_profile, qos) if readers else (qos, info.qos_profile)
        compatibility, reason = qos_check_compatible(pub, sub)
        if compatibility == QoSCompatibility.ERROR:
            why = reason.strip().removeprefix("ERROR:").strip().rstrip(";. ")
            out.append(f"{(info.node_namespace or '/').rstrip('/')}/{info.node_name} ({why})")
    return out


def qos_event_callbacks(node, topic: str, qos: QoSProfile, problems: list[str] | None = None,
                        reader: bool = True):
    """Event callbacks that name, in one logged line, a peer whose QoS cannot match our endpoint on ``topic``.

    rclpy's default says only "incompatible QoS, last policy X"; this names
    the topic, each peer node and the reason. The event can come before the
    peer's node name is discovered: the line waits for it (a steady-clock
    timer, up to 2 s). For a subscription (``reader``) the line is also
    appended to ``problems``: the runner stops the episode with it, since the
    step waits for a message that will never come.

    Returns
    -------
    SubscriptionEventCallbacks or PublisherEventCallbacks
    """
    def on_incompatible(info) -> None:
        policy = getattr(info.last_policy_kind, "name", str(info.last_policy_kind)).replace("RMW_QOS_POLICY_", "")
        give_up = time.monotonic() + 2.0
        timer = []

        def report() -> bool:
            resolved = node.resolve_topic_name(topic)
            peers = incompatible_peers(node, resolved, qos, reader)
            if (not peers or any(UNKNOWN_NODE in p for p in peers)) and time.monotonic() < give_up:
                return False  # the peer's name is not discovered yet: ask again at the next tick
            for t in timer:
                node.destroy_timer(t)
            side = "publisher" if reader else "subscriber"
            text = (f"{resolved}: {side} {', '.join(peers) or 'of another node'} has QoS incompatible with "
                    f"{node.get_name()}'s {'subscription' if reader else 'publisher'} (policy {policy}); "
                    "no message passes between them")
            node.get_logger().error(text)
            if problems is not None and reader:
                problems.append(text)
            return True

        if not report():
            timer.append(node.create_timer(0.05, report, clock=Clock(clock_type=ClockType.STEADY_TIME)))

    if reader:
        return SubscriptionEventCallbacks(incompatible_qos=on_incompatible)
    return PublisherEventCallbacks(incompatible_qos=on_incompatible)


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
    if topic == TF:  # what tf2's broadcasters offer: reliable, volatile, keep-last 100
        return qos_profiles_yaml(depth=100)
    if topic == BODY_MODEL:  # latched, as a robot model is: a subscriber joining a replay gets it
        return qos_profiles_yaml(durability="transient_local", depth=1)
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
