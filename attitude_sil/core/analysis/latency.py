"""An outside controller's timing, as the run's recorder sees it: latency, and for a wall-clock one its misses.

Every figure is wall time, measured where the runner's recorder receives the
messages (one DDS hop from each node), which is what a flight-software
engineer budgets: the controller's own computing plus its transport.

* :func:`latency_summary` - latency per command (ms): mean, 99th percentile,
  maximum.
* :class:`CommandArrivals` - a controller on the wall clock
  (``command_timing: wall``): its commands come when its timer fires, not
  per step, so the summary adds how many steps found only a stale command
  and how many of its periods passed without one.
"""

from __future__ import annotations

import numpy as np

__all__ = ["latency_summary", "CommandArrivals", "STALE_PERIODS"]

#: a step whose newest command is older than this many of the controller's periods is stale: a period at least
#: was missed (one and a half: a controller on time, at a phase of its own against the steps, is never late by it)
STALE_PERIODS = 1.5


def latency_summary(latency_s: list[float]) -> dict[str, float]:
    """Mean, 99th percentile and maximum of ``latency_s`` (wall s per command), in ms."""
    ms = np.asarray(latency_s) * 1e3
    return {"controller_latency_mean_ms": float(ms.mean()), "controller_latency_p99_ms": float(np.percentile(ms, 99)),
            "controller_latency_max_ms": float(ms.max())}


class CommandArrivals:
    """Arrivals of a wall-clock controller's commands against the plant's steps.

    Parameters
    ----------
    period_s : float
        The controller's nominal period (``--external-rate``), wall s.

    Call :meth:`attitude`, :meth:`command` and :meth:`step` with the wall time
    (s, monotonic) each message arrives; :meth:`summary` gives the figures.
    """

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)
        self.latency: list[float] = []
        self.arrivals: list[float] = []
        self.steps = 0
        self.stale_steps = 0
        self._attitude_at: float | None = None

    def attitude(self, now: float) -> None:
        """The plant published a state."""
        self._attitude_at = now

    def command(self, now: float) -> None:
        """A command came: its latency is the time since the newest state (the one a timer reads)."""
        if self._attitude_at is not None:
            self.latency.append(now - self._attitude_at)
        self.arrivals.append(now)

    def step(self, now: float) -> None:
        """A step began (its ``/clock``): it is stale when the newest command is older than :data:`STALE_PERIODS`
        periods (the controller missed at least one), or none came yet."""
        if not self.arrivals or now - self.arrivals[-1] > STALE_PERIODS * self.period_s:
            self.stale_steps += 1
        self.steps += 1

    def missed_periods(self) -> int:
        """Periods with no command: each gap between two commands counts its whole periods past the first."""
        gaps = np.diff(self.arrivals) / self.period_s
        return int(np.sum(np.maximum(np.rint(gaps) - 1.0, 0.0)))

    def summary(self) -> dict[str, float | int]:
        """``command_count``, ``command_stale_steps``, ``command_missed_periods`` and the latency figures."""
        out: dict[str, float | int] = {"command_count": len(self.arrivals), "command_stale_steps": self.stale_steps,
                                       "command_missed_periods": self.missed_periods()}
        if self.latency:
            out.update(latency_summary(self.latency))
        return out
