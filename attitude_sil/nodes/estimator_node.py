"""``estimator`` node: the attitude the flight software uses, from the gyro and the star tracker.

The filter ``type`` selects (:mod:`attitude_sil.core.sensing.registry`; by
default ``mekf``, the multiplicative EKF on attitude and gyro bias of
:mod:`attitude_sil.core.sensing.mekf`). For step k it waits for
``imu`` stamped t_k and, when the star tracker's schedule
(``star_tracker.rate_hz``, ``star_tracker.latency_s``) has a report due at
step k, for that step's ``star_tracker`` message (the tracker's next, in the
order it publishes them; stamped with its exposure time, which a slow tracker
makes older than the latency); then it propagates on the gyro, updates with
the report (rolling back to the exposure; a report with its orientation
absent, an outage, is no update; one older than ``star_tracker.max_age_s`` is
dropped, with a warning) and publishes, stamped t_k, ``estimate/attitude`` (QuaternionStamped,
frame ``inertial``), ``estimate/body_rate`` (bias-corrected, rad/s),
``estimate/gyro_bias`` (rad/s) and ``estimate/attitude_sigma`` (1-sigma per
body axis, rad). The noise it assumes comes with the messages: the gyro's
white-noise variance and the tracker's covariance (REP 145 fields).

With ``feedback: estimate`` the controller's ``attitude`` and ``body_rate``
are remapped to ``estimate/attitude`` and ``estimate/body_rate``. A node of
the user's may take this one's place (``run --external estimator``).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from attitude_sil.core.plant.quaternion import unit_or_none
from attitude_sil.core.sensing.estimator import Filter
from attitude_sil.core.sensing.models import StarTrackerReport, TrackerSchedule
from attitude_sil.core.sensing.registry import build_filter
from attitude_sil.ros.contract import (
    ESTIMATE_ATTITUDE,
    ESTIMATE_ATTITUDE_SIGMA,
    ESTIMATE_BODY_RATE,
    ESTIMATE_GYRO_BIAS,
    IMU,
    STAR_TRACKER,
)
from attitude_sil.ros.convert import imu_orientation, imu_rate, stamp_to_ns
from attitude_sil.ros.node import LockstepNode, run_node
from attitude_sil.storage.cdr import stamped_vector_cdr


class EstimatorNode(LockstepNode):
    """The attitude filter in lockstep; see the module docstring."""

    schema_name = "estimator"
    step_inputs = ()

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_q = self.step_publisher(ESTIMATE_ATTITUDE)
        self.pub_w = self.step_publisher(ESTIMATE_BODY_RATE)
        self.pub_b = self.step_publisher(ESTIMATE_GYRO_BIAS)
        self.pub_s = self.step_publisher(ESTIMATE_ATTITUDE_SIGMA)
        self.step_subscription(IMU, self._on_imu)
        self.step_subscription(STAR_TRACKER, self._on_star_tracker)
        self.imu: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # stamp -> (rate, variance)
        #: the tracker's reports in the order published: (exposure stamp, (q, variance) or None)
        self.star: deque[tuple[int, tuple[np.ndarray, np.ndarray] | None]] = deque()
        self.filter: Filter | None = None
        self.new_episode()

    def rebuild(self) -> None:
        """The star tracker's schedule from the parameters (the filter itself starts with the first gyro sample)."""
        dt = self.param("control_period")
        self.schedule = TrackerSchedule(self.param("star_tracker.rate_hz"), self.param("star_tracker.latency_s"), dt)
        self.latency_steps = self.schedule.latency_steps

    def _start(self, variance: np.ndarray) -> None:
        """A new episode: the filter from the parameters and the gyro's white-noise variance (rad/s)^2."""
        self.new_episode()
        dt = self.param("control_period")
        arw = float(np.sqrt(np.max(variance) * dt))
        try:
            self.filter = build_filter(self.values(), arw, np.zeros(3), dt, 1, self.latency_steps)
        except Exception as exc:  # a plugin filter's own code: its failure is one line, the episode waits
            self.filter = None
            self.get_logger().error(f"estimator {self.param('type')!r} could not be built: "
                                    f"{type(exc).__name__}: {exc}")
        self.k = 0

    def _on_imu(self, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        rate, variance = imu_rate(msg)
        if not (self.finite(rate) and self.finite(variance)) or np.any(variance < 0.0):
            self.get_logger().error(f"imu at t={t * 1e-9:.6f} s: angular velocity or its covariance not finite "
                                    "(or negative); ignored", throttle_duration_sec=1.0)
            return
        def start() -> None:
            self.imu.clear()
            self.star = deque(m for m in self.star if m[0] == 0)  # what a past episode left is not ours
            self._start(variance)

        if not self.in_sequence(IMU, t, on_new=start):
            return
        self.imu[t] = (rate, variance)
        self._advance()

    def _on_star_tracker(self, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        got = imu_orientation(msg)
        if got is not None:
            q = unit_or_none(got[0][None])
            if q is None or not self.finite(got[1]) or np.any(got[1] < 0.0):
                self.get_logger().error(f"star_tracker at t={t * 1e-9:.6f} s: orientation not a finite unit "
                                        "quaternion or covariance invalid; taken as no attitude",
                                        throttle_duration_sec=1.0)
                got = None  # in the queue still: the reports that follow keep their report steps
            else:
                got = (q, got[1])
        self.star.append((t, got))
        self._advance()

    def _advance(self) -> None:
        """Run every step whose inputs are all here, in order."""
        while self.filter is not None:
            k = self.k
            t = k * self.dt_ns
            if t not in self.imu:
                return
            report = None
            if self.schedule.reports_at(k):
                if not self.star:
                    return
                t_exp, got = self.star.popleft()
                if got is None:
                    report = StarTrackerReport(t_exp // self.dt_ns, np.array([[0.0, 0.0, 0.0, 1.0]]), False)
                else:
                    self.filter.set_star_tracker_variance(got[1])
                    report = StarTrackerReport(t_exp // self.dt_ns, got[0], True)
            rate, _ = self.imu.pop(t)
            dropped = self.filter.dropped
            try:
                est = self.filter.step(k, rate[None], report)
            except Exception as exc:  # a plugin filter's own code too: one line, and the episode stops here
                self.get_logger().error(f"estimator {self.param('type')!r} failed at t={t * 1e-9:.6f} s: "
                                        f"{type(exc).__name__}: {exc}; no estimate until the next episode")
                self.filter = None
                return
            if self.filter.dropped > dropped:
                self.get_logger().warning(f"star_tracker report of t={t_exp * 1e-9:g} s at t={t * 1e-9:g} s: older "
                                          "than star_tracker.max_age_s, dropped", throttle_duration_sec=5.0)
            self.k = k + 1
            self.pub_q.publish(stamped_vector_cdr(est.q_BN[0], t, "inertial"))
            self.pub_w.publish(stamped_vector_cdr(est.omega_BN_B[0], t, "body"))
            self.pub_b.publish(stamped_vector_cdr(est.gyro_bias[0], t, "body"))
            self.pub_s.publish(stamped_vector_cdr(est.attitude_sigma[0], t, "body"))


def main(args: list[str] | None = None) -> int:
    """Console script ``estimator_node``."""
    return run_node(EstimatorNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
