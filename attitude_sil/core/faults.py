"""The fault model: what a scenario's ``faults`` list says, checked in one place for every driver.

A fault is one line, the words of ``attitude-sil fault`` with a time::

    TARGET MODE [VALUE] [at T] [for D]

e.g. ``wheel1 stuck at 2``, ``wheel3 lost at 5.5``. ``at`` is the sim time
(s) the fault becomes active (the first step at or after it; default 0),
``for`` how long it lasts (s; default: to the end of the run). The list is
a ROS ``string[]`` parameter, ``faults``, so a scenario stays a ROS 2
parameter file that ``ros2 launch`` hands to the nodes unchanged (a
parameter cannot be a list of mappings); set it under ``/**`` and each node
takes the faults of its own targets.

:data:`CATALOGUE` lists every target and the modes it can take (issue 43's
table), every one flown by every driver. A mode a target cannot take is
refused in one line, never accepted in silence. Today's ``wheels.failure.*`` keys are the fault
``wheel<n> <mode> at <time>`` (:func:`legacy_wheel_fault`), flown the same.
The steps a fault is active in (:func:`fault_steps`) and a device's ``off``
and ``stuck`` (:class:`HeldFaults`) are computed here too, once for every
model that flies them.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from attitude_sil.errors import ScenarioError

#: target kind -> the modes it can take (a VALUE is needed where the mode names a size)
CATALOGUE: dict[str, tuple[str, ...]] = {
    "wheel": ("lost", "stuck", "friction", "torque_limit", "speed_limit"),
    "gyro": ("off", "stuck", "bias_jump", "scale", "spike"),
    "star_tracker": ("off", "stuck", "latency"),
    "magnetometer": ("off", "stuck"),
    "magnetorquers": ("off", "stuck"),
    "controller": ("gain", "delay"),
}
#: target kind -> the node that flies its faults and publishes them on /diagnostics
OWNER: dict[str, str] = {"wheel": "wheels", "gyro": "sensors", "star_tracker": "sensors", "magnetometer": "sensors",
                         "magnetorquers": "magnetorquers", "controller": "wheels"}
#: the nodes that declare the ``faults`` list today
FAULT_NODES = ("wheels", "sensors", "magnetorquers")
#: target kinds that need the sensing loop (scenario.sensors)
SENSED = frozenset({"gyro", "star_tracker", "magnetometer"})
#: modes that last once they happen (a wheel that seized stays seized): no ``for``
PERMANENT = frozenset({("wheel", "lost"), ("wheel", "stuck"), ("wheel", "torque_limit"), ("wheel", "speed_limit"),
                       ("wheel", "friction")})
#: modes whose VALUE is a size (a gain, a factor, a limit, a time)
VALUED = frozenset({"friction", "torque_limit", "speed_limit", "bias_jump", "scale", "spike", "latency", "gain",
                    "delay"})
#: modes whose VALUE must be positive (a time or a limit), or at least 0 (a gain: 0 opens the loop)
POSITIVE = frozenset({"delay", "latency", "torque_limit", "speed_limit"})
NON_NEGATIVE = frozenset({"gain", "friction"})

_TARGET = re.compile(r"^(wheel)([1-9][0-9]*)$|^(gyro)\.([xyz])$|^(star_tracker|magnetometer|magnetorquers|controller)$")


@dataclass(frozen=True)
class Fault:
    """One fault of a scenario's ``faults`` list.

    Attributes
    ----------
    kind : str
        Target kind, a key of :data:`CATALOGUE` (``wheel``, ``gyro``, ...).
    index : int or str or None
        Which one: the wheel number (1-based), the gyro axis (``x``, ``y``,
        ``z``), None for a target of its own.
    mode : str
        What goes wrong (:data:`CATALOGUE`).
    value : float or None
        Its size, where the mode has one (:data:`VALUED`).
    time_s : float
        Sim time it becomes active, s.
    duration_s : float or None
        How long it lasts, s (None: to the end).
    """

    kind: str
    index: int | str | None
    mode: str
    value: float | None
    time_s: float
    duration_s: float | None = None

    @property
    def target(self) -> str:
        """The target as written: ``wheel1``, ``gyro.x``, ``star_tracker``."""
        if self.kind == "wheel":
            return f"wheel{self.index}"
        return f"gyro.{self.index}" if self.kind == "gyro" else self.kind

    def __str__(self) -> str:
        words = [self.target, self.mode] + ([] if self.value is None else [f"{self.value:g}"])
        words += ["at", f"{self.time_s:g}"] + ([] if self.duration_s is None else ["for", f"{self.duration_s:g}"])
        return " ".join(words)


def parse_fault(text: str) -> Fault:
    """A :class:`Fault` from its line ``TARGET MODE [VALUE] [at T] [for D]``.

    Raises
    ------
    ScenarioError
        One line naming what is wrong: an unknown target, a mode the target
        cannot take, a missing or needless value,
        a negative or non-finite time.
    """
    words = str(text).split()
    where = f"fault {text!r}"
    if len(words) < 2:
        raise ScenarioError(f"{where}: expected TARGET MODE [VALUE] [at T] [for D], e.g. 'wheel1 stuck at 2'")
    m = _TARGET.match(words[0])
    if m is None:
        raise ScenarioError(f"{where}: unknown target {words[0]!r} (targets: wheel<n>, gyro.x|y|z, star_tracker, "
                            "magnetometer, magnetorquers, controller)")
    kind = m.group(1) or m.group(3) or m.group(5)
    index = int(m.group(2)) if m.group(2) else m.group(4)
    mode = words[1]
    if mode not in CATALOGUE[kind]:
        raise ScenarioError(f"{where}: a {kind} cannot be {mode!r} (its modes: {', '.join(CATALOGUE[kind])})")
    rest = words[2:]
    value = None
    if mode in VALUED:
        if not rest or rest[0] in ("at", "for"):
            raise ScenarioError(f"{where}: {mode} needs a value, e.g. '{words[0]} {mode} 2 at 5'")
        value = _number(rest.pop(0), where, "value")
        if (mode in POSITIVE and value <= 0.0) or (mode in NON_NEGATIVE and value < 0.0):
            raise ScenarioError(f"{where}: a {mode} must be {'>' if mode in POSITIVE else '>='} 0, got {value:g}")
    times = {"at": 0.0, "for": None}
    while rest:
        word = rest.pop(0)
        if word not in times or not rest:
            raise ScenarioError(f"{where}: unexpected {word!r}; expected 'at T' or 'for D' after the mode")
        times[word] = _number(rest.pop(0), where, word)
        if times[word] < 0.0 or (word == "for" and times[word] == 0.0):
            raise ScenarioError(f"{where}: '{word}' must be {'>' if word == 'for' else '>='} 0 s, got "
                                f"{times[word]:g}")
    if times["for"] is not None and (kind, mode) in PERMANENT:
        raise ScenarioError(f"{where}: a {kind} {mode} lasts to the end of the run; drop 'for'")
    return Fault(kind, index, mode, value, times["at"], times["for"])


def _number(word: str, where: str, what: str) -> float:
    try:
        x = float(word)
    except ValueError:
        raise ScenarioError(f"{where}: {what} {word!r} is not a number") from None
    if not math.isfinite(x):
        raise ScenarioError(f"{where}: {what} must be finite, got {word}")
    return x


def outage_windows(values: dict) -> list[tuple[float, float]]:
    """The star tracker's ``off`` faults of the ``sensors`` parameters ``values`` as outage windows
    [start, end) of exposure time, s (end: infinity for one that lasts)."""
    return [(f.time_s, math.inf if f.duration_s is None else f.time_s + f.duration_s)
            for f in faults_of(values, "sensors") if f.kind == "star_tracker" and f.mode == "off"]


def parse_faults(lines, duration_s: float, n_wheels: int | None, sensing: bool = True,
                 rods: bool = True) -> list[Fault]:
    """Every fault of a ``faults`` list, checked against the run: each starts within it (0 <= T <= the
    duration, when the run has one: ``duration_s`` > 0), a wheel is one of the geometry's (``n_wheels``;
    None: no reaction wheels to fail), at most one wheel fails in a run (the drivers' failure record
    holds one), and a sensor fails only where the sensing loop runs (``sensing``).

    Raises
    ------
    ScenarioError
        One line for the first fault that cannot fly.
    """
    faults = [parse_fault(line) for line in lines]
    for f in faults:
        if duration_s > 0.0 and f.time_s > duration_s:
            raise ScenarioError(f"fault '{f}': at {f.time_s:g} s is after the run's end ({duration_s:g} s)")
        if f.kind in SENSED and not sensing:
            raise ScenarioError(f"fault '{f}': a {f.kind} fault needs the sensing loop (scenario.sensors true)")
        if f.kind == "magnetorquers" and not rods:
            raise ScenarioError(f"fault '{f}': the magnetorquers do not fly in this run (controller momentum.mode, "
                                "or bdot among its laws)")
        if f.kind == "wheel":
            if n_wheels is None:
                raise ScenarioError(f"fault '{f}': a wheel fault needs wheels.actuator reaction_wheels")
            if not 1 <= f.index <= n_wheels:
                raise ScenarioError(f"fault '{f}': the geometry has wheels 1..{n_wheels}")
        if f.kind == "controller" and n_wheels is None:
            raise ScenarioError(f"fault '{f}': a controller output fault acts on the reaction wheels' command "
                                "(wheels.actuator reaction_wheels)")
    for what, same in (("one wheel fault", lambda f: f.kind == "wheel"),
                       ("one controller gain", lambda f: (f.kind, f.mode) == ("controller", "gain")),
                       ("one controller delay", lambda f: (f.kind, f.mode) == ("controller", "delay"))):
        twice = [f for f in faults if same(f)]
        if len(twice) > 1:
            raise ScenarioError(f"faults: '{twice[0]}' and '{twice[1]}': {what} per run for now")
    return faults


def foreign_line(lines, node: str) -> str:
    """The first of ``lines`` whose target ``node`` does not fly (:data:`OWNER`), as a refusal; '' if none.
    A list under ``/**`` reaches every node, each flying its own; one set on a node alone must be its own."""
    for line in lines:
        owner = OWNER[parse_fault(line).kind]
        if owner != node:
            return (f"fault {line!r} is flown by the {owner} node, not the {node}: set it there "
                    "(attitude-sil fault does)")
    return ""


def faults_rule(lines) -> str:
    """The ``faults`` parameter's rule: '' if every line parses, else the first line's problem."""
    try:
        for line in lines:
            parse_fault(line)
    except ScenarioError as exc:
        return f"holds {exc}"
    return ""


def legacy_wheel_fault(wheel: int, time_s: float, mode: str, limit: float = 0.0) -> Fault | None:
    """Today's ``wheels.failure.*`` keys as the fault they are (None: ``failure.wheel`` 0, no failure)."""
    return None if wheel == 0 else Fault("wheel", int(wheel), str(mode), None if mode in ("lost", "stuck") else
                                         float(limit), float(time_s))


def wheel_failure_values(w: dict) -> dict:
    """The ``failure.*`` values of the ``wheels`` parameters ``w`` with its ``faults`` list's wheel fault laid
    over them: the drivers' one failure record (:class:`~attitude_sil.core.plant.kernels.WheelFailure`).

    Raises
    ------
    ScenarioError
        The list has a wheel fault and ``failure.wheel`` names one too.
    """
    fault = next((f for f in map(parse_fault, w["faults"]) if f.kind == "wheel"), None)
    if fault is None:
        return {}
    legacy = legacy_wheel_fault(w["failure.wheel"], w["failure.time"], w["failure.mode"], w["failure.value"])
    if legacy is not None:
        raise ScenarioError(f"fault '{fault}' and wheels.failure ('{legacy}'): one wheel fault per run; "
                            "say it in faults")
    return {"failure.wheel": fault.index, "failure.time": fault.time_s, "failure.mode": fault.mode,
            "failure.value": 0.0 if fault.value is None else fault.value}


def faults_of(values: dict, node: str) -> list[Fault]:
    """The faults ``node`` flies (its targets', :data:`OWNER`) from its parameters ``values``, in list order:
    its ``faults`` list's, and the wheel fault of the ``failure.*`` keys where it has them."""
    out = [f for f in map(parse_fault, values.get("faults", ())) if OWNER[f.kind] == node]
    if "failure.wheel" in values:
        legacy = legacy_wheel_fault(values["failure.wheel"], values["failure.time"], values["failure.mode"],
                                    values["failure.value"])
        out += [] if legacy is None else [legacy]
    return out


def first_step(time_s: float, dt_ns: int) -> int:
    """The first step (index) at or after sim time ``time_s`` (s) for steps of ``dt_ns`` (ns): where a fault
    starts or ends."""
    t_ns = int(round(time_s * 1e9))
    return t_ns // dt_ns + (t_ns % dt_ns > 0)


#: a step index no run reaches: the end of a fault that lasts
NEVER = int(np.iinfo(np.int64).max)


def fault_steps(fault: Fault, dt_ns: int, start: int | None = None) -> tuple[int, int]:
    """The steps [start, end) a fault is active in (steps of ``dt_ns`` ns; end :data:`NEVER` for one that
    lasts): from its time, or from step ``start`` where it was added while a run went, for its duration."""
    t_s = fault.time_s if start is None else start * dt_ns * 1e-9
    first = first_step(t_s, dt_ns)
    return first, NEVER if fault.duration_s is None else first_step(t_s + fault.duration_s, dt_ns)


class HeldFaults:
    """The ``off`` and ``stuck`` faults of a device's whole output (a magnetometer's reading, the rods' dipole):
    while one is active the output is 0 (``off``) or the output of the step before it (``stuck``)."""

    def __init__(self) -> None:
        self.windows: list[tuple[str, int, int]] = []  # (off or stuck, first step, end step)
        self._last = None  # the output of the step before (P, 3)
        self._held: dict[int, np.ndarray] = {}  # a stuck fault's output, by its first step

    def __bool__(self) -> bool:
        return bool(self.windows)

    def add(self, fault: Fault, dt_ns: int, start: int | None = None) -> None:
        """``fault`` (off or stuck) from its time, or from step ``start``, for its duration."""
        self.windows.append((fault.mode, *fault_steps(fault, dt_ns, start)))

    def apply(self, x: np.ndarray, k: int) -> np.ndarray:
        """The output at step ``k`` for the device's own ``x`` (P, 3)."""
        for mode, first, end in self.windows:
            if first <= k < end:
                x = np.zeros_like(x) if mode == "off" else self._held.setdefault(
                    first, x if self._last is None else self._last)
        self._last = x
        return x


def changes_at(faults: list[Fault], k: int, dt_ns: int) -> list[tuple[Fault, bool]]:
    """The faults that become active (True) or end (False) at step ``k`` (steps of ``dt_ns`` ns)."""
    out = []
    for f in faults:
        start, end = fault_steps(f, dt_ns)
        if end == start:  # between two steps: no step sees it, so nothing happens and nothing is said
            continue
        if start == k:
            out.append((f, True))
        elif end == k:
            out.append((f, False))
    return out


def added_faults(before, after) -> list[str]:
    """The lines a change of a running node's ``faults`` list adds (``before`` -> ``after``): faults may be
    added while a graph runs, not taken back or changed (what happened, happened).

    Raises
    ------
    ScenarioError
        A line of ``before`` is not where it was in ``after``.
    """
    before, after = list(before), list(after)
    gone = [line for i, line in enumerate(before) if i >= len(after) or after[i] != line]
    if gone:
        raise ScenarioError(f"faults may be added while the graph runs, not taken back or changed: {gone[0]!r} "
                            "is gone")
    return after[len(before):]
