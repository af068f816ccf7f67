"""Metrics of one episode from its steps as they come: memory that does not grow with the run.

A graph run used to keep every message of the episode to compute its metrics
at the end (about 1.5 kB per step: 13 GB for a simulated day). An
:class:`EpisodeAccumulator` takes each step once (time, attitude, setpoint,
torque on the body, command) and keeps only running sums, so what
:func:`attitude_sil.core.analysis.metrics.episode_report` computes from a whole
trajectory comes out of O(1) memory, to rounding (the sums are added in
another order; the tests hold them to rtol 1e-12).

Two figures need a look back, and keep what they need of it only:

* the settling time of a ``regulation`` scenario whose step is zero (paper
  004's impulse: settled once |error| stays within ``settling_band`` of its
  peak, a peak not known until the end) keeps the samples that can still be
  the last one outside that band: those above the band of the peak so far
  and above every later sample. That is the transient, not the run;
* the first sample's time step closes the last step's integrals.

A ``step`` scenario's metrics are taken against the setpoint the step goes to
(the setpoint of the first sample at or after ``guidance.step_time``); the
trajectory's metrics take the final one. The two differ only if the setpoint
is changed by hand after the step, which :attr:`EpisodeAccumulator.setpoint_moved`
reports.
"""

from __future__ import annotations

import math

import numpy as np

from attitude_sil.core.analysis.magnetic import MagneticFigures
from attitude_sil.core.analysis.metric_rows import euler_axis, first_crossing
from attitude_sil.core.analysis.metrics import _EXTRA_KEYS, METRIC_KEYS, PAPER_001_SETTLING_ANGLE, _finite_or_none
from attitude_sil.core.analysis.pointing import pointing_errors, pointing_metrics, pointing_start

__all__ = ["EpisodeAccumulator"]

_NAN = float("nan")


def _euler(q, axis: int) -> float:
    # quaternion.euler_from_quat for one quaternion and one axis (the batch engine's compiled function)
    return float(euler_axis(float(q[0]), float(q[1]), float(q[2]), float(q[3]), axis))


def _principal_angle(q_BN, q_RN) -> float:
    # metrics.principal_angle for one pair: 2 atan2(|vec(q_BR)|, w) with w >= 0
    bx, by, bz, bw = q_BN
    rx, ry, rz, rw = -q_RN[0], -q_RN[1], -q_RN[2], q_RN[3]
    ex = rw * bx + bw * rx + ry * bz - rz * by
    ey = rw * by + bw * ry + rz * bx - rx * bz
    ez = rw * bz + bw * rz + rx * by - ry * bx
    ew = rw * bw - rx * bx - ry * by - rz * bz
    if ew < 0.0:
        ex, ey, ez, ew = -ex, -ey, -ez, -ew
    return 2.0 * math.atan2(math.sqrt(ex * ex + ey * ey + ez * ez), ew)


class _Segment:
    """Running figures of one controller's stretch (metrics.segment_metrics)."""

    def __init__(self, kind: str, t_start: float) -> None:
        self.kind = kind
        self.t_start = self.t_end = t_start
        self.iae = self.ise = self.effort = 0.0
        self.max_err = self.max_cmd = 0.0
        self.sq = 0.0
        self.n = 0

    def add(self, err: float, tau_norm: float, cmd_max: float, dt: float) -> None:
        self.iae += abs(err) * dt
        self.ise += err * err * dt
        self.max_err = max(self.max_err, abs(err))
        self.sq += err * err
        self.n += 1
        self.effort += tau_norm * dt
        self.max_cmd = cmd_max if math.isnan(cmd_max) else max(self.max_cmd, cmd_max)

    def report(self, t_end: float) -> dict:
        return {"controller_type": self.kind, "t_start_s": self.t_start, "t_end_s": t_end, "iae": self.iae,
                "ise": self.ise, "max_abs_error_rad": self.max_err, "rms_error_rad": math.sqrt(self.sq / self.n),
                "control_effort_Nms": self.effort, "max_abs_command": self.max_cmd}


class EpisodeAccumulator:
    """The ``run --json`` metrics of one episode, fed one step at a time.

    Parameters
    ----------
    scenario_values : dict
        The ``scenario`` node's values (``metrics.*``).
    step_time : float
        ``guidance.step_time``, s.
    controller_type : str
        The law at the start.
    schedule : list of (time s, step, controller_type), optional
        Scheduled swaps: the report gets ``segments``, as
        :func:`~attitude_sil.core.analysis.metrics.episode_report` gives them.
    """

    def __init__(self, scenario_values: dict, step_time: float, controller_type: str,
                 schedule: list[tuple[float, int, str]] | None = None, magnetorquers: bool = False) -> None:
        s = scenario_values
        # detumbling and momentum figures (where a threshold is set, where the magnetorquers fly)
        self.figures = MagneticFigures(s["metrics.detumble_rate_deg_s"], magnetorquers)
        self.mode = s["metrics.mode"]
        self.axis = int(s["metrics.axis"])
        self.band = float(s["metrics.settling_band"])
        self.tau_d, self.w_os, self.beta = float(s["metrics.tau_d"]), float(s["metrics.w_os"]), float(s["metrics.beta"])
        angle = float(s["metrics.settling_angle_deg"])
        self.settling_angle = PAPER_001_SETTLING_ANGLE if angle < 0 else math.radians(angle)
        self.step_time = float(step_time)
        self.controller_type = controller_type
        self.schedule = list(schedule or [])
        self.setpoint_moved = False
        self.k = 0  # samples taken
        self._pending = None  # the latest sample, waiting for the next one's time step
        self._t0 = self._t1 = None
        # step figures
        self.y0 = None
        self.ref_before = None
        self.r = None
        self.tc = self.t10 = self.t90 = _NAN
        self.f_max = -math.inf
        self.n_after = 0
        self.last_out = -1
        self.settle_step = _NAN
        self.prev = (0.0, 0.0, 0.0)  # fraction, time after the step, error
        self.iae = self.ise = self.itae = 0.0
        self.sse = _NAN
        self.effort = 0.0
        # regulation: error over every sample, and the samples that can still be the last outside the band
        self.sq_err = 0.0
        self.max_err = 0.0
        self.candidates: list[tuple[float, float]] = []  # (|error|, time of the next sample) decreasing
        self._candidate_pending: float | None = None
        self._last_out_at_end: float | None = None
        # tracking
        self.z_prev = None
        self.z_iae = self.z_ise = 0.0
        self.z_last_out = -1
        self.z_settle = _NAN
        self.z_final = _NAN
        self.segments: list[_Segment] = []
        # pointing (APE, AKE): every step's quaternions, for percentiles after a start known only at the end
        self.scenario_values = s
        self._pointing: list[tuple] = []  # (t, q_BN, q_RN, q_BN_est or None)
        self._bounds = [k for _, k, _ in self.schedule]
        self._kinds = [kind for _, _, kind in self.schedule]

    # -- feeding --------------------------------------------------------------
    def add(self, t: float, q_BN, q_RN, tau_c_B, u_cmd, q_BN_est=None, magnetic: tuple | None = None) -> None:
        """One step: time (s), q_BN and q_RN (4,), tau_c_B (3,) N m the actuators' torque over the step (the
        wheels', with the rods' where they fly), u_cmd (3,), the
        estimator's q_BN (4,) where the sensing loop runs, and where :attr:`figures` reports (its ``enabled``)
        ``magnetic`` = (omega_BN_B (3,) rad/s, h_wheels_B (3,) N m s, the dipole commanded (3,) A m^2 or
        None)."""
        self._pointing.append((t, q_BN, q_RN, q_BN_est))
        if magnetic is not None:
            self.figures.add(t, *magnetic)
        q_BN = tuple(float(v) for v in q_BN)
        q_RN = tuple(float(v) for v in q_RN)
        tau_norm = math.sqrt(float(tau_c_B[0]) ** 2 + float(tau_c_B[1]) ** 2 + float(tau_c_B[2]) ** 2)
        cmd_max = max(abs(float(v)) for v in u_cmd) if not any(math.isnan(v) for v in u_cmd) else _NAN
        if self._pending is not None:
            self._close(t)
        if self._t0 is None:
            self._t0 = t
        elif self._t1 is None:
            self._t1 = t
        self._sample(t, q_BN, q_RN)
        self._pending = (t, q_BN, q_RN, tau_norm, cmd_max)
        self.k += 1

    def _close(self, t_next: float) -> None:
        # the pending sample's integrals over [t, t_next] (the last one: the first time step)
        t, q_BN, q_RN, tau_norm, cmd_max = self._pending
        dt = t_next - t
        self.effort += tau_norm * dt
        self._segment(t, q_BN, q_RN, tau_norm, cmd_max, dt)
        if self._candidate_pending is not None:  # the regulation candidate needs the next sample's time
            self._push_candidate(self._candidate_pending, t_next)
            self._candidate_pending = None

    def swap(self, k: int, controller_type: str) -> None:
        """A swap learned of while the episode runs (a live ``controller_type`` set): the law from step ``k``.

        A step already taken into a stretch cannot move: the swap then starts
        at the first step that is not.
        """
        k = max(int(k), self.k - 1 if self._pending is not None else self.k)
        self._bounds.append(k)
        self._kinds.append(controller_type)

    def _segment(self, t, q_BN, q_RN, tau_norm, cmd_max, dt) -> None:
        # the pending sample (index k - 1) into its controller's stretch (every run keeps them: a live swap
        # can come at any time; a report shows them once there are two)
        k = self.k - 1
        if k == 0 or k in self._bounds:
            kinds = [self.controller_type] + [kind for b, kind in zip(self._bounds, self._kinds, strict=True)
                                              if b <= k]
            if self.segments:
                self.segments[-1].t_end = t  # a stretch ends at the first sample of the next
            self.segments.append(_Segment(kinds[-1], t))
        err = _euler(q_RN, self.axis) - _euler(q_BN, self.axis)
        self.segments[-1].add(err, tau_norm, cmd_max, dt)

    def _sample(self, t: float, q_BN, q_RN) -> None:
        if self.mode == "tracking":
            z = _principal_angle(q_BN, q_RN)
            if z > self.settling_angle:
                self.z_last_out = self.k
            elif self.z_last_out == self.k - 1 and self.z_last_out >= 0:
                self.z_settle = t
            if self.z_prev is not None:
                zp, tp = self.z_prev
                self.z_iae += 0.5 * (z + zp) * (t - tp)
                self.z_ise += 0.5 * (z * z + zp * zp) * (t - tp)
            self.z_prev = (z, t)
            self.z_final = z
            return
        y = _euler(q_BN, self.axis)
        ref = _euler(q_RN, self.axis)
        if self.k == 0:
            self.y_first = y
        if t < self.step_time - 1e-12:
            self.ref_before = ref
        else:
            if self.r is None:
                self.r = ref
                self.y0 = self.ref_before if self.ref_before is not None else self.y_first
            elif ref != self.r:
                self.setpoint_moved = True
            self._after(t - self.step_time, y)
        if self.mode == "regulation":
            err = ref - y
            self.sq_err += err * err
            if abs(err) > self.max_err:
                self.max_err = abs(err)
                floor = self.band * self.max_err
                while self.candidates and self.candidates[-1][0] <= floor:
                    self.candidates.pop()
            self._candidate_pending = abs(err)

    def _push_candidate(self, value: float, t_next: float) -> None:
        # keep |error| samples that can still be the last one above band x (final peak)
        if value <= self.band * self.max_err:
            return
        while self.candidates and self.candidates[-1][0] <= value:
            self.candidates.pop()
        self.candidates.append((value, t_next))

    def _crossing(self, found: float, level: float, f: float, ta: float) -> float:
        f_prev, ta_prev, _ = self.prev
        return float(first_crossing(found, level, f, f_prev, ta, ta_prev, self.n_after == 0))

    def _after(self, ta: float, y: float) -> None:
        span = self.r - self.y0
        f = (y - self.y0) / (1.0 if span == 0.0 else span)
        self.tc = self._crossing(self.tc, 0.632, f, ta)
        self.t10 = self._crossing(self.t10, 0.1, f, ta)
        self.t90 = self._crossing(self.t90, 0.9, f, ta)
        self.f_max = max(self.f_max, f)
        if abs(y - self.r) > self.band * abs(span):
            self.last_out = self.n_after
        elif self.last_out == self.n_after - 1 and self.last_out >= 0:
            self.settle_step = ta
        err = self.r - y
        if self.n_after:
            f_prev, ta_prev, e_prev = self.prev
            d = ta - ta_prev
            self.iae += 0.5 * (abs(err) + abs(e_prev)) * d
            self.ise += 0.5 * (err ** 2 + e_prev ** 2) * d
            self.itae += 0.5 * (ta * abs(err) + ta_prev * abs(e_prev)) * d
        self.prev = (f, ta, err)
        self.sse = abs(err)
        self.n_after += 1

    # -- the result -----------------------------------------------------------
    def metrics(self) -> dict[str, float]:
        """The scenario's metrics (the keys of :func:`attitude_sil.core.analysis.metrics.scenario_metrics`)."""
        if self._pending is not None:
            last_t = self._pending[0]
            first_dt = (self._t1 - self._t0) if self._t1 is not None else 0.0
            # the last sample: no effort (the trajectory's tau_c after the final state is not counted)
            t, q_BN, q_RN, tau_norm, cmd_max = self._pending
            self._segment(t, q_BN, q_RN, tau_norm, cmd_max, first_dt)
            if self.segments:
                self.segments[-1].t_end = last_t
            # the last sample has no next one: if it is outside the band, the run never settled
            self._last_out_at_end = self._candidate_pending
            self._candidate_pending = None
            self._pending = None
        if self.mode == "tracking":
            settle = self.z_settle
            if self.z_last_out < 0:
                settle = self._t0
            elif self.z_last_out == self.k - 1:
                settle = _NAN
            return {"settling_time_s": settle, "control_effort_Nms": self.effort,
                    "fitness_f": -(settle + self.beta * self.effort), "final_error_rad": self.z_final,
                    "iae": self.z_iae, "ise": self.z_ise}
        span = self.r - self.y0 if self.r is not None else 0.0
        zero = span == 0.0
        settle = self.settle_step
        if self.last_out < 0:
            settle = 0.0
        elif self.last_out == self.n_after - 1:
            settle = _NAN
        overshoot = max(0.0, self.f_max - 1.0) * 100.0
        tc, t10, t90 = self.tc, self.t10, self.t90
        if zero:
            tc = t10 = t90 = overshoot = settle = _NAN
        m = {"time_constant_s": tc, "rise_time_s": t90 - t10, "settling_time_s": settle, "overshoot_pct": overshoot,
             "steady_state_error_rad": self.sse, "iae": self.iae, "ise": self.ise, "itae": self.itae,
             "control_effort_Nms": self.effort, "cost_J": abs(tc - self.tau_d) + self.w_os * overshoot}
        if self.mode == "regulation":
            m["mse"] = self.sq_err / self.k
            m["max_abs_error_rad"] = self.max_err
            if math.isnan(m["settling_time_s"]):
                floor = self.band * self.max_err
                last = self._last_out_at_end
                above = [t for v, t in self.candidates if v > floor]
                if above and not (last is not None and last > floor):
                    m["settling_time_s"] = above[-1]
        return m

    def report(self, scenario_name: str, duration_s: float, wall_s: float) -> dict:
        """The ``run --json`` object without ``bag``, as :func:`~attitude_sil.core.analysis.metrics.episode_report`."""
        m = self.metrics()
        out: dict = {
            "scenario": scenario_name,
            "controller_type": self.controller_type,
            "sim_time_s": float(duration_s),
            "wall_time_s": float(wall_s),
            "real_time_factor": float(duration_s / wall_s) if wall_s > 0 else None,
        }
        for key in METRIC_KEYS:
            out[key] = _finite_or_none(m[key]) if key in m else None
        for key in _EXTRA_KEYS:
            if key in m:
                out[key] = _finite_or_none(m[key])
        out.update(self.pointing(m.get("settling_time_s")))
        out.update(self.figures.report())
        if self.schedule or len(self.segments) > 1:
            out["segments"] = [seg.report(seg.t_end) for seg in self.segments]
        return out

    def pointing(self, settling_time_s: float | None) -> dict:
        """APE and AKE per body axis (:func:`~attitude_sil.core.analysis.pointing.pointing_metrics`)."""
        if not self._pointing:
            return pointing_metrics(np.zeros(0), np.zeros((0, 3)), None, 0.0)
        t = np.array([p[0] for p in self._pointing])
        q_BN, q_RN = (np.array([p[i] for p in self._pointing], dtype=float) for i in (1, 2))
        q_est = None if self._pointing[0][3] is None else np.array([p[3] for p in self._pointing], dtype=float)
        ape, ake = pointing_errors(q_BN, q_RN, q_est)
        return pointing_metrics(t, ape, ake, pointing_start(self.scenario_values, settling_time_s))
