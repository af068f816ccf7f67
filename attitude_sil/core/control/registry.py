"""The one list of control laws: the built-ins and those other packages register.

Every part of the package that needs to know which laws exist asks here: the
controller node and its parameter table, the CLI's ``--controller`` /
``--swap`` / ``--help``, the batch engine, the tuner, Monte Carlo, replay
verification and ``docs/parameters.md``.

* Built-in laws: every module of :mod:`attitude_sil.core.control.laws` that
  defines ``LAW``, found by itself (adding one is adding a file).
* Plugins: entry points of the group ``attitude_sil.laws`` (a contract, see
  docs/writing-a-law.md); each names a :class:`~attitude_sil.core.control.law.Law`
  or a module defining ``LAW``. A plugin that fails to load, breaks the
  contract or reuses a taken name is skipped with one line on stderr naming
  the entry point and the reason; the rest of the package works on.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from functools import lru_cache
from importlib.metadata import entry_points
from types import ModuleType

from attitude_sil.core.control import laws as _builtin
from attitude_sil.core.control.law import Law
from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.errors import ScenarioError

__all__ = ["ENTRY_POINT_GROUP", "laws", "get", "names", "declared_names", "builtin_names", "output_of",
           "parameter_table", "plugin_problems", "refresh"]

#: the entry-point group through which other packages add laws (a contract)
ENTRY_POINT_GROUP = "attitude_sil.laws"

_PROBLEMS: list[str] = []


def _law_of(obj, where: str) -> Law:
    law = getattr(obj, "LAW", obj) if isinstance(obj, ModuleType) else obj
    if not isinstance(law, Law):
        raise TypeError(f"{where} is not a Law (nor a module defining LAW)")
    return law


@lru_cache(maxsize=1)
def _plugin_entry_points() -> tuple:
    """The group's entry points by name, read once per process: the read opens every installed distribution's
    metadata, a noticeable share of each ``attitude-sil`` command's start."""
    return tuple(sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name))


def refresh() -> None:
    """Read the laws and the plugins' entry points again on next use (a plugin installed while this process runs)."""
    _plugin_entry_points.cache_clear()
    laws.cache_clear()


@lru_cache(maxsize=1)
def laws() -> dict[str, Law]:
    """Every law by name: the built-ins (by module name), then the plugins (by entry-point name)."""
    found: dict[str, Law] = {}
    for info in sorted(pkgutil.iter_modules(_builtin.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{_builtin.__name__}.{info.name}")
        if hasattr(module, "LAW"):
            law = _law_of(module, module.__name__)
            if law.name != info.name:
                raise TypeError(f"{module.__name__} defines the law {law.name!r}; a built-in law's module must carry "
                                "its name")
            found[law.name] = law
    for ep in _plugin_entry_points():
        where = f"law plugin {ep.name!r} ({ep.value})"
        try:
            law = _law_of(ep.load(), where)
        except Exception as exc:  # a broken plugin must not take the simulator down with it
            _skip(f"{where} could not be loaded: {type(exc).__name__}: {exc}")
            continue
        if law.name in found:
            _skip(f"{where} is named {law.name!r}, which another law already has")
            continue
        if law.name != ep.name:
            _skip(f"{where} defines the law {law.name!r}; the entry point must carry the law's name")
            continue
        found[law.name] = law
    return found


def _skip(line: str) -> None:
    _PROBLEMS.append(line)
    print(f"attitude-sil: {line}; skipped", file=sys.stderr)


def plugin_problems() -> list[str]:
    """What was wrong with each plugin that was skipped (after :func:`laws`)."""
    laws()
    return list(_PROBLEMS)


def names() -> tuple[str, ...]:
    """The ``controller_type`` values, built-ins first."""
    return tuple(laws())


def declared_names() -> tuple[str, ...]:
    """The law names, read without importing any law (for ``--help``): built-in module names, then entry points.

    A built-in law's module carries its name (checked by :func:`laws`), a
    plugin's entry point too; :func:`names` is the checked list.
    """
    builtin = sorted(m.name for m in pkgutil.iter_modules(_builtin.__path__))
    return tuple(builtin) + tuple(ep.name for ep in _plugin_entry_points() if ep.name not in builtin)


def builtin_names() -> tuple[str, ...]:
    """The laws this package ships (:mod:`attitude_sil.core.control.laws`), without plugins."""
    return tuple(name for name, law in laws().items() if law.step.py_func.__module__.startswith(_builtin.__name__))


def get(name: str) -> Law:
    """The law called ``name``; a ScenarioError naming the known laws if there is none."""
    try:
        return laws()[name]
    except KeyError:
        raise ScenarioError(f"unknown controller_type {name!r}; known: {', '.join(names())}") from None


def output_of(name: str) -> str:
    """``command`` or ``torque``: what the law commands (:data:`attitude_sil.core.control.law.OUTPUTS`)."""
    return get(name).output


def parameter_table() -> list[ParamSpec]:
    """Every law's parameters with full names (``pid.kp``, ...), in registry order."""
    return [spec for law in laws().values() for spec in law.table()]
