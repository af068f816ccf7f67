"""A /clock relay that loses the jump back to 0 at a new episode, as a sim-time reader's depth-1 queue can.

``python test/graph/lossy_clock.py FIRST_TICK_S`` relays ``/clock`` to
``/lossy_clock`` in order, except a ``/clock`` 0 that follows one later than
FIRST_TICK_S (the end of an episode): a node reading ``/lossy_clock`` (remapped
``-r /clock:=/lossy_clock``) then first sees a time after 0 and its rcl timer
takes its phase from there. A 0 that follows the first tick's ``/clock`` (the
plant sending the episode's start again) goes through.
"""

from __future__ import annotations

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock


def main() -> int:
    first_tick_ns = int(round(float(sys.argv[1]) * 1e9))
    rclpy.init()
    node = Node("lossy_clock")
    pub = node.create_publisher(Clock, "/lossy_clock", QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    last = [0]

    def relay(msg: Clock) -> None:
        t = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        drop = t == 0 and last[0] > first_tick_ns
        last[0] = t
        if not drop:
            pub.publish(msg)

    node.create_subscription(Clock, "/clock", relay, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
