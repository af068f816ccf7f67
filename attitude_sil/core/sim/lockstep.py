"""The lockstep protocol as plain code: step sequencing, hold, pacing, watchdog, autostart.

The graph advances in lockstep (docs/architecture.md, "Lockstep"): for step k
at t_k = k dt every message carries the stamp t_k; the plant publishes the
state of step k, waits for its inputs (wheel torque, wheel momentum,
disturbance torque) stamped t_k, integrates to t_k+1 and publishes again.
This module holds the decisions of that protocol, free of rclpy and of any
clock: every method takes the wall time ``now`` (s, monotonic) as an argument,
so the rules are unit-tested directly and the nodes only carry them out.

* :class:`StepSequencer` - what a downstream node does with a stamp
  (new episode, next step, duplicate, mismatch).
* :class:`StepInputs` - a node's inputs gathered by stamp until a step has
  them all.
* :class:`PlantLockstep` - the plant's episode: which input completes a step,
  when to publish, hold (``hold_at``), pace (``real_time_factor``), time out
  (``input_timeout``) and autostart; with a clock gate, ``/clock`` goes out
  only once the step's setpoints have (a flight computer on a sim-time timer).
* :class:`CommandHold` - the command the wheels apply each step when an
  outside flight computer runs on a timer of its own (``command_timing``
  ``sim_timer`` or ``wall``), not on the stamps of the lockstep.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np

__all__ = ["StepSequencer", "StepInputs", "PlantLockstep", "Action", "CommandHold", "COMMAND_TIMINGS",
           "command_period_ns", "is_tick", "tick_period_ns"]


class StepSequencer:
    """Tracks the step stamps a downstream node has handled.

    A stamp of 0 starts a new episode (a reset restarts the lockstep at 0;
    nothing else is taken before the first 0);
    the next stamp must be the last plus ``dt``; a repeat of the last stamp is
    a duplicate; an earlier stamp is stale (a late or foreign message). Stale
    and skipped stamps are mismatches the node refuses, so it never integrates
    with a stale or skipped input, and a stray old message cannot reset it.
    """

    NEW, NEXT, DUPLICATE, STALE, MISMATCH = "new", "next", "duplicate", "stale", "mismatch"

    def __init__(self) -> None:
        self.last_ns: int | None = None

    def classify(self, t_ns: int, dt_ns: int) -> str:
        """Classify stamp ``t_ns`` (ns) for a step of ``dt_ns`` (ns); NEW and NEXT are accepted."""
        last = self.last_ns
        if t_ns == 0:
            kind = self.NEW
        elif last is None:
            return self.MISMATCH  # an episode starts at stamp 0; anything else first is stray
        elif t_ns < last:
            return self.STALE
        elif t_ns == last:
            return self.DUPLICATE
        elif t_ns == last + dt_ns:
            kind = self.NEXT
        else:
            return self.MISMATCH
        self.last_ns = t_ns
        return kind


class StepInputs:
    """A node's inputs of each step, gathered by stamp until the step holds every one of ``names``.

    The first valid message of a step counts (as in the plant); once the node
    has taken a completed step (its stamp in sequence), :meth:`taken` drops
    anything older, which can never complete (a stray stamp completes nothing).
    """

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = tuple(names)
        self.pending: dict[int, dict[str, object]] = {}

    def add(self, name: str, t_ns: int, value) -> dict | None:
        """Hold ``value`` of input ``name`` for stamp ``t_ns``; return the step's inputs once it has them all."""
        slot = self.pending.setdefault(t_ns, {})
        slot.setdefault(name, value)
        if len(slot) < len(self.names):
            return None
        del self.pending[t_ns]
        return slot

    def taken(self, t_ns: int) -> None:
        """The step of stamp ``t_ns`` went through: drop what is older."""
        for stale in [s for s in self.pending if s < t_ns]:
            del self.pending[stale]


class Action(Enum):
    """What the plant node must do next."""

    NONE = "none"  #: nothing (wait for inputs or the pacing deadline)
    PUBLISH = "publish"  #: publish the state of the current step k
    ADVANCE = "advance"  #: every input of step k is in: integrate to k+1, then call :meth:`PlantLockstep.advanced`
    HOLD = "hold"  #: stopped before step k at ``hold_at``
    PACE = "pace"  #: publish at :attr:`PlantLockstep.publish_at` (wall s), then call :meth:`PlantLockstep.paced`
    CLOCK = "clock"  #: the clock gate opened: publish ``/clock`` of step k, then call :meth:`PlantLockstep.clocked`
    START = "start"  #: autostart: the graph is wired, start an episode
    REFUSED = "refused"  #: an input was refused (:attr:`PlantLockstep.refusal` says why); the step waits on
    FAIL = "fail"  #: the episode stopped; :attr:`PlantLockstep.error` says why


@dataclass
class PlantLockstep:
    """The plant's side of the lockstep, one episode at a time.

    Attributes
    ----------
    inputs_needed : tuple of str
        The inputs that complete a step (the plant node passes the topic
        contract's ``PLANT_INPUTS``).
    clock_gate : tuple of str
        Inputs stamped t_k that must arrive before ``/clock`` of step k goes
        out (empty: ``/clock`` goes with the state). The plant of a graph whose
        controller runs on a sim-time timer passes the setpoints: the timer
        fires when ``/clock`` reaches its tick, so every input of the tick
        must be out before it.
    n_steps : int
        K: the episode publishes steps 0..K.
    dt_ns : int
        Step, ns.
    k : int
        Current step; its state is published (or about to be).
    inputs : dict
        Inputs of step k received so far, ``name -> (3,)`` array.
    running, done, holding : bool
    error : str
        Why the episode stopped ('' while fine).
    publish_at : float or None
        Wall time (s) a paced step is due.
    """

    inputs_needed: tuple[str, ...] = ()
    clock_gate: tuple[str, ...] = ()
    n_steps: int = 0
    dt_ns: int = 1
    k: int = 0
    inputs: dict[str, np.ndarray] = field(default_factory=dict)
    running: bool = False
    done: bool = False
    holding: bool = False
    error: str = ""
    publish_at: float | None = None
    refusal: str = ""
    gate: dict[str, np.ndarray] = field(default_factory=dict)
    clock_out: bool = True
    episode_wall0: float = 0.0
    step_wall0: float = 0.0

    @property
    def t_ns(self) -> int:
        """Stamp of step k, ns."""
        return self.k * self.dt_ns

    def start(self, n_steps: int, dt_ns: int, now: float, hold_at: float) -> Action:
        """Begin an episode at step 0 (after a reset); returns PUBLISH or HOLD."""
        self.n_steps, self.dt_ns, self.k = int(n_steps), int(dt_ns), 0
        self.inputs = {}
        self.running, self.done, self.holding, self.error = True, False, False, ""
        self.publish_at = None
        self.episode_wall0 = now
        return self.finish_step(hold_at)

    def fail(self, reason: str) -> Action:
        """Stop the episode with ``reason`` (the first reason wins)."""
        if self.running:
            self.running = False
            self.error = reason
            return Action.FAIL
        return Action.NONE

    def offer(self, name: str, t_ns: int, value: np.ndarray) -> Action:
        """An input message arrived; returns ADVANCE when it completes step k, REFUSED or NONE.

        A stamp other than step k's (an earlier step or episode, or one ahead),
        a non-finite value, or a second message for an input already held is
        refused (:attr:`refusal` says why, naming the stamp expected) and the step waits
        for its producer's message: the plant never integrates with a
        mismatched input, and a stray message does not stop the run (a missing
        one does, at ``input_timeout``).
        """
        if not self.running and not (self.done and name in self.clock_gate):  # the last step's /clock still goes
            return Action.NONE
        if t_ns != self.t_ns:
            kind = "stale" if t_ns < self.t_ns else "ahead of the step"
            self.refusal = (f"plant: {name} stamped {t_ns * 1e-9:.6f} s refused ({kind}); expected "
                            f"{self.t_ns * 1e-9:.6f} s")
            return Action.REFUSED
        if not np.all(np.isfinite(value)):
            self.refusal = f"plant: {name} at t={t_ns * 1e-9:.6f} s is not finite: {np.ravel(value).tolist()}; refused"
            return Action.REFUSED
        if name in self.clock_gate:
            return self._open_gate(name, value)
        if name in self.inputs:
            if np.array_equal(self.inputs[name], value):
                return Action.NONE  # a repeat (an episode restarted at its first step): the same input
            self.refusal = f"plant: a second {name} for step t={t_ns * 1e-9:.6f} s; refused (the first is kept)"
            return Action.REFUSED
        self.inputs[name] = value
        return self._ready()

    def _ready(self) -> Action:
        """ADVANCE once step k has every input and its ``/clock`` is out."""
        if self.clock_out and len(self.inputs) == len(self.inputs_needed) and self.k < self.n_steps:
            return Action.ADVANCE
        return Action.NONE

    def _open_gate(self, name: str, value: np.ndarray) -> Action:
        """A gate input of step k: CLOCK once the gate has them all (a repeat changes nothing)."""
        if name in self.gate:
            return Action.NONE
        self.gate[name] = value
        if not self.clock_out and len(self.gate) == len(self.clock_gate):
            return Action.CLOCK
        return Action.NONE

    def clocked(self) -> Action:
        """``/clock`` of step k went out; returns ADVANCE if the step's inputs are in already, else NONE."""
        self.clock_out = True
        return self._ready()

    def advanced(self, state_finite: bool, now: float, real_time_factor: float, hold_at: float) -> Action:
        """The body was integrated to step k+1; returns FAIL, PACE, PUBLISH or HOLD."""
        self.inputs = {}
        self.k += 1
        if not state_finite:
            return self.fail(f"plant: state diverged at t={self.t_ns * 1e-9:.6f} s")
        if real_time_factor > 0.0:
            due = self.episode_wall0 + self.t_ns * 1e-9 / real_time_factor
            if due > now:
                self.publish_at = due
                return Action.PACE
        return self.finish_step(hold_at)

    def paced(self, hold_at: float) -> Action:
        """The pacing deadline passed; returns PUBLISH, HOLD or NONE (episode stopped meanwhile)."""
        self.publish_at = None
        return self.finish_step(hold_at) if self.running else Action.NONE

    def finish_step(self, hold_at: float) -> Action:
        """Publish step k unless ``hold_at`` (s, < 0: never) stops the plant before it."""
        if hold_at >= 0.0 and self.t_ns >= round(hold_at * 1e9):
            self.holding = True
            return Action.HOLD
        return Action.PUBLISH

    def published(self, now: float) -> bool:
        """The state of step k went out (its ``/clock`` too, unless a clock gate holds it); returns True when
        that was the last step."""
        self.step_wall0 = now
        self.gate = {}
        self.clock_out = not self.clock_gate
        if self.n_steps > 0 and self.k >= self.n_steps:
            self.running = False
            self.done = True
            return True
        return False

    def release(self, hold_at: float, now: float) -> Action:
        """``hold_at`` changed; returns PUBLISH (or HOLD again) if the plant was holding, else NONE."""
        if not (self.holding and self.running):
            return Action.NONE
        if hold_at < 0.0 or self.t_ns < round(hold_at * 1e9):
            self.holding = False
            self.step_wall0 = now
            return self.finish_step(hold_at)
        return Action.NONE

    def watchdog(self, now: float, input_timeout: float, autostart: bool, wired: bool) -> Action:
        """Periodic check: START an idle wired graph with ``autostart``; FAIL a step whose inputs are late."""
        if not self.running and not self.done and not self.error and autostart and wired:
            return Action.START
        if self.running and self.publish_at is None and not self.holding and now - self.step_wall0 > input_timeout:
            missing = [n for n in self.inputs_needed if n not in self.inputs]
            if not self.clock_out:  # /clock waits for the gate: what it waits for comes first
                missing = [n for n in self.clock_gate if n not in self.gate] + missing
            return self.fail(f"plant: no {', '.join(missing)} for step t={self.t_ns * 1e-9:.6f} s "
                             f"within {input_timeout:g} s; episode stopped")
        return Action.NONE


#: how the wheels take the controller's command (the wheels' and the plant's ``command_timing``)
COMMAND_TIMINGS = ("stamped", "sim_timer", "wall")


class CommandHold:
    """The command the wheels apply over each step, for a controller on a timer of its own.

    ``stamped`` (the lockstep of the contract) needs none of this: each step's
    command carries the step's stamp. The other two take flight software as
    it is written, a node that caches its inputs and computes on
    ``create_timer``, stamping with its clock's ``now()``:

    * ``sim_timer`` - the node runs on sim time with period T (a multiple of
      the step dt). Its tick j fires when ``/clock`` reaches t_j = j T
      (j >= 1: an rcl timer first fires one period after it starts) and its
      command, stamped t_j, is applied over [t_j + T, t_j + 2 T): logical
      execution time (Kirsch and Sokolova, "The Logical Execution Time
      Paradigm", 2012), a one-period computation delay whatever the node's
      real computing time, so a run is deterministic. Before the first
      tick's command takes effect the command is zero. The wheels wait, at
      each step that is a tick, for that tick's command (:meth:`waits_at`):
      nothing of the next step is published before the node has computed.
    * ``wall`` - the node runs on the wall clock; the newest command received
      is applied, whatever its stamp (sample and hold).

    Parameters
    ----------
    timing : str
        ``sim_timer`` or ``wall``.
    period_ns : int
        T, ns (``sim_timer``; a ``wall`` hold has no ticks, whatever it is).
    zero : (value, torque_mode)
        The command before any takes effect: a (1, 3) zero and its kind.
    """

    def __init__(self, timing: str, period_ns: int, zero: tuple[np.ndarray, bool]) -> None:
        self.timing = timing
        self.period_ns = int(period_ns)
        self.zero = zero
        self.ticks: dict[int, tuple[np.ndarray, bool]] = {}  # sim_timer: tick stamp (ns) -> its command
        self.newest = zero  # wall: the newest command received

    def is_tick(self, t_ns: int) -> bool:
        """``sim_timer``: the node's timer fires at sim time ``t_ns`` (ns)."""
        return self.timing == "sim_timer" and is_tick(t_ns, self.period_ns)

    def next_tick(self, t_ns: int) -> int:
        """The first tick at or after sim time ``t_ns`` (ns): the stamp a command is expected with."""
        return max(-(-t_ns // self.period_ns), 1) * self.period_ns

    def waits_at(self, t_ns: int) -> bool:
        """The step at ``t_ns`` (ns) is a tick whose command has not come yet: the wheels wait for it."""
        return self.is_tick(t_ns) and t_ns not in self.ticks

    def replays_start(self, clock_ns: int, previous_ns: int | None) -> bool:
        """``/clock`` ``clock_ns`` (ns) is the plant sending the episode's start again, not a new episode.

        A plant whose first tick stays unanswered sends ``/clock`` 0 again among the tick's own
        (``PlantNode._resend_clock``): a timer that missed the jump back to 0 took its phase from a later time.
        That 0 comes right after a ``/clock`` of the first tick (``previous_ns``, the ``/clock`` before it),
        whether these wheels have the tick's command or not (the plant may wait for another input). A new
        episode's 0 after the first tick (its plant reset there) is sent again by the plant 0.5 s later, and the
        second 0 in a row is taken as one.
        """
        return self.timing == "sim_timer" and clock_ns == 0 and previous_ns == self.period_ns

    def offer(self, t_ns: int, value: np.ndarray, torque_mode: bool, latest_ns: int | None) -> str:
        """A command stamped ``t_ns`` (ns) came; ``latest_ns`` is the latest stamp one may carry (the step whose
        ``/clock`` is out: a tick's command may overtake that ``/clock`` on its way to the wheels; None: no
        episode yet). Returns '' if taken, else why it is refused (a later stamp: a stray of an earlier episode,
        which must not take a tick's place)."""
        if self.timing == "wall":
            self.newest = (value, torque_mode)
            return ""
        if not self.is_tick(t_ns):
            return f"not a tick of the controller's period {self.period_ns * 1e-9:g} s"
        if latest_ns is not None and t_ns > latest_ns:
            return "ahead of the clock"
        held = self.ticks.setdefault(t_ns, (value, torque_mode))  # a repeat of a tick answered changes nothing
        if held[0] is not value and not np.array_equal(held[0], value):
            return ("a second, different command for a tick already answered (the first is kept): the node ticked "
                    "twice there, its law stepped twice, and the run is not reproducible")
        return ""

    def applied(self, t_ns: int) -> tuple[np.ndarray, bool]:
        """The command (value, torque_mode) held over the step at ``t_ns`` (ns)."""
        if self.timing == "wall":
            return self.newest
        tick = (t_ns // self.period_ns - 1) * self.period_ns  # the tick whose command takes effect at t_ns
        for old in [s for s in self.ticks if s < tick]:
            del self.ticks[old]
        return self.ticks.get(tick, self.zero)


def is_tick(t_ns: int, period_ns: int) -> bool:
    """A timer of period ``period_ns`` started at sim time 0 fires at ``t_ns`` (ns): a whole number of periods after
    0 (an rcl timer first fires one period after it starts); ``period_ns`` 0: no timer, no tick."""
    return period_ns > 0 and t_ns > 0 and t_ns % period_ns == 0


def tick_period_ns(timing: str, rate_hz: float, dt_ns: int) -> int:
    """The period (ns) of the ticks a node must serve for a controller of ``command_timing`` ``timing``: its
    sim-time timer's (:func:`command_period_ns`) with ``sim_timer``, else 0 (no ticks)."""
    return command_period_ns(rate_hz, dt_ns) if timing == "sim_timer" else 0


def command_period_ns(rate_hz: float, dt_ns: int) -> int:
    """The period (ns) of a controller's sim-time timer at ``rate_hz`` (0: one step ``dt_ns``), a whole number of
    steps: the timer fires at its ticks only if they are steps of the plant.

    Raises
    ------
    ValueError
        A rate whose period is not a whole number of steps (to a thousandth of a nanosecond: a period a
        nanosecond off would never meet a step).
    """
    if rate_hz == 0.0:
        return int(dt_ns)
    period = 1e9 / rate_hz
    steps = round(period / dt_ns)
    if steps < 1 or abs(period - steps * dt_ns) > 1e-3:
        raise ValueError(f"a controller rate of {rate_hz:g} Hz has a period of {period * 1e-9:g} s, not a whole "
                         f"number of control periods ({dt_ns * 1e-9:g} s)")
    return int(steps * dt_ns)
