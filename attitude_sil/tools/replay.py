"""``attitude-sil replay``: republish a recorded bag on its topics with its timing.

The project's stand-in for ``ros2 bag play``. Messages go out as the recorded
CDR bytes (no decode/encode), ``/clock`` included, so live nodes with
``use_sim_time`` consume them as if the plant were running. Each topic is
offered with the QoS its bag recorded (``offered_qos_profiles``, adapted as
``ros2 bag play`` does: :func:`attitude_sil.ros.qos.recorded_qos`). Timing follows the
log times (the recorded sim-time stamps) scaled by ``rate``; ``rate = 0`` sends
as fast as possible. ``/parameter_events`` is not republished unless asked for
(a replayed parameter event would look like a change of the live nodes). A
topic whose message type is not installed is left out with a note (the 3D
view's ``/tf``: tf2_msgs has no wheel on PyPI; ``ros2 bag play`` on a full
ROS 2 install replays it); named in ``--topics``, it is an error.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy.node import Node

from attitude_sil.errors import AttitudeSilError, BagError
from attitude_sil.ros.contract import CLOCK, PARAMETER_EVENTS, check_namespace, message_class
from attitude_sil.ros.environment import localhost_environment
from attitude_sil.ros.qos import recorded_qos
from attitude_sil.storage.reader import open_bag

__all__ = ["ReplayOptions", "replay_bag", "remap_topic"]


@dataclass
class ReplayOptions:
    """What and how to replay.

    Attributes
    ----------
    rate : float
        Speed factor on the recorded timing; 0 = as fast as possible.
    start : float
        Seconds after the bag's first message to start from.
    duration : float or None
        Seconds of the bag to play (None: to the end).
    topics : list of str or None
        Topics to play (full names or last components); None: all but /parameter_events.
    loop : bool
        Start again at the end, until interrupted.
    namespace : str or None
        Put every topic except /clock under this namespace.
    wait_for_subscribers : int
        Before sending, wait until each topic has this many matched subscribers.
    connect_timeout : float
        Seconds to wait for them.
    """

    rate: float = 1.0
    start: float = 0.0
    duration: float | None = None
    topics: list[str] | None = None
    loop: bool = False
    namespace: str | None = None
    wait_for_subscribers: int = 0
    connect_timeout: float = 20.0

    def check(self) -> None:
        """Refuse what cannot be played (before any ROS context starts).

        Raises
        ------
        AttitudeSilError
            A rate, start or duration that is not finite or out of range, or a bad namespace.
        """
        for flag, value, least, strict in (("--rate", self.rate, 0.0, False), ("--start", self.start, 0.0, False),
                                           ("--duration", self.duration, 0.0, True)):
            if value is None:
                continue
            if not math.isfinite(value) or value < least or (strict and value == least):
                rule = f"> {least:g}" if strict else f">= {least:g}"
                raise AttitudeSilError(f"{flag} must be a finite number {rule}, got {value}")
        self.namespace = check_namespace(self.namespace)


def remap_topic(topic: str, namespace: str | None) -> str:
    """``/attitude`` -> ``/<namespace>/attitude``; /clock and /parameter_events stay global."""
    if not namespace or topic in (CLOCK, PARAMETER_EVENTS):
        return topic
    return "/" + namespace.strip("/") + "/" + topic.split("/")[-1]


def _installed(type_name: str) -> bool:
    try:
        message_class(type_name)
    except AttitudeSilError:
        return False
    return True


def _select(reader, wanted: list[str] | None, say: Callable[[str], None] | None = None) -> list[str]:
    names = list(reader.topics)
    if wanted is None:
        chosen = []
        for n in names:
            if n == PARAMETER_EVENTS:
                continue
            if not _installed(reader.topics[n].type):
                if say is not None:
                    say(f"note: {n} ({reader.topics[n].type}) is not replayed: its message type is not installed "
                        "(ros2 bag play on a full ROS 2 install replays it)")
                continue
            chosen.append(n)
        return chosen
    chosen = []
    for w in wanted:
        match = w if w in reader.topics else reader.find_topic(w.strip("/"))
        if match is None:
            raise BagError(f"{reader.paths[0]}: no topic {w!r} in the bag (it has {', '.join(sorted(names))})")
        chosen.append(match)
    return chosen


def _topic_qos(reader, topic: str):
    try:
        return recorded_qos(reader.topics[topic].offered_qos_profiles)
    except ValueError as exc:
        raise BagError(f"{reader.paths[0]}: {topic}: {exc}") from None


def replay_bag(path: str | Path, options: ReplayOptions, context=None,
               on_progress: Callable[[float, int], None] | None = None,
               should_stop: Callable[[], bool] | None = None, say: Callable[[str], None] | None = None) -> int:
    """Publish the bag's messages with their timing; return how many were sent.

    Parameters
    ----------
    path : bag directory or .mcap file
    options : ReplayOptions
    context : rclpy.Context, optional
        An initialised context (default: init and shut down one here).
    on_progress : callable(sim_time_s, sent), optional
    should_stop : callable() -> bool, optional
        Polled between messages (Ctrl-C handling of the caller).
    say : callable(str), optional
        Where a note on a topic left out goes (its message type is not installed).

    Raises
    ------
    BagError
        Unreadable bag, unknown topic, or subscribers that never came.
    """
    options.check()
    reader = open_bag(path)
    topics = _select(reader, options.topics, say)
    own = context is None
    if own:
        localhost_environment()
        context = rclpy.Context()
        rclpy.init(args=[], context=context)
    node = Node("replay", context=context)
    try:
        pubs = {t: node.create_publisher(message_class(reader.topics[t].type), remap_topic(t, options.namespace),
                                         _topic_qos(reader, t)) for t in topics}
        if options.wait_for_subscribers > 0:
            deadline = time.monotonic() + options.connect_timeout
            while any(p.get_subscription_count() < options.wait_for_subscribers for p in pubs.values()):
                if time.monotonic() > deadline:
                    missing = [t for t, p in pubs.items() if p.get_subscription_count() < options.wait_for_subscribers]
                    raise BagError(f"no subscriber on {', '.join(missing)} within {options.connect_timeout:g} s")
                time.sleep(0.01)  # rmw discovery runs in its own threads; nothing to spin here
        t0 = reader.start_ns + int(options.start * 1e9)
        t1 = None if options.duration is None else t0 + int(options.duration * 1e9)
        sent = 0
        while True:
            wall0 = time.monotonic()
            for msg in reader.iter_raw(topics=topics, start_ns=t0, end_ns=t1):
                if should_stop is not None and should_stop():
                    return sent
                if options.rate > 0:
                    delay = wall0 + (msg.log_time_ns - t0) * 1e-9 / options.rate - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                pubs[msg.topic].publish(msg.data)
                sent += 1
                if on_progress is not None and sent % 200 == 0:
                    on_progress((msg.log_time_ns - reader.start_ns) * 1e-9, sent)
            if not options.loop:
                return sent
    finally:
        node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)
