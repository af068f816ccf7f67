"""Stop signals: Ctrl-C (SIGINT), SIGTERM and SIGHUP become a flag checked at a clean point.

One helper for every loop that must stop cleanly: the graph runner
(:mod:`attitude_sil.graph.session`), a node process (:func:`attitude_sil.ros.node.run_node`),
``attitude-sil tune`` (stops after the current generation) and ``replay``. A
``KeyboardInterrupt`` raised inside a node callback or a numba kernel would tear
a step in half; a flag checked between steps stops where the bag can be closed
and results written. The exit code of a stopped command is ``128 + signum``
(130, 143, 129). ROS-free (only :mod:`signal`), so any layer above may use it.
"""

from __future__ import annotations

import signal
from collections.abc import Callable

__all__ = ["STOP_SIGNALS", "Interrupted", "StopSignals"]

#: the signals that stop a run cleanly: Ctrl-C, ``kill``/``timeout``/``docker stop``, a closed terminal
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """A run stopped by a signal; ``signum`` is the signal (the exit code is 128 + signum)."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum = signum


class StopSignals:
    """``with StopSignals() as stop:`` turns the :data:`STOP_SIGNALS` into ``stop.requested``.

    Parameters
    ----------
    on_first : callable(signum), optional
        Called (from the handler) on the first signal, e.g. to say what happens next.
    second_stops_now : bool
        A second signal raises :class:`Interrupted` at once instead of waiting
        for the clean point (``tune``: "again to stop now").

    Outside the main thread the handlers cannot be installed and are left alone.
    The previous handlers come back on exit.
    """

    def __init__(self, on_first: Callable[[int], None] | None = None, second_stops_now: bool = False) -> None:
        self.signum: int | None = None
        self.on_first = on_first
        self.second_stops_now = second_stops_now
        self._old: dict[int, object] = {}

    @property
    def requested(self) -> bool:
        """A stop signal came."""
        return self.signum is not None

    @property
    def exit_code(self) -> int:
        """``128 + signum`` after a signal, else 0."""
        return 0 if self.signum is None else 128 + int(self.signum)

    def __enter__(self) -> StopSignals:
        for sig in STOP_SIGNALS:
            try:
                self._old[sig] = signal.signal(sig, self._on_signal)
            except ValueError:  # not the main thread: leave signals alone
                break
        return self

    def _on_signal(self, signum, frame) -> None:
        if self.signum is None:
            self.signum = signum
            if self.on_first is not None:
                self.on_first(signum)
        elif self.second_stops_now:
            raise Interrupted(signum)

    def check(self) -> None:
        """Raise :class:`Interrupted` if a stop signal came."""
        if self.signum is not None:
            raise Interrupted(self.signum)

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old if old is not None else signal.SIG_DFL)
        self._old = {}
