"""The wheel drive's FDIR: detect a wheel fault on the tachometer, isolate the wheel, share the command
among the others (issue 43, item 3).

Detection is a residual of each wheel's tachometer against the commanded
motor model. The model is the drive's own: the nominal motor
(:meth:`~attitude_sil.core.plant.wheels.WheelAssembly.nominal`, so a motor
whose constants differ from the datasheet's is a model error the detector
must tolerate), driven by the same command through the same allocation and
drive limits (:meth:`~attitude_sil.core.plant.wheels.WheelAssembly.advance`).
It runs as an observer:

* the tachometer reads each wheel's angle as a count of ``counts_per_rev``
  Hall edges a revolution; its reading is the middle of the count, so it is
  within ``q / 2`` of the angle, ``q = 2 pi / counts_per_rev``;
* at each step, before the command, the residual ``r = theta_read - theta_hat``
  (rad) corrects the model's angle and speed with the gains of a double pole
  at ``p = exp(-bandwidth dt)``: ``theta_hat += l1 r``, ``omega_hat += l2 r`` with
  ``l1 = 2 (1 - p)`` and ``l2 = (1 - p)^2 / dt``. A wheel whose torque departs
  from the model's by ``J a`` (lost: no drive; stuck: the wrong voltage) then
  leaves a steady residual ``a / (bandwidth^2 + 2 bandwidth / tau_m)``, with
  ``tau_m`` the motor's mechanical time constant (``J R / (K_i K_b)``, about
  1 s on HST's wheels; the back-EMF damps the wheel and the model alike), where
  a healthy wheel's is the count's quantisation, within a count;
* a wheel whose ``|r|`` exceeds ``threshold_rad`` for ``persistence`` steps in a
  row is isolated (the largest residual, where several do at once): from that
  step the allocation shares the command among the others, as ideal isolation
  does from the failure's step (``WheelParams.reallocate``), and no other
  wheel is isolated after it (one wheel per run);
* then the model predicts the next step from the corrected state.

The drivers call :meth:`WheelFdir.check` and :meth:`WheelFdir.predict` around
the wheels' own step (:class:`attitude_sil.core.sim.models.Wheels`), so the
graph's wheels node and the stepwise driver fly the same detector.
"""

from __future__ import annotations

import math

import numpy as np

from attitude_sil.core.plant.kernels import WheelFailure
from attitude_sil.core.plant.lanes import ANGLE, SPEED
from attitude_sil.core.plant.wheels import WheelAssembly

__all__ = ["WheelFdir", "tachometer_angle", "FDIR_COLUMNS", "fdir_columns", "fdir_report"]


def tachometer_angle(angle: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """The tachometer's reading of wheel angles (rad): the middle of the Hall-edge count they are in."""
    q = 2.0 * math.pi / counts_per_rev
    return (np.floor(np.asarray(angle, dtype=float) / q) + 0.5) * q


class WheelFdir:
    """The detector and isolation of one assembly's P episodes (module docstring).

    Parameters
    ----------
    assembly : the wheels it watches (its nominal motor is the model)
    n_episodes : P
    counts_per_rev : the tachometer's Hall edges a revolution
    threshold_rad : residual threshold, rad
    persistence : steps in a row over the threshold that isolate a wheel
    bandwidth_rad_s : the observer's double pole, rad/s
    """

    def __init__(self, assembly: WheelAssembly, n_episodes: int, counts_per_rev: int, threshold_rad: float,
                 persistence: int, bandwidth_rad_s: float) -> None:
        self.assembly = assembly
        self.n_episodes = n_episodes
        self.counts_per_rev = int(counts_per_rev)
        self.threshold = float(threshold_rad)
        self.persistence = int(persistence)
        p = math.exp(-bandwidth_rad_s * assembly.dt)
        self.gains = (2.0 * (1.0 - p), (1.0 - p) ** 2 / assembly.dt)
        self._model = None
        self._model_of = None

    def reset(self, x0: np.ndarray) -> None:
        """A new episode from the wheels' state ``x0`` (P, n, 3), which the drive knows at power-on."""
        P, n = x0.shape[0], x0.shape[1]
        self.x_hat = x0.copy()
        self.count = np.zeros((P, n), dtype=np.int64)
        self.residual = np.zeros((P, n))
        self.isolated = np.full(P, -1, dtype=np.int64)
        self.isolated_step = np.zeros(P, dtype=np.int64)
        # the model's failure record: no wheel failed, the isolation above (its arrays, written in place)
        self._record = WheelFailure(np.full(P, -1, dtype=np.int64), np.zeros(P, dtype=np.int64),
                                    np.zeros(P, dtype=np.int64), np.zeros(P), np.zeros(P), self.isolated,
                                    self.isolated_step, np.zeros((1, 3, 3)), np.zeros((1, 3)))

    def model(self) -> WheelAssembly:
        """The drive's model: the assembly as it now stands (allocation, null-space loop) with its nominal motor."""
        if self._model_of is not self.assembly.params:
            self._model, self._model_of = self.assembly.nominal(), self.assembly.params
        return self._model

    def check(self, k: int, x: np.ndarray) -> np.ndarray:
        """Step ``k``'s residuals of the wheels' true state ``x`` (P, n, 3) read by the tachometer; corrects the
        model and isolates. Returns the episodes that isolated a wheel at this step (indices)."""
        r = tachometer_angle(x[:, :, ANGLE], self.counts_per_rev) - self.x_hat[:, :, ANGLE]
        l1, l2 = self.gains
        self.x_hat[:, :, ANGLE] += l1 * r
        self.x_hat[:, :, SPEED] += l2 * r
        self.residual = r
        over = np.abs(r) > self.threshold
        self.count = np.where(over, self.count + 1, 0)
        due = self.count >= self.persistence
        newly = np.flatnonzero((self.isolated < 0) & due.any(axis=1))
        if newly.size:
            wheel = np.argmax(np.where(due, np.abs(r), -1.0), axis=1)
            self.isolated[newly] = wheel[newly]
            self.isolated_step[newly] = k
        return newly

    def predict(self, cmd_B: np.ndarray, torque_mode: bool, k: int, wheel_cmd: np.ndarray | None = None) -> None:
        """The model one step on under the command the wheels take at step ``k``: ``cmd_B`` (P, 3), or each
        wheel's ``wheel_cmd`` (P, n) N m."""
        self.x_hat, _, _ = self.model().advance(self.x_hat, cmd_B, torque_mode, k, self.isolation(), wheel_cmd)

    def isolation(self) -> WheelFailure:
        """The model's failure record (P rows): no wheel failed, the detector's isolation."""
        return self._record


#: the per-episode figures of an FDIR run (:func:`fdir_columns`): the wheel isolated (1..n, 0: none), when (s)
FDIR_COLUMNS = ("fdir_wheel", "fdir_time_s")


def fdir_columns(t: np.ndarray, isolated: np.ndarray) -> dict[str, np.ndarray]:
    """:data:`FDIR_COLUMNS` of P runs from their ``fdir_isolated`` record (P, K+1) and step times ``t`` (s)."""
    isolated = np.asarray(isolated)
    any_ = isolated[:, -1] > 0
    first = np.argmax(isolated > 0, axis=1)
    return {"fdir_wheel": isolated[:, -1].astype(float),
            "fdir_time_s": np.where(any_, np.asarray(t)[first], np.nan)}


def fdir_report(failed_wheel, failure_time_s, failure_mode, fdir_wheel, fdir_time_s, duration_s: float) -> dict:
    """Detection latency, missed detections and false alarms of runs with and without a wheel failure.

    Parameters
    ----------
    failed_wheel, failure_time_s, failure_mode : (n,) the failure each run flew (wheel 1..n, 0: none; s; mode)
    fdir_wheel, fdir_time_s : (n,) what its FDIR isolated (:func:`fdir_columns`)
    duration_s : each run's length, s

    Returns
    -------
    dict: ``failed_runs``, ``detected`` (the failed wheel, at or after its failure), ``missed`` (a failed run
    that isolated nothing), ``latency_s`` (p50, p90, max, mean of the detected), ``missed_by_mode``,
    ``false_alarms`` (an isolation that is not a detection: in a healthy run, of another wheel, or before the
    failure), ``false_alarm_rate`` (per run) and ``false_alarms_per_hour`` of healthy flight.
    """
    failed = np.asarray(failed_wheel, dtype=np.int64)
    t_fail = np.asarray(failure_time_s, dtype=float)
    wheel = np.asarray(fdir_wheel, dtype=float).astype(np.int64)
    t_iso = np.asarray(fdir_time_s, dtype=float)
    mode = np.asarray(failure_mode).astype(str)
    has = failed > 0
    detected = has & (wheel == failed) & (t_iso >= t_fail - 1e-9)
    missed = has & (wheel == 0)
    false = (wheel > 0) & ~detected
    latency = t_iso[detected] - t_fail[detected]
    healthy_h = float(np.sum(np.where(has, np.minimum(t_fail, duration_s), duration_s))) / 3600.0
    out = {"runs": int(failed.size), "failed_runs": int(has.sum()), "detected": int(detected.sum()),
           "missed": int(missed.sum()), "false_alarms": int(false.sum()),
           "false_alarm_rate": float(false.mean()) if failed.size else 0.0,
           "false_alarms_per_hour": float(np.sum(false & ~has) / healthy_h) if healthy_h > 0 else 0.0,
           "missed_by_mode": {m: int(np.sum(missed & (mode == m))) for m in sorted(set(mode[has]))},
           "failed_by_mode": {m: int(np.sum(has & (mode == m))) for m in sorted(set(mode[has]))}}
    if latency.size:
        p50, p90 = np.percentile(latency, [50, 90])
        out["latency_s"] = {"p50": float(p50), "p90": float(p90), "max": float(latency.max()),
                            "mean": float(latency.mean())}
    return out
