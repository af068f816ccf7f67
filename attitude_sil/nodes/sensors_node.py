"""``sensors`` node: what the hardware reports of the plant's truth.

Once it holds ``attitude`` and ``body_rate`` stamped t_k it samples the
models of :class:`attitude_sil.core.sensing.models.SensorSuite` and publishes,
stamped t_k, ``imu`` (``sensor_msgs/Imu``: the gyro's mean body rate over the
last step with its per-sample white-noise variance; orientation and linear
acceleration absent, REP 145) and, on the star tracker's schedule,
``star_tracker`` (``sensor_msgs/Imu``: q_BN with its noise covariance, stamped
with the exposure time; during an outage the orientation is absent). On
``wheel_state`` stamped t_k it publishes ``wheel_speed`` (``JointState``: the
Hall-sensor tachometer readings), and on ``magnetic_field`` (the plant's,
where the scenario has a field) ``magnetometer`` (``sensor_msgs/MagneticField``,
the reading in B with its noise variance). Every noise parameter is a ROS parameter
(docs/parameters.md); a draw depends only on (``seed``, source, step, axis),
so a run is repeatable and equals the batch engine's (docs/sensors.md).
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.faults import Fault, first_step
from attitude_sil.core.sensing.models import SensorSuite
from attitude_sil.core.sim.lockstep import StepSequencer
from attitude_sil.errors import ScenarioError
from attitude_sil.ros.contract import (
    ATTITUDE,
    BODY_RATE,
    IMU,
    MAGNETIC_FIELD,
    MAGNETOMETER,
    STAR_TRACKER,
    WHEEL_SPEED,
    WHEEL_STATE,
)
from attitude_sil.ros.convert import (
    imu_msg,
    joint_state_msg,
    magnetic_field_msg,
    message_to_array,
    stamp_to_ns,
    star_tracker_msg,
)
from attitude_sil.ros.node import LockstepNode, NodeFaults, run_node

INPUTS = (ATTITUDE, BODY_RATE)


class SensorsNode(LockstepNode):
    """The gyro, the star tracker and the wheel tachometers in lockstep; see the module docstring."""

    schema_name = "sensors"
    step_inputs = INPUTS

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_imu = self.step_publisher(IMU)
        self.pub_star = self.step_publisher(STAR_TRACKER)
        self.pub_speed = self.step_publisher(WHEEL_SPEED)
        for name in INPUTS:
            self.step_subscription(name, lambda m, n=name: self._on_input(n, m))
        self.step_subscription(WHEEL_STATE, self._on_wheel_state)
        self.wheel_seq = StepSequencer()
        self.pub_magnetometer = self.step_publisher(MAGNETOMETER)
        self.step_subscription(MAGNETIC_FIELD, self._on_field)
        self.field_seq = StepSequencer()
        self.faults = NodeFaults(self, "sensors")  # rebuild() resets it
        self.new_episode()

    def rebuild(self) -> None:
        self.core = SensorSuite(self.values(), self.param("control_period"))
        self.gyro_variance = np.full(3, self.core.gyro.errors.white_std(self.core.gyro.dt) ** 2)
        self.star_variance = self.core.star_tracker.errors.sigma_B ** 2
        self.faults.reset()  # the list as it stands, each fault said on /diagnostics as it becomes active
        self.k = -1  # the latest step sampled

    def check_parameters(self, pending: dict) -> str:
        try:
            if "faults" in pending:
                foreign = self.faults.refusal(pending["faults"])
                if foreign:
                    return foreign
            SensorSuite({**self.values(), **pending}, self.param("control_period"))
        except (ValueError, ScenarioError) as exc:
            return str(exc)
        return ""

    def on_parameters_set(self, names: list[str]) -> None:
        if "faults" in names:
            self._inject(self.faults.added())

    def _inject(self, faults: list[Fault]) -> None:
        """Faults added while the graph runs: each from its time, or, if that has passed, from the step after the
        one sampled last, for its duration (a star tracker off: an outage; a gyro axis' fault: on its reading)."""
        for fault in faults:
            step = max(first_step(fault.time_s, self.dt_ns), self.k + 1)
            self.core.add_fault(fault, step)
            self.faults.started(fault, step, self.dt_ns)

    def _on_input(self, name: str, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        slot = self.gather(name, message_to_array(msg)[None], t)
        if slot is None:
            return
        self.k = t // self.dt_ns
        sample = self.core.sample(slot[ATTITUDE], slot[BODY_RATE], self.k)
        report = sample.star_tracker
        if report is not None:  # first, so the estimator holds it when the step's gyro reading comes
            t_exp = report.exposure_step * self.dt_ns
            self.pub_star.publish(star_tracker_msg(report.q_BN[0], self.star_variance if report.valid else None,
                                                   t_exp))
        self.pub_imu.publish(imu_msg(sample.omega_meas_B[0], self.gyro_variance, t))
        self.faults.say(t, self.dt_ns)

    def _on_wheel_state(self, msg) -> None:
        t = stamp_to_ns(msg.header.stamp)
        kind = self.wheel_seq.classify(t, self.dt_ns)
        if kind == StepSequencer.NEW:
            self.core.tachometer.reset()  # (the suite is rebuilt on the episode's first state, before this)
        elif kind != StepSequencer.NEXT:
            return
        angle = np.asarray(msg.position, dtype=float)
        speed = np.asarray(msg.velocity, dtype=float)
        if not (self.finite(angle) and self.finite(speed)) or angle.shape != speed.shape:
            self.get_logger().error(f"wheel_state at t={t * 1e-9:.6f} s is not finite; ignored",
                                    throttle_duration_sec=1.0)
            return
        reading = self.core.tachometer.sample(angle, speed)
        self.pub_speed.publish(joint_state_msg(list(msg.name), np.zeros(0), reading, np.zeros(0), t))


    def _on_field(self, msg) -> None:
        """The plant's field at t_k: the magnetometer's reading of it, stamped t_k."""
        t = stamp_to_ns(msg.header.stamp)
        b = message_to_array(msg)[None]
        if not self.finite(b):
            self.get_logger().error(f"magnetic_field at t={t * 1e-9:.6f} s is not finite; ignored",
                                    throttle_duration_sec=1.0)
            return
        if self.field_seq.classify(t, self.dt_ns) not in (StepSequencer.NEW, StepSequencer.NEXT):
            return
        reading = self.core.magnetometer.sample(b, t // self.dt_ns)
        self.pub_magnetometer.publish(magnetic_field_msg(reading[0], self.core.magnetometer.variance, t))


def main(args: list[str] | None = None) -> int:
    """Console script ``sensors_node``."""
    return run_node(SensorsNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
