"""QoS profiles of the graph, and their rosbag2 ``offered_qos_profiles`` form.

One home for every profile a publisher, subscriber, recorder or replay uses,
so a recorded bag states the QoS the graph really offered.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_parameter_events

from attitude_sil.ros.contract import PARAMETER_EVENTS
from attitude_sil.storage.writer import qos_profiles_yaml

__all__ = ["LOCKSTEP_QOS", "PARAMETER_EVENTS_QOS", "offered_qos_yaml"]

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
