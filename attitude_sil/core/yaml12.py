"""One YAML reader for every file and command-line value: YAML 1.2 numbers.

PyYAML implements YAML 1.1, where ``1e2`` or ``1e-3`` (no dot, unsigned
exponent) are strings; YAML 1.2, ROS 2's parameter files and ``ros2 param
set`` read them as numbers. Scenario files, parameter files, tuning specs,
``--set`` and ``param set`` all load through :func:`load`, so a value means the
same wherever it is written.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

__all__ = ["load"]


class _Loader(yaml.SafeLoader):
    """SafeLoader plus the YAML 1.2 floats that YAML 1.1 misses (exponent without a dot or sign)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def load(text: str) -> Any:
    """Parse YAML text (``yaml.YAMLError`` on malformed input)."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
