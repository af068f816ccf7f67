"""What every node shares: parameters from the schema, QoS, stamps and conversions.

Nodes stay thin: they declare their parameters from
:mod:`attitude_sil.core.params`, turn messages into numpy arrays, call the core
step object and publish the result.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from attitude_sil.core.params import NODE_PARAMS, ParamSpec
from attitude_sil.core.scenario import Scenario, scenario_from_dict

__all__ = [
    "LOCKSTEP_QOS",
    "SchemaNode",
    "stamp_to_ns",
    "ns_to_stamp",
    "steady_clock",
    "run_node",
    "typed_parameter",
]

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

_PTYPE = {
    "double": (ParameterType.PARAMETER_DOUBLE, Parameter.Type.DOUBLE),
    "integer": (ParameterType.PARAMETER_INTEGER, Parameter.Type.INTEGER),
    "bool": (ParameterType.PARAMETER_BOOL, Parameter.Type.BOOL),
    "string": (ParameterType.PARAMETER_STRING, Parameter.Type.STRING),
    "double_array": (ParameterType.PARAMETER_DOUBLE_ARRAY, Parameter.Type.DOUBLE_ARRAY),
    "integer_array": (ParameterType.PARAMETER_INTEGER_ARRAY, Parameter.Type.INTEGER_ARRAY),
    "string_array": (ParameterType.PARAMETER_STRING_ARRAY, Parameter.Type.STRING_ARRAY),
}


def stamp_to_ns(stamp: Time) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def ns_to_stamp(t_ns: int) -> Time:
    """Integer nanoseconds -> builtin_interfaces/Time."""
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def steady_clock() -> Clock:
    """A wall clock for watchdogs and pacing (sim time would stall with the graph)."""
    return Clock(clock_type=ClockType.STEADY_TIME)


def typed_parameter(spec: ParamSpec, value: Any) -> Parameter:
    """A ``Parameter`` of the spec's type (so an empty list is not taken for bytes)."""
    return Parameter(spec.name, _PTYPE[spec.kind][1], value)


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    desc = ParameterDescriptor(
        name=spec.name,
        type=_PTYPE[spec.kind][0],
        description=spec.description,
    )
    if spec.choices:
        desc.additional_constraints = "one of: " + ", ".join(spec.choices)
    if spec.lengths:
        desc.additional_constraints = (desc.additional_constraints + "; " if desc.additional_constraints else "") + \
            "length " + " or ".join(map(str, spec.lengths))
    if spec.kind == "double" and (spec.min is not None or spec.max is not None):
        desc.floating_point_range = [FloatingPointRange(
            from_value=float(spec.min if spec.min is not None else -sys.float_info.max),
            to_value=float(spec.max if spec.max is not None else sys.float_info.max),
            step=0.0)]
    if spec.kind == "integer" and (spec.min is not None or spec.max is not None):
        desc.integer_range = [IntegerRange(
            from_value=int(spec.min if spec.min is not None else -(2**63)),
            to_value=int(spec.max if spec.max is not None else 2**63 - 1),
            step=1)]
    return desc


class SchemaNode(Node):
    """A node whose parameters come from :data:`~attitude_sil.core.params.NODE_PARAMS`.

    Every parameter is declared with a descriptor (type, description, range);
    a set request is validated by the schema rule and then by
    :meth:`check_parameters` (cross-parameter rules); a refusal names the
    parameter and the rule. Accepted values reach :meth:`on_parameters_set`.
    """

    schema_name = ""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.schema_name, **kwargs)
        self._specs = {s.name: s for s in NODE_PARAMS[self.schema_name]}
        for spec in self._specs.values():
            default = spec.default if (not isinstance(spec.default, list) or spec.default) else _PTYPE[spec.kind][1]
            self.declare_parameter(spec.name, default, _descriptor(spec))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._after_set)
        # validate what came in from overrides or a params file
        for spec in self._specs.values():
            try:
                spec.validate(self.param(spec.name), self.get_name())
            except ValueError as exc:
                raise ValueError(f"invalid parameter: {exc}") from None

    # -- parameters ------------------------------------------------------------
    def param(self, name: str) -> Any:
        """Current value of a schema parameter (empty list for an unset array)."""
        if not self.has_parameter(name) or self.get_parameter_or(name).type_ == Parameter.Type.NOT_SET:
            return []
        value = self.get_parameter(name).value
        if value is None and self._specs[name].kind.endswith("_array"):
            return []
        if isinstance(value, (tuple, np.ndarray)) or type(value).__name__ == "array":
            return list(value)
        return value

    def values(self) -> dict[str, Any]:
        """All schema parameters as ``name -> value``."""
        return {name: self.param(name) for name in self._specs}

    def scenario(self) -> Scenario:
        """A scenario holding this node's current parameters (others default)."""
        return scenario_from_dict({self.schema_name: {"ros__parameters": self.values()}},
                                  source=f"node {self.get_name()}", check=False)

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        pending = {}
        for p in params:
            spec = self._specs.get(p.name)
            if spec is None:
                continue  # use_sim_time and friends: rclpy's own rules apply
            value = p.value
            if value is None and spec.kind.endswith("_array"):
                value = []
            try:
                pending[p.name] = spec.validate(list(value) if spec.kind.endswith("_array") else value,
                                                self.get_name())
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        reason = self.check_parameters(pending)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def check_parameters(self, pending: dict[str, Any]) -> str:
        """Cross-parameter rules; return a refusal reason or ''."""
        return ""

    def _after_set(self, params: list[Parameter]) -> None:
        names = [p.name for p in params if p.name in self._specs]
        if names:
            self.on_parameters_set(names)

    def on_parameters_set(self, names: list[str]) -> None:
        """Hook: accepted parameters changed."""

    # -- helpers ---------------------------------------------------------------
    @staticmethod
    def finite(array: np.ndarray) -> bool:
        return bool(np.all(np.isfinite(array)))


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Spin one node in its own process until Ctrl-C or shutdown; the body of every ``main()``.

    Uses rclpy's ``EventsExecutor``: about 7x less overhead per message than the
    default executor on this machine, which is what bounds a lockstep graph.

    Bad parameters print one line and exit 2.
    """
    from rclpy.experimental import EventsExecutor

    rclpy.init(args=args)
    node = None
    executor = None
    try:
        node = factory()
        executor = EventsExecutor()
        executor.add_node(node)
        # spin_once in a loop: EventsExecutor.spin() of rclpy 7.1 left service
        # requests unanswered in a separate process (measured here)
        while rclpy.ok():
            try:
                executor.spin_once(timeout_sec=0.5)
            except RuntimeError:
                if rclpy.ok():
                    raise
                break  # Ctrl-C shut the context down inside spin_once
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


class StepSequencer:
    """Tracks the step stamps a downstream node has handled.

    A stamp of 0, or one earlier than the last, starts a new episode (the
    plant was reset); the next stamp must be the last plus ``dt``; a repeat
    of the last stamp is a duplicate. Anything else is a mismatch the node
    refuses, so it never integrates with a stale or skipped input.
    """

    NEW, NEXT, DUPLICATE, MISMATCH = "new", "next", "duplicate", "mismatch"

    def __init__(self) -> None:
        self.last_ns: int | None = None

    def classify(self, t_ns: int, dt_ns: int) -> str:
        last = self.last_ns
        if last is None or t_ns == 0 or t_ns < last:
            kind = self.NEW
        elif t_ns == last:
            return self.DUPLICATE
        elif t_ns == last + dt_ns:
            kind = self.NEXT
        else:
            return self.MISMATCH
        self.last_ns = t_ns
        return kind
