"""The one list of control laws: the built-ins and those other packages register.

Every part of the package that needs to know which laws exist asks here: the
controller node and its parameter table, the CLI's ``--controller`` /
``--swap`` / ``--help``, the batch engine, the tuner, Monte Carlo, replay
verification and ``docs/parameters.md``.

* Built-in laws: every module of :mod:`attitude_sil.core.control.laws` that
  defines ``LAW``, found by itself (adding one is adding a file).
* Plugins: entry points of the group ``attitude_sil.laws`` (a contract, see
  docs/writing-a-law.md); each names a :class:`~attitude_sil.core.control.law.Law`
  or a module defining ``LAW``. A plugin is checked once per process, fully:
  as it is loaded, its defaults against its own table and its ``record`` on
  those defaults (:func:`plugin_fault`); before the first compiled dispatch
  table is built (:func:`dispatch_module`, the first time a process needs a
  law's compiled code), its step and bumpless entry compiled on that record.
  One that fails to load, breaks the contract, fails a check or reuses a
  taken name is skipped with one line on stderr naming the entry point, its
  distribution and the reason (the whole error with
  ``ATTITUDE_SIL_VERBOSE=1``); every other law, and every run that does not
  use it, works on.

:func:`dispatch_module` is the compiled dispatch table of the registered laws.
"""

from __future__ import annotations

import os
import pkgutil
import sys
from functools import lru_cache
from importlib.metadata import entry_points
from types import ModuleType

import numba
import numpy as np

from attitude_sil.core.control import compiled
from attitude_sil.core.control import laws as _builtin
from attitude_sil.core.control.law import Law, state_layout
from attitude_sil.core.control.shared import shared_defaults
from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.plugins import builtin_units, load_plugin, plugin_where
from attitude_sil.errors import ScenarioError

__all__ = ["ENTRY_POINT_GROUP", "laws", "get", "names", "declared_names", "builtin_names", "output_of",
           "parameter_table", "plugin_problems", "refresh", "dispatch_module", "plugin_fault", "compile_fault",
           "verbose"]

#: the entry-point group through which other packages add laws (a contract)
ENTRY_POINT_GROUP = "attitude_sil.laws"

_PROBLEMS: list[str] = []
#: each loaded plugin's entry-point description and its record for one episode, until its compile check has run
_UNCOMPILED: dict[str, tuple[str, tuple]] = {}
#: the skipped plugins' lines by law name, for an error that asks for one
_SKIPPED: dict[str, str] = {}


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
    _UNCOMPILED.clear()
    _SKIPPED.clear()


@lru_cache(maxsize=1)
def laws() -> dict[str, Law]:
    """Every law by name: the built-ins (by module name), then the plugins (by entry-point name)."""
    found: dict[str, Law] = {}
    for name, module in builtin_units(_builtin, "LAW"):
        law = _law_of(module, module.__name__)
        if law.name != name:
            raise TypeError(f"{module.__name__} defines the law {law.name!r}; a built-in law's module must carry "
                            "its name")
        found[law.name] = law
    for ep in _plugin_entry_points():
        where = plugin_where("law", ep)
        law, why = load_plugin(ep, where, _law_of)
        if why:
            _skip(why)
            continue
        if law.name in found:
            _skip(f"{where} is named {law.name!r}, which another law already has")
            continue
        if law.name != ep.name:
            _skip(f"{where} defines the law {law.name!r}; the entry point must carry the law's name")
            continue
        fault, record = plugin_fault(law)
        if fault:
            _skip(f"{where}: {fault}", name=law.name)
            continue
        found[law.name] = law
        _UNCOMPILED[law.name] = (where, record)
    return found


def verbose() -> bool:
    """Whether a skipped plugin's whole error is printed (``ATTITUDE_SIL_VERBOSE=1``)."""
    return os.environ.get("ATTITUDE_SIL_VERBOSE", "") not in ("", "0")


def _skip(line: str, detail: str = "", name: str = "") -> None:
    _PROBLEMS.append(line)
    if name:
        _SKIPPED[name] = line
    hint = "" if verbose() or not detail else " (ATTITUDE_SIL_VERBOSE=1 prints the whole error)"
    print(f"attitude-sil: {line}; skipped{hint}", file=sys.stderr)
    if detail and verbose():
        print(detail, file=sys.stderr)


#: the control period a plugin's record and step are checked with, s
_CHECK_DT = 0.01


def plugin_fault(law: Law) -> tuple[str, tuple | None]:
    """What keeps ``law`` from running, found without compiling: (one line, None), or ('', its record for one
    episode) for a law that passes.

    The checks, in order: each parameter's default passes its own table's
    rule; ``record(defaults, n, dt)`` returns a NamedTuple whose array fields
    have a leading axis of n (n = 1 and 2) and the same types both times, with
    ``u_max`` for a law that does not saturate itself. :func:`compile_fault`
    is the rest.
    """
    for spec in law.params:
        try:
            spec.validate(spec.default, f"controller.{law.name}")
        except ValueError as exc:
            return f"its default {exc}", None
    records = []
    for n in (1, 2):
        values = _Reads({**shared_defaults(), **{spec.name: spec.default for spec in law.params}})
        try:
            rec = law.record(values, n, _CHECK_DT)
        except Exception as exc:  # the plugin's own code: anything it raises is its fault, told in one line
            last = f" (on {law.name}.{values.last})" if values.last in {p.name for p in law.params} else ""
            return f"record(defaults, {n}, dt) raised {type(exc).__name__}{last}: {exc}", None
        fault = _record_fault(law, rec, n)
        if fault:
            return fault, None
        records.append(rec)
    if numba.typeof(records[0]) != numba.typeof(records[1]):
        return "record() gives a record of another type for 2 episodes than for 1", None
    return "", records[0]


class _Reads(dict):
    """The values a record is built from, remembering the last name read (the parameter a failure was on)."""

    last = ""

    def __getitem__(self, key):
        self.last = key
        return super().__getitem__(key)


def _record_fault(law: Law, rec, n: int) -> str:
    """What is wrong with a record built for n episodes ('' if nothing)."""
    if not (isinstance(rec, tuple) and hasattr(rec, "_fields")):
        return f"record() must return a NamedTuple of the law's parameters, got {type(rec).__name__}"
    for name, value in zip(rec._fields, rec, strict=True):
        if isinstance(value, np.ndarray):
            if value.ndim == 0 or value.shape[0] != n:
                return (f"record field {name!r} has shape {value.shape}; an array field needs a leading axis of "
                        f"the episodes ({n}, ...)")
        elif not isinstance(value, (bool, int, float, np.bool_, np.integer, np.floating)):
            return f"record field {name!r} is a {type(value).__name__}; a field is an array or a number"
    if not law.saturated and "u_max" not in rec._fields:
        return "record() needs a u_max field: the law does not saturate itself (saturated=False)"
    return ""


def compile_fault(law: Law, rec) -> tuple[str, str]:
    """What keeps the law's compiled code from building, as (one line, the whole error), or ('', ''): its
    controller-bank loops (``rows_0``, ``enter_0`` of a table of its own) compiled on ``rec``, one episode's."""
    table = compiled.table_for((law,))
    q = np.zeros((1, 4))
    q[:, 3] = 1.0
    w, u = np.zeros((1, 3)), np.zeros((1, 3))
    st = table.State_0(*(np.zeros((1, int(width)), dtype=dtype) for width, dtype in state_layout(law).values()))
    xfer = (np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1, dtype=np.bool_))
    loops = (("step", table.rows_0, (np.zeros(1, dtype=np.int64), q, w, q, w, rec, st, _CHECK_DT, u, xfer[1],
                                     xfer[2], 0.0)),
             ("bumpless entry", table.enter_0, (q, w, q, w, 0, rec, st, _CHECK_DT, 0.0, xfer, u)))
    for what, fn, args in loops:
        try:
            fn.compile(tuple(numba.typeof(a) for a in args))
        except Exception as exc:  # numba's typing and lowering errors: the plugin's code, not the package's
            return f"its {what} does not compile on its record: {_first_line(exc)}", f"{type(exc).__name__}: {exc}"
    return "", ""


def _first_line(exc: Exception) -> str:
    """The line of a numba error that says what went wrong, and where in the law's source when it says so."""
    lines = [x.strip() for x in str(exc).splitlines() if x.strip()]
    what = next((x for x in lines if not x.startswith(("Failed in", "During:", "File ", "^", "<source"))),
                lines[0] if lines else type(exc).__name__)
    where = next((x for x in lines if x.startswith("File ")), "")
    return f"{what} ({where})" if where else what


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
        skipped = f" ({_SKIPPED[name]})" if name in _SKIPPED else ""
        raise ScenarioError(f"unknown controller_type {name!r}{skipped}; known: {', '.join(names())}") from None


def output_of(name: str) -> str:
    """``command`` or ``torque``: what the law commands (:data:`attitude_sil.core.control.law.OUTPUTS`)."""
    return get(name).output


def dispatch_module() -> ModuleType:
    """The compiled dispatch table of the registered laws, in :func:`names` order (a law's code is its place).

    The first call compiles each plugin's own loops on its record
    (:func:`compile_fault`) and skips one that does not compile, before the
    table of the laws that remain is built.
    """
    found = laws()
    for name, (where, record) in list(_UNCOMPILED.items()):
        del _UNCOMPILED[name]
        fault, detail = compile_fault(found[name], record)
        if fault:
            del found[name]  # the registry's list, from now on without it
            _skip(f"{where}: {fault}", detail, name=name)
    return compiled.table_for(tuple(found.values()))


def parameter_table() -> list[ParamSpec]:
    """Every law's parameters with full names (``pid.kp``, ...), in registry order."""
    return [spec for law in laws().values() for spec in law.table()]
