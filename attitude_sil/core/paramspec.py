"""One parameter's schema: type, default, unit, range, and the check a value must pass.

:class:`ParamSpec` is the unit of every parameter table: the nodes'
(:mod:`attitude_sil.core.sim.params`) and each control law's own
(:mod:`attitude_sil.core.control.law`). It lives apart from both so a law
module can declare its table without importing the node tables.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from attitude_sil.errors import ScenarioError

__all__ = ["ParamSpec", "double", "double_array", "inertia_rule", "nonzero", "distinct"]

_YAML12_FLOAT = re.compile(r"[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?")

KINDS = ("double", "integer", "bool", "string", "double_array", "integer_array", "string_array")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: its type, default and the rule a value must satisfy.

    Attributes
    ----------
    name : str
        Parameter name, dotted for groups (``pid.kp``).
    kind : str
        One of ``double``, ``integer``, ``bool``, ``string`` and their
        ``*_array`` forms.
    default : Any
    description : str
        One line, with the unit.
    min, max : float, optional
        Inclusive bounds for numbers and for every array element.
    min_exclusive : bool
        ``min`` itself is not allowed (strictly positive quantities).
    lengths : tuple of int, optional
        Allowed array lengths.
    choices : tuple of str, optional
        Allowed values for strings (and string-array elements).
    """

    name: str
    kind: str
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    lengths: tuple[int, ...] | None = None
    choices: tuple[str, ...] | None = None
    runtime: bool = field(default=False)
    rule: Callable[[Any], str] | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        assert self.kind in KINDS, self.kind

    # -- validation ------------------------------------------------------------
    def _check_number(self, value: Any, where: str) -> float | int:
        if isinstance(value, str) and _YAML12_FLOAT.fullmatch(value.strip()):
            value = float(value)  # PyYAML (YAML 1.1) reads 1e-3 as a string; YAML 1.2 and ROS read a number
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ScenarioError(f"{where} must be a number, got {type(value).__name__} {value!r}")
        if self.kind.startswith("integer"):
            if isinstance(value, float):
                if not value.is_integer():
                    raise ScenarioError(f"{where} must be an integer, got {value!r}")
                value = int(value)
            if not -(2**63) <= value < 2**63:
                raise ScenarioError(f"{where} must fit a 64-bit integer (a ROS integer), got {value!r}")
        else:
            value = float(value)
            if not math.isfinite(value):
                raise ScenarioError(f"{where} must be finite, got {value!r}")
        if self.min is not None:
            if value < self.min or (self.min_exclusive and value == self.min):
                rel = ">" if self.min_exclusive else ">="
                raise ScenarioError(f"{where} must be {rel} {self.min}, got {value!r}")
        if self.max is not None and value > self.max:
            raise ScenarioError(f"{where} must be <= {self.max}, got {value!r}")
        return value

    def _check_string(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            raise ScenarioError(f"{where} must be a string, got {type(value).__name__} {value!r}")
        if self.choices is not None and value not in self.choices:
            raise ScenarioError(f"{where} must be one of {', '.join(self.choices)}; got {value!r}")
        return value

    def validate(self, value: Any, node: str = "") -> Any:
        """Return the value converted to this parameter's type or raise ``ValueError``.

        The message names the parameter and the rule it broke, on one line.
        """
        where = f"{node}.{self.name}" if node else self.name
        if self.kind == "bool":
            if not isinstance(value, bool):
                raise ScenarioError(f"{where} must be true or false, got {value!r}")
            return value
        if self.kind == "string":
            out = self._check_string(value, where)
            broken = self.rule(out) if self.rule is not None else ""
            if broken:
                raise ScenarioError(f"{where} {broken}")
            return out
        if self.kind in ("double", "integer"):
            return self._check_number(value, where)
        # arrays
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            raise ScenarioError(f"{where} must be a list, got {type(value).__name__} {value!r}")
        items = list(value)
        if self.lengths is not None and len(items) not in self.lengths:
            allowed = " or ".join(str(n) for n in self.lengths)
            raise ScenarioError(f"{where} must have {allowed} elements, got {len(items)}")
        if self.kind == "string_array":
            out = [self._check_string(v, f"{where}[{i}]") for i, v in enumerate(items)]
        else:
            out = [self._check_number(v, f"{where}[{i}]") for i, v in enumerate(items)]
        if self.rule is not None:
            broken = self.rule(out)
            if broken:
                raise ScenarioError(f"{where} {broken}")
        return out


def double(name, default, description, **kw) -> ParamSpec:
    return ParamSpec(name, "double", float(default), description, **kw)


def double_array(name, default, description, **kw) -> ParamSpec:
    return ParamSpec(name, "double_array", [float(v) for v in default], description, **kw)


# ---------------------------------------------------------------- rules shared by several tables

def inertia_rule(values: list) -> str:
    """An inertia must be symmetric and positive definite (3 principal values: each > 0)."""
    if len(values) == 3:
        return "" if all(v > 0.0 for v in values) else "principal moments must be > 0"
    m = [values[0:3], values[3:6], values[6:9]]
    scale = max(abs(v) for v in values) or 1.0
    if any(abs(m[i][j] - m[j][i]) > 1e-9 * scale for i in range(3) for j in range(i)):
        return "must be symmetric (9 row-major entries)"
    minor2 = m[0][0] * m[1][1] - m[0][1] * m[1][0]
    det = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
           + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
    return "" if m[0][0] > 0.0 and minor2 > 0.0 and det > 0.0 else "must be positive definite"


def nonzero(values: list) -> str:
    """A direction: not the zero vector."""
    return "" if any(v != 0.0 for v in values) else "must not be the zero vector"


def distinct(values: list) -> str:
    """Rule of paper 001: the entries of K must differ."""
    return "entries must be distinct (paper 001: k1 != k2 != k3)" if len(set(values)) < len(values) else ""
