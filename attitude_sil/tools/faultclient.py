"""``attitude-sil fault``: inject a fault into a running graph.

A fault is a line of the node's ``faults`` parameter
(:mod:`attitude_sil.core.faults`), so injecting one is adding a line to
the list of the node that flies its target, through its parameter service
(``ros2 param set`` could do the same). The line carries the sim time the
fault was given (the graph's latest ``/clock``); the node starts it at the
first step it can, and says so on ``/diagnostics``, which this client waits
for and reports. A fault the node cannot fly (a latency of no whole number of steps, a second
wheel fault, a wheel the geometry lacks) is refused in one line, and nothing
changes.
"""

from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from attitude_sil.core.faults import OWNER, parse_fault
from attitude_sil.errors import ParamClientError
from attitude_sil.ros.contract import CLOCK, DIAGNOSTICS, check_namespace
from attitude_sil.ros.convert import fault_lines, stamp_to_ns
from attitude_sil.tools.paramclient import remote_session

__all__ = ["fault_command"]

#: what a late reader takes from the plant's /clock and the nodes' /diagnostics: their history (transient local)
_HISTORY = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def fault_command(target: str, mode: str, value: str | None = None, namespace: str | None = None,
                  timeout: float = 10.0) -> str:
    """Add the fault ``TARGET MODE [VALUE]`` to the running graph; return the text to print.

    Raises
    ------
    ScenarioError
        The fault cannot fly (checked before anything is sent).
    ParamClientError
        The node is not found, does not answer, or refuses the fault.
    """
    line = " ".join([target, mode] + ([value] if value is not None else []))
    fault = parse_fault(line)
    ns = check_namespace(namespace)
    node = f"/{ns}/{OWNER[fault.kind]}" if ns else f"/{OWNER[fault.kind]}"
    with remote_session(node, timeout) as s:
        clocks: list[int] = []
        said: list[str] = []
        s.node.create_subscription(Clock, CLOCK, lambda m: clocks.append(stamp_to_ns(m.clock)), _HISTORY)
        s.node.create_subscription(DiagnosticArray, DIAGNOSTICS, lambda data: said.extend(fault_lines(data)),
                                   _HISTORY, raw=True)
        _spin_until(s, lambda: bool(clocks), min(timeout, 2.0))  # the graph's time now, if it runs: the /clock
        _spin_quiet(s, clocks, 0.25, min(timeout, 2.0))  # history comes as a burst, the newest last
        given = f"{line} at {clocks[-1] * 1e-9:.9g}" if clocks else line
        held = s.values(["faults"])["faults"]  # None: the list is empty (rclpy answers nothing for it)
        now = [] if held is None else list(parameter_value_to_python(held))
        result = s.wait(s.client.set_parameters([Parameter("faults", value=[*now, given])])).results[0]
        if not result.successful:
            raise ParamClientError(f"{node} refused the fault {line!r}: {result.reason}")
        since = clocks[-1] * 1e-9 - 1e-9 if clocks else 0.0  # a status of the history, before it: not this one

        def this_one() -> list[str]:
            return [x for x in said if x.startswith(line + " at ") and parse_fault(x).time_s >= since]

        _spin_until(s, lambda: bool(this_one()), timeout)
    active = this_one()
    if active:
        return f"{active[-1]}: active (on {node}, said on {DIAGNOSTICS})"
    return (f"{given}: given to {node}; not active within {timeout:g} s (the graph holds, has ended, or the "
            "fault's time is to come)")


def _spin_until(session, done, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while not done() and time.monotonic() < deadline:
        session.executor.spin_once(timeout_sec=0.05)


def _spin_quiet(session, seen: list, quiet: float, seconds: float) -> None:
    """Spin until ``seen`` has not grown for ``quiet`` s (or ``seconds`` s have passed)."""
    deadline = time.monotonic() + seconds
    count, since = len(seen), time.monotonic()
    while time.monotonic() < deadline and time.monotonic() - since < quiet:
        session.executor.spin_once(timeout_sec=0.05)
        if len(seen) != count:
            count, since = len(seen), time.monotonic()
