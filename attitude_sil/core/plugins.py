"""What the package's registries of units share: finding the built-ins in their folder, naming a plugin and
loading it without letting it take the simulator down.

The control laws (:mod:`attitude_sil.core.control.registry`) and the attitude filters
(:mod:`attitude_sil.core.sensing.registry`) are each a folder of built-in modules and an entry-point group;
each registry keeps its own checks.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from types import ModuleType
from typing import Any

__all__ = ["builtin_units", "plugin_where", "load_plugin"]


def builtin_units(package: ModuleType, attr: str) -> list[tuple[str, ModuleType]]:
    """Each module of ``package`` that defines ``attr``, with its name, in name order (adding a built-in is
    adding a file)."""
    out = []
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        if hasattr(module, attr):
            out.append((info.name, module))
    return out


def plugin_where(kind: str, ep) -> str:
    """A plugin as one line names it: ``<kind> plugin 'name' (module:attr, distribution D)``."""
    dist = getattr(getattr(ep, "dist", None), "name", None)
    return f"{kind} plugin {ep.name!r} ({ep.value}{f', distribution {dist}' if dist else ''})"


def load_plugin(ep, where: str, unit_of: Callable[[Any, str], Any]) -> tuple[Any, str]:
    """The unit entry point ``ep`` names (``unit_of(loaded, where)`` takes it out of its module), and '';
    or None and the line that says why it could not be loaded."""
    try:
        return unit_of(ep.load(), where), ""
    except Exception as exc:  # a broken plugin must not take the simulator down with it
        return None, f"{where} could not be loaded: {type(exc).__name__}: {exc}"
