"""The figures of momentum management and detumbling, one step at a time: what ``run --json`` adds for them.

Fed a step at a time (a graph run as its messages come, a trajectory step by
step), so a run's report and a bag's ``metrics`` give the same numbers
(:class:`MagneticFigures`); :func:`magnetic_columns` computes them for a batch
of trajectories at once (the tuner's and Monte Carlo's summaries; equal to
the running figures, test/unit/test_bdot.py):

* ``detumble_time_s``: the time from which |omega_BN| stays below
  ``metrics.detumble_rate_deg_s`` (the first sample after the last one at or
  above it; the first sample's time if none is; None if the last sample is
  still above), where that threshold is set;
* where the magnetorquers fly: ``wheel_momentum_peak_Nms`` and
  ``wheel_momentum_final_Nms`` (|h_w|, the largest and the last) and
  ``dipole_effort_Am2s`` (the integral of |m_cmd| dt, each step's dipole held
  over its step, as the control effort integrates the wheel torque).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MagneticFigures", "magnetic_figures", "magnetic_columns"]


def _norm(v) -> float:
    return math.sqrt(float(v[0]) ** 2 + float(v[1]) ** 2 + float(v[2]) ** 2)


class MagneticFigures:
    """Running detumble and momentum figures of one episode.

    Parameters
    ----------
    detumble_rate_deg_s : float
        ``metrics.detumble_rate_deg_s`` (0: no ``detumble_time_s``).
    magnetorquers : bool
        The magnetorquers fly: report the wheel momentum and dipole figures.
    """

    def __init__(self, detumble_rate_deg_s: float, magnetorquers: bool) -> None:
        self.rate = math.radians(detumble_rate_deg_s)
        self.magnetorquers = magnetorquers
        self.t_first: float | None = None
        self.above_last = False  # the latest sample is at or above the rate
        self.after_above: float | None = None  # the time of the sample after the latest one above
        self.h_peak = 0.0
        self.h_last = math.nan
        self.effort = 0.0
        self._held: tuple[float, float] | None = None  # (t, |m|) of the latest sample

    @property
    def enabled(self) -> bool:
        """Whether it reports anything."""
        return self.rate > 0.0 or self.magnetorquers

    def add(self, t: float, omega_BN_B, h_wheels_B, dipole_B=None) -> None:
        """One step: time s, the body rate (3,) rad/s, the wheel momentum (3,) N m s and the dipole commanded
        (3,) A m^2 (None where none is)."""
        if self.t_first is None:
            self.t_first = t
        if self.above_last:
            self.after_above = t
        self.above_last = not _norm(omega_BN_B) < self.rate  # a non-finite rate is not below it
        h = _norm(h_wheels_B)
        self.h_peak = max(self.h_peak, h) if not math.isnan(h) else math.inf
        self.h_last = h
        if self._held is not None:
            self.effort += self._held[1] * (t - self._held[0])
        self._held = (t, math.nan if dipole_B is None else _norm(dipole_B))  # a step without its dipole: unknown

    def report(self) -> dict:
        """The figures as ``run --json`` keys (None for one not reached)."""
        out: dict = {}
        if self.rate > 0.0:
            reached = not self.above_last and self.t_first is not None
            out["detumble_time_s"] = (self.after_above if self.after_above is not None else self.t_first) \
                if reached else None
        if self.magnetorquers:
            finite = math.isfinite(self.h_peak)
            out["wheel_momentum_peak_Nms"] = self.h_peak if finite else None
            out["wheel_momentum_final_Nms"] = self.h_last if math.isfinite(self.h_last) else None
            out["dipole_effort_Am2s"] = self.effort if math.isfinite(self.effort) else None
        return out


def magnetic_figures(figures: MagneticFigures, t: np.ndarray, omega_BN_B: np.ndarray, h_wheels_B: np.ndarray,
                     dipole_B: np.ndarray | None) -> dict:
    """``figures`` fed one episode's trajectory (t (K+1,), the others (K+1, 3)); its report."""
    for k in range(t.size):
        figures.add(float(t[k]), omega_BN_B[k], h_wheels_B[k], None if dipole_B is None else dipole_B[k])
    return figures.report()


def magnetic_columns(t: np.ndarray, omega_BN_B: np.ndarray, h_wheels_B: np.ndarray, dipole_B: np.ndarray | None,
                     detumble_rate_deg_s: float) -> dict[str, np.ndarray]:
    """The figures of P trajectories at once (t (K+1,), the others (P, K+1, 3)), each (P,), NaN for one not
    reached: ``detumble_time_s`` where ``detumble_rate_deg_s`` > 0, the momentum and dipole figures where
    ``dipole_B`` is given (the magnetorquers flew)."""
    out: dict[str, np.ndarray] = {}
    if detumble_rate_deg_s > 0.0:
        above = ~(np.linalg.norm(omega_BN_B, axis=2) < math.radians(detumble_rate_deg_s))  # NaN: not below
        last = np.where(above.any(axis=1), t.size - 1 - np.argmax(above[:, ::-1], axis=1), -1)  # -1: never above
        out["detumble_time_s"] = np.where(last == t.size - 1, np.nan, t[np.minimum(last + 1, t.size - 1)])
    if dipole_B is not None:  # (without one, the running figures say None: no keys here, NaN in a table)
        h = np.linalg.norm(h_wheels_B, axis=2)
        out["wheel_momentum_peak_Nms"] = np.max(np.nan_to_num(h, nan=np.inf), axis=1)
        out["wheel_momentum_final_Nms"] = h[:, -1]
        out["dipole_effort_Am2s"] = np.sum(np.linalg.norm(dipole_B[:, :-1], axis=2) * np.diff(t), axis=1)
    return out
