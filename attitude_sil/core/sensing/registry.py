"""The one list of attitude estimators: the built-ins and those other packages register.

Every part of the package that builds a filter asks here: the ``estimator``
node, the stepwise driver (and so tune, montecarlo and replay) and the
``estimator`` parameter table (``type`` and each filter's own parameters).

* Built-ins: every module of :mod:`attitude_sil.core.sensing.estimators` that
  defines ``ESTIMATOR``, found by itself (adding one is adding a file).
* Plugins: entry points of the group ``attitude_sil.estimators`` (a contract,
  docs/sensors.md), each naming an :class:`~attitude_sil.core.sensing.estimator.Estimator`
  or a module defining ``ESTIMATOR``. A plugin is checked as it is loaded: its
  parameters' defaults against their own rules, then built on them for 1 and
  2 episodes (with a ``dropped`` count and ``set_star_tracker_variance``) and
  stepped twice (a gyro reading, then a report), each estimate of the right
  shapes and finite. One that fails to load, fails a check or
  reuses a taken name is skipped with one line on stderr naming the entry
  point, its distribution and the reason; every other filter works on.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from functools import lru_cache
from importlib.metadata import entry_points
from types import ModuleType

import numpy as np

from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.plugins import builtin_units, load_plugin, plugin_where
from attitude_sil.core.sensing import estimators as _builtin
from attitude_sil.core.sensing.estimator import Estimator
from attitude_sil.core.sensing.models import StarTrackerReport
from attitude_sil.errors import ScenarioError

__all__ = ["ENTRY_POINT_GROUP", "estimators", "get", "names", "builtin_names", "unknown", "parameter_table",
           "plugin_fault", "refresh", "build_filter", "report_reach"]

#: the entry-point group through which other packages add estimators (a contract)
ENTRY_POINT_GROUP = "attitude_sil.estimators"


def _estimator_of(obj, where: str) -> Estimator:
    est = getattr(obj, "ESTIMATOR", obj) if isinstance(obj, ModuleType) else obj
    if not isinstance(est, Estimator):
        raise TypeError(f"{where} is not an Estimator (nor a module defining ESTIMATOR)")
    return est


def refresh() -> None:
    """Read the built-ins and the entry points again on next use (a plugin installed while this process runs)."""
    estimators.cache_clear()


@lru_cache(maxsize=1)
def estimators() -> dict[str, Estimator]:
    """Every estimator by name: the built-ins (by module name), then the plugins (by entry-point name)."""
    found = {name: _estimator_of(module, module.__name__) for name, module in builtin_units(_builtin, "ESTIMATOR")}
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        where = plugin_where("estimator", ep)
        est, why = load_plugin(ep, where, _estimator_of)
        if why:
            _skip(why)
            continue
        if est.name in found or est.name != ep.name:
            _skip(f"{where} is named {est.name!r}: " + ("another estimator has that name" if est.name in found
                                                       else "the entry point must carry the estimator's name"))
            continue
        fault = plugin_fault(est)
        if fault:
            _skip(f"{where}: {fault}")
            continue
        found[est.name] = est
    return found


def _skip(line: str) -> None:
    print(f"attitude-sil: {line}; skipped", file=sys.stderr)


def builtin_names() -> tuple[str, ...]:
    """The built-in estimators' names (the modules of :mod:`attitude_sil.core.sensing.estimators`)."""
    modules = {name for name, _ in builtin_units(_builtin, "ESTIMATOR")}
    return tuple(n for n in estimators() if n in modules)


def names() -> tuple[str, ...]:
    """The names ``estimator.type`` takes."""
    return tuple(estimators())


def unknown(name: str) -> str:
    """'' if ``name`` is an estimator, else the rule it breaks (the parameter ``type``'s check)."""
    return "" if name in estimators() else f"must name an estimator ({', '.join(estimators())}), got {name!r}"


def get(name: str) -> Estimator:
    """The estimator ``name``, or ScenarioError naming the ones there are."""
    if unknown(name):
        raise ScenarioError(f"estimator.type {unknown(name)}")
    return estimators()[name]


def parameter_table() -> list[ParamSpec]:
    """Every estimator's own parameters as the ``estimator`` node declares them (``<name>.<param>``)."""
    return [replace(s, name=f"{e.name}.{s.name}") for e in estimators().values() for s in e.params]


def report_reach(estimator: dict, latency_steps: int, dt: float) -> int:
    """How many steps back the filter takes a star tracker report: ``star_tracker.max_age_s`` of the
    ``estimator`` parameters in whole steps, at least the tracker's latency ``latency_steps``."""
    return max(int(latency_steps), int(np.floor(estimator["star_tracker.max_age_s"] / dt + 1e-9)))


def build_filter(values: dict, gyro_arw: float, star_tracker_sigma, dt: float, n_episodes: int,
                 latency_steps: int):
    """The filter ``values["type"]`` selects, built from the ``estimator`` parameters ``values`` (the selected
    filter's own under ``<type>.``, handed to it without the prefix), for a tracker of ``latency_steps``: it
    keeps reports as far back as :func:`report_reach`."""
    est = get(values["type"])
    own = {s.name: values.get(f"{est.name}.{s.name}", s.default) for s in est.params}
    return est.build({**values, **own}, float(gyro_arw), np.asarray(star_tracker_sigma, dtype=float), float(dt),
                     int(n_episodes), report_reach(values, latency_steps, dt))


#: the common parameters a plugin is checked with (the estimator node's defaults)
_CHECK_VALUES = {"initial_attitude_rpy_deg": [0.0, 0.0, 0.0], "initial_attitude_sigma_deg": 1.0,
                 "initial_bias_sigma_deg_h": 1.0, "bias_walk_deg_h_rt_h": 0.01, "star_tracker.rate_hz": 4.0,
                 "star_tracker.latency_s": 0.0, "star_tracker.max_age_s": 0.0, "control_period": 0.01}


def plugin_fault(est: Estimator) -> str:
    """What keeps ``est`` from flying ('' if nothing): a default that breaks its own rule, or a filter that
    does not build and step on the defaults (1 and 2 episodes) to estimates of the right shapes, finite."""
    for spec in est.params:
        if spec.name in _CHECK_VALUES or spec.name == "type":
            return f"its parameter {spec.name!r} has the name of one every filter reads"
        try:
            spec.validate(spec.default, f"estimator.{est.name}")
        except ValueError as exc:
            return f"its default {exc}"
    values = {**_CHECK_VALUES, **{s.name: s.default for s in est.params}}
    for n in (1, 2):
        try:
            filt = est.build(values, 1e-6, np.full(3, 1e-5), 0.01, n, 0)
            if not isinstance(getattr(filt, "dropped", None), (int, np.integer)) or not callable(
                    getattr(filt, "set_star_tracker_variance", None)):
                return "the filter it builds needs a count 'dropped' and set_star_tracker_variance(variance)"
            filt.set_star_tracker_variance(np.full(3, 1e-10))
            filt.step(0, np.zeros((n, 3)))
            q = np.zeros((n, 4))
            q[:, 3] = 1.0
            out = filt.step(1, np.full((n, 3), 1e-3), StarTrackerReport(1, q, True))
        except Exception as exc:  # the plugin's own code: anything it raises is its fault, told in one line
            return f"building and stepping it on its defaults ({n} episodes) raised {type(exc).__name__}: {exc}"
        for field, shape in (("q_BN", (n, 4)), ("omega_BN_B", (n, 3)), ("gyro_bias", (n, 3)),
                             ("attitude_sigma", (n, 3)), ("cov", (n, 6, 6))):
            value = np.asarray(getattr(out, field, None), dtype=float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                return f"its estimate's {field} is {value.shape}, not finite {shape}, on its defaults ({n} episodes)"
    return ""
