"""What a control law is: the one unit a user writes to add a controller.

A law is a module that defines ``LAW = Law(...)``. Everything the package
does with a law (the controller node and its ROS parameters, ``run
--controller`` / ``--swap``, ``param set controller_type``, the stepwise and
compiled batch drivers, the tuner's genome check, Monte Carlo, ``replay
--verify-controller``, ``docs/parameters.md``) reads it through the registry
(:mod:`attitude_sil.core.control.registry`). The built-in laws live in
:mod:`attitude_sil.core.control.laws`; a law in another package registers
through the entry-point group ``attitude_sil.laws`` (docs/writing-a-law.md).

The compiled step
-----------------
``step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u)`` is a numba
function (``@njit(cache=True, inline="always")``) that computes row ``p``:
it reads row ``p`` of the inputs (``q_BN`` (n, 4), ``omega_BN_B`` (n, 3) rad/s,
``q_RN`` (n, 4), ``omega_RN_R`` (n, 3) rad/s in R), the law's parameter record
``par`` (a ``typing.NamedTuple`` of arrays with a leading episode axis, built
by ``record``), its state record ``st`` (a NamedTuple of (n, width) arrays laid
out by ``state``), advances row ``p`` of the state by one control period
``dt`` (s) and writes the command into ``u[p, 0:3]`` (V or N m, see
``output``). It allocates nothing and touches no Python object, so the
engine can inline it into its compiled loop and the node can call it with
n = 1: the same arithmetic everywhere, which is what makes graph == batch.
When every episode of a batch runs one law, the engine calls the step in a
loop over ``p`` with every array in column-major order (the episodes of a
column contiguous), and LLVM packs the episodes into SIMD lanes
(``vector_<code>``, :mod:`attitude_sil.core.control.compiled`): the author
writes the step once, for one row.

Bumpless entry
--------------
At a swap to this law the bank zeroes the law's state rows and, when the old
law commanded the same kind, calls ``enter(q_BN, omega_BN_B, q_RN, omega_RN_R,
p, par, st, dt, decay, u_last, offset)`` if the law has one: it sets the
state so the first command equals ``u_last[p]`` and writes any remainder into
``offset[p]``, returning True when that remainder must decay over the
following steps. A law without ``enter`` gets the generic transfer: its step
is evaluated once on fresh state (then the state is zeroed again) and the
difference to ``u_last`` decays by ``decay`` per step
(``bumpless_time_constant``).
"""

from __future__ import annotations

import keyword
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from attitude_sil.core.paramspec import ParamSpec

__all__ = ["Law", "OUTPUTS", "lanes", "state_layout"]

#: what a law commands: ``command`` follows the controller's ``command`` parameter
#: (volts for wheel presets, N m for torque presets); ``torque`` is always N m
OUTPUTS = ("command", "torque")

_FIELD = re.compile(r"[a-z][a-z0-9_]*")


@dataclass(frozen=True)
class Law:
    """One control law: its table, its state and its compiled step.

    Attributes
    ----------
    name : str
        ``controller_type`` value and parameter prefix (``pid`` -> ``pid.kp``), snake_case.
    summary : str
        One line: what the law is and where it comes from (paper, equation).
    params : tuple of ParamSpec
        The law's parameter table with names relative to the law (``kp``, not
        ``pid.kp``): type, default, range, run-time settable, one line of
        meaning with the unit. They become the controller node's ROS
        parameters ``<name>.<param>``.
    state : mapping str -> (int, dtype)
        The state layout: each field is an (n, width) array of that dtype,
        zero at an episode's start and at a swap to the law.
    record : callable
        ``record(values, n, dt) -> NamedTuple``: the parameter record for n
        episodes. ``values`` maps the law's parameter names (short) and the
        controller's shared ones (``output_limit``, ``error_mode``,
        ``orbit.mu``, ...) to values, each a scalar/list or an array with a
        leading axis of n (per-episode dispersions). Every ndarray field of
        the record has a leading axis of n; other fields are scalars.
    step : numba dispatcher
        The compiled step (module docstring).
    enter : numba dispatcher, optional
        Bumpless entry (module docstring); None: the generic decaying offset.
    output : str
        ``command`` or ``torque`` (:data:`OUTPUTS`).
    saturated : bool
        The step saturates its own output; False: the bank clips it to
        ``par.u_max`` after the transfer offset (the record must then have a
        ``u_max`` field).
    """

    name: str
    summary: str
    params: tuple[ParamSpec, ...]
    state: Mapping[str, tuple[int, Any]]
    record: Callable[[Mapping[str, Any], int, float], tuple]
    step: Any
    enter: Any = None
    output: str = "command"
    saturated: bool = True

    def __post_init__(self) -> None:
        problems = self.problems()
        if problems:
            raise ValueError(f"law {self.name!r}: {problems[0]}")

    def problems(self) -> list[str]:
        """What breaks the contract (empty when the law is well formed)."""
        out = []
        if not isinstance(self.name, str) or not _FIELD.fullmatch(self.name):
            out.append("name must be snake_case (letters, digits, underscores)")
        if self.output not in OUTPUTS:
            out.append(f"output must be one of {', '.join(OUTPUTS)}, got {self.output!r}")
        for spec in self.params:
            if not isinstance(spec, ParamSpec) or "." in spec.name or not _FIELD.fullmatch(spec.name):
                out.append(f"parameter {getattr(spec, 'name', spec)!r} must be a ParamSpec with a short snake_case "
                           "name (the registry adds the law's prefix)")
        for name, layout in self.state.items():
            if not _FIELD.fullmatch(name) or keyword.iskeyword(name):
                out.append(f"state field {name!r} must be a snake_case name")
            elif not (isinstance(layout, tuple) and len(layout) == 2 and int(layout[0]) >= 1):
                out.append(f"state field {name!r} must be (width >= 1, dtype)")
        for what in ("step", "enter"):
            fn = getattr(self, what)
            if fn is not None and not hasattr(fn, "py_func"):
                out.append(f"{what} must be a numba function (@njit(cache=True, inline='always'))")
        if self.step is None:
            out.append("step is required")
        return out

    def table(self) -> tuple[ParamSpec, ...]:
        """The parameter table with full names (``pid.kp``), as the controller node declares it."""
        return tuple(replace(s, name=f"{self.name}.{s.name}") for s in self.params)


def lanes(value: Any, n: int, tail: tuple[int, ...] = (3,), dtype: Any = float) -> np.ndarray:
    """``value`` as a new writable contiguous (n, *tail) array: a scalar, a (*tail) value or (n, *tail) rows.

    The helper every ``record`` uses to give each episode its own row. Always
    a fresh array: a read-only or broadcast view would be another numba type
    and compile the law's loops a second time.
    """
    a = np.asarray(value, dtype=dtype)
    out = np.empty((n, *tail), dtype=dtype)
    if a.shape == out.shape or a.size == 1:
        out[...] = a
        return out
    size = int(np.prod(tail))
    if a.size == size:
        out[...] = a.reshape(tail)
    elif a.size == n * size:
        out[...] = a.reshape(out.shape)
    else:
        raise ValueError(f"a value of shape {a.shape} fits neither {tail} nor ({n}, *{tail})")
    return out


def state_layout(law: Law) -> Mapping[str, tuple[int, Any]]:
    # a stateless law still gets a record (numba needs a type): one unused column
    return law.state or {"unused": (1, np.bool_)}
