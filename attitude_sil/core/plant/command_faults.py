"""The controller output's faults: a gain and a delay between the law's command and the actuators.

Issue 43's ``controller gain K`` and ``controller delay D`` (the stability-margin
tests of 42's ``LoopGain`` and ``LoopDelay``) act on the body-axis command the
wheels take, whoever computed it: the package's law or a user's flight
software. The command the law sent stays what the bag records on
``voltage_cmd`` (or ``torque_cmd``); the wheels apply

    v_applied[k] = g[k] * u[k - d[k]],

with ``g[k]`` the gain while its fault is active (1 otherwise) and ``d[k]`` the
delay in control steps while its fault is active (0 otherwise). A command from
before the record began is the one applied before it (zero at the start of a
run, the last command for a delay injected while the graph runs).

One row kernel, :func:`command_fault_row`, is the stage in every driver: the
wheels model of the nodes and of the stepwise driver calls it on its (P, 3)
command (:func:`command_fault_rows`), the compiled loop per episode row.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.faults import NEVER, fault_steps

__all__ = ["CommandFault", "no_command_fault", "command_fault_rows", "command_fault_row", "delay_steps"]


class CommandFault(NamedTuple):
    """The controller output's faults per episode (F = 1 for all, or P rows) and the delay's record (state).

    ``gain`` applies over steps ``gain_from <= k < gain_to``, ``delay`` (control steps) over
    ``delay_from <= k < delay_to``. ``ring`` (P, L + 1, 3) holds each episode's commands of the last L + 1
    steps (L: the longest delay; no columns without one) and ``held`` (P, 3) the one applied before the record.
    """

    gain: np.ndarray  # (F,)
    gain_from: np.ndarray  # (F,) int64
    gain_to: np.ndarray  # (F,) int64
    delay: np.ndarray  # (F,) int64, control steps
    delay_from: np.ndarray  # (F,) int64
    delay_to: np.ndarray  # (F,) int64
    ring: np.ndarray  # (P, L + 1, 3), state
    held: np.ndarray  # (P, 3)


def no_command_fault(n_episodes: int = 1) -> CommandFault:
    """The record for "no output fault" (F = 1, gain 1 never, no delay): the command passes unchanged."""
    never = np.full(1, NEVER, dtype=np.int64)
    return CommandFault(np.ones(1), never.copy(), never.copy(), np.zeros(1, dtype=np.int64), never.copy(),
                        never.copy(), np.zeros((n_episodes, 0, 3)), np.zeros((n_episodes, 3)))


def delay_steps(delay_s: float, dt_ns: int) -> int:
    """A delay of ``delay_s`` seconds in control steps of ``dt_ns`` ns: the nearest whole step.

    Raises
    ------
    ValueError
        The delay is not a whole number of steps (to a nanosecond a step).
    """
    t_ns = int(round(delay_s * 1e9))
    d = int(round(t_ns / dt_ns))
    if abs(t_ns - d * dt_ns) > max(1, d):
        raise ValueError(f"a delay of {delay_s:g} s is not a whole number of {dt_ns * 1e-9:g} s control steps")
    return d


@njit(cache=True, inline="always")
def command_fault_row(u, p, row, k, cf, out):
    """Row ``p`` of the command ``u`` (n, 3) at step ``k`` with the faults of ``cf``'s row ``row``, into ``out[p]``;
    records ``u[p]`` in row ``p`` of the delay's ring.

    ``row`` is 0 where ``cf`` has one row of faults for all episodes. The ring keeps one slot per step modulo
    its length, so a delay of up to L steps reads a command L steps old.
    """
    ring, n = cf.ring, cf.ring.shape[1]
    if n > 0:
        for i in range(3):
            ring[p, k % n, i] = u[p, i]
    g = cf.gain[row] if cf.gain_from[row] <= k < cf.gain_to[row] else 1.0
    d = cf.delay[row] if cf.delay_from[row] <= k < cf.delay_to[row] else 0
    if d == 0:
        for i in range(3):
            out[p, i] = g * u[p, i]
    elif k - d < 0:
        for i in range(3):
            out[p, i] = g * cf.held[p, i]
    else:
        for i in range(3):
            out[p, i] = g * ring[p, (k - d) % n, i]


@njit(cache=True)
def command_fault_rows(u, k, cf, out):
    """:func:`command_fault_row` of every row of ``u`` (P, 3) at step ``k``, into ``out`` (P, 3)."""
    one = cf.gain.shape[0] == 1
    for p in range(u.shape[0]):
        command_fault_row(u, p, 0 if one else p, k, cf, out)


def command_fault_record(faults, dt_ns: int, n_episodes: int, held: np.ndarray | None = None) -> CommandFault | None:
    """The record (F = 1, rings for ``n_episodes``) of the ``controller`` faults among ``faults``
    (:class:`attitude_sil.core.faults.Fault`), or None where there are none. ``held`` (P, 3): the command
    applied before the record (default zero).

    Raises
    ------
    ValueError
        A delay that is not a whole number of steps of ``dt_ns``.
    """
    ours = {f.mode: f for f in faults if f.kind == "controller"}
    if not ours:
        return None
    cf = no_command_fault(n_episodes)
    for mode, f in ours.items():
        start, end = fault_steps(f, dt_ns)
        if mode == "gain":
            cf = cf._replace(gain=np.full(1, float(f.value)), gain_from=np.full(1, start), gain_to=np.full(1, end))
        else:
            d = delay_steps(float(f.value), dt_ns)
            cf = cf._replace(delay=np.full(1, d), delay_from=np.full(1, start), delay_to=np.full(1, end),
                             ring=np.zeros((n_episodes, d + 1, 3)))
    if held is not None:
        cf.held[:] = held
        cf.ring[:] = held[:, None, :]
    return cf
