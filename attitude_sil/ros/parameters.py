"""ROS parameters from the project's schema: descriptors, typed values.

The schema (:mod:`attitude_sil.core.sim.params`) is ROS-free; this module turns a
:class:`~attitude_sil.core.sim.params.ParamSpec` into a ``ParameterDescriptor``
(type, description, ranges, constraints) and a value into a typed
``Parameter``.
"""

from __future__ import annotations

import sys
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.parameter import Parameter

from attitude_sil.core.sim.params import ParamSpec

__all__ = ["typed_parameter", "descriptor", "PARAMETER_TYPES"]

PARAMETER_TYPES = {
    "double": (ParameterType.PARAMETER_DOUBLE, Parameter.Type.DOUBLE),
    "integer": (ParameterType.PARAMETER_INTEGER, Parameter.Type.INTEGER),
    "bool": (ParameterType.PARAMETER_BOOL, Parameter.Type.BOOL),
    "string": (ParameterType.PARAMETER_STRING, Parameter.Type.STRING),
    "double_array": (ParameterType.PARAMETER_DOUBLE_ARRAY, Parameter.Type.DOUBLE_ARRAY),
    "integer_array": (ParameterType.PARAMETER_INTEGER_ARRAY, Parameter.Type.INTEGER_ARRAY),
    "string_array": (ParameterType.PARAMETER_STRING_ARRAY, Parameter.Type.STRING_ARRAY),
}


def typed_parameter(spec: ParamSpec, value: Any) -> Parameter:
    """A ``Parameter`` of the spec's type (so an empty list is not taken for bytes)."""
    return Parameter(spec.name, PARAMETER_TYPES[spec.kind][1], value)


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ``ParameterDescriptor`` of a schema entry: type, description, range, constraints."""
    desc = ParameterDescriptor(
        name=spec.name,
        type=PARAMETER_TYPES[spec.kind][0],
        description=spec.description,
        # what the schema marks not changeable at runtime is read-only: rclpy refuses a set
        # after declaration, naming the parameter (a parameter file or override still sets it)
        read_only=not spec.runtime,
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
