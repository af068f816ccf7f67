"""One YAML reader for every file and command-line value: YAML 1.2 numbers.

PyYAML implements YAML 1.1, where ``1e2`` or ``1e-3`` (no dot, unsigned
exponent) are strings; YAML 1.2, ROS 2's parameter files and ``ros2 param
set`` read them as numbers. Scenario files, parameter files, tuning specs,
``--set`` and ``param set`` all load through :func:`load`, so a value means the
same wherever it is written.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

__all__ = ["load", "load_file", "problem", "read"]


class _Loader(yaml.SafeLoader):
    """SafeLoader plus the YAML 1.2 floats that YAML 1.1 misses (exponent without a dot or sign)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def load(text: str) -> Any:
    """Parse YAML text (``yaml.YAMLError`` on malformed input, nesting too deep included)."""
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except RecursionError:  # PyYAML composes nested collections recursively
        raise yaml.YAMLError("collections nested too deeply") from None


def load_file(path: str | Path) -> Any:
    """Parse a YAML file; ``yaml.YAMLError`` also when it is not UTF-8 text (binary garbage).

    ``OSError`` (missing, a directory, unreadable) is left to the caller.
    """
    data = Path(path).read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise yaml.YAMLError(f"not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})") from None
    return load(text)


def problem(exc: BaseException) -> str:
    """`` at line N`` or `` (problem)`` for a YAML error: one line, for the messages of every YAML file."""
    mark = getattr(exc, "problem_mark", None)
    if mark is not None:
        return f" at line {mark.line + 1}"
    text = " ".join(str(exc).split())
    return f" ({text})" if text else ""


def read(path: str | Path, what: str, error: type[Exception]) -> Any:
    """The data of a YAML file, or ``error`` with one line that names the file and the problem.

    Parameters
    ----------
    path : path
    what : str
        What the file is, for the messages (``scenario file``, ``tuning spec``).
    error : exception class
        Raised for a missing file, a directory, unreadable or invalid YAML.
    """
    p = Path(path)
    if p.is_dir():
        raise error(f"{p}: a directory, not a {what}")
    if not p.is_file():
        raise error(f"{p}: no such {what}")
    try:
        return load_file(p)
    except yaml.YAMLError as exc:
        raise error(f"{p}: not valid YAML{problem(exc)}") from None
    except OSError as exc:
        raise error(f"{p}: cannot read: {exc.strerror or exc}") from None
