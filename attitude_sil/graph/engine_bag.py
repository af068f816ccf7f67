"""Write a batch-engine episode as the bag the node graph would have recorded.

A tuning run keeps the best design of every generation. Re-running each one
through the node graph to record it cost minutes; the engine computes the same
episode (graph == batch to 1e-9, tested), so :func:`record_episode` writes its
:class:`~attitude_sil.core.trajectory.Trajectory` straight to a rosbag2 MCAP bag
with the graph's topics, types, frames, stamps (sim time t_k = k dt), QoS
profiles, the controller's parameter change as a ``/parameter_events`` entry,
the 3D view's ``/tf`` and ``/body_model`` as the recorder writes them, and the
same parameter snapshot in ``metadata.yaml``. test_engine_bag.py checks
it against a graph-recorded bag of the same design, message for message. The
final best of a tuning run is still recorded through the graph: a true SIL
record.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rcl_interfaces.msg import ParameterEvent
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message

from attitude_sil.core.faults import OWNER, changes_at, faults_of
from attitude_sil.core.plant.quaternion import euler_from_quat, quat_conjugate, quat_error
from attitude_sil.core.plant.scene import BODY
from attitude_sil.core.sensing.models import SensorSuite
from attitude_sil.core.sim.build import build_environment, build_scene
from attitude_sil.core.sim.scenario import Scenario
from attitude_sil.core.trajectory import Trajectory
from attitude_sil.errors import RunError
from attitude_sil.graph.session import extra_parameters
from attitude_sil.ros.contract import (
    ATTITUDE,
    ATTITUDE_ERROR,
    ATTITUDE_SETPOINT,
    BODY_MODEL,
    BODY_RATE,
    CLOCK,
    COMMAND_TOPIC,
    DIAGNOSTICS,
    DIPOLE_CMD,
    DISTURBANCE_TORQUE,
    ESTIMATE_ATTITUDE,
    ESTIMATE_ATTITUDE_SIGMA,
    ESTIMATE_BODY_RATE,
    ESTIMATE_GYRO_BIAS,
    IMU,
    MAGNETIC_FIELD,
    MAGNETIC_TORQUE,
    MAGNETOMETER,
    ORBIT_TOPIC,
    PARAMETER_EVENTS,
    RATE_SETPOINT,
    STAR_TRACKER,
    TF,
    VIEW_TOPICS,
    WHEEL_MOMENTUM,
    WHEEL_SPEED,
    WHEEL_STATE,
    WHEEL_TORQUE,
    recorded_topics,
)
from attitude_sil.ros.convert import (
    fault_diagnostics_msg,
    imu_msg,
    isolation_diagnostics_msg,
    joint_state_msg,
    magnetic_field_msg,
    ns_to_stamp,
    odometry_msg,
    star_tracker_msg,
)
from attitude_sil.ros.qos import offered_qos_yaml
from attitude_sil.storage.cdr import (
    TfLayout,
    encode_clocks,
    encode_joint_states,
    encode_stamped_vectors,
    marker_array_cdr,
)
from attitude_sil.storage.writer import PARAMETERS_KEY, SCENARIO_KEY, BagWriter

__all__ = ["record_episode"]


def _absolute(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def _graph_stamps(scn: Scenario, tr: Trajectory) -> np.ndarray:
    """The step stamps (ns, sim time) of a trajectory the graph would have recorded; RunError for any other."""
    if scn.param("plant", "model") == "flexible_axis":
        raise RunError("record_episode: the flexible plant's mode is not in the trajectory; record through the graph")
    if tr.wheel_angle is None or tr.wheel_effort is None or tr.omega_RN_R is None:
        raise RunError("record_episode: the trajectory lacks wheel angles, efforts or rate setpoints")
    dt_ns = int(round(scn.dt * 1e9))
    stamps = np.round(tr.t * 1e9).astype(np.int64)
    if not np.array_equal(stamps, np.arange(stamps.size) * dt_ns):
        raise RunError("record_episode: the trajectory must keep every step (stride 1)")
    return stamps


def _write_design(writer: BagWriter, params: dict[str, Any]) -> None:
    """The design's parameter change at t = 0 as the controller's parameter service logs it (none: nothing)."""
    if params:
        event = ParameterEvent(stamp=ns_to_stamp(0), node="/controller",
                               changed_parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in params.items()])
        writer.write(PARAMETER_EVENTS, serialize_message(event), 0)


def _series(scn: Scenario, tr: Trajectory, p: int, stamps: np.ndarray) -> dict:
    """Each step topic's whole series of episode ``p``, encoded at once (storage/cdr.py, equal to rclpy's
    messages, tested); ``command`` the command of each step, whichever its topic."""
    q, q_r = tr.q_BN[p], tr.q_RN[p]
    seen = tr.q_BN_est[p] if scn.feedback == "estimate" else q  # the attitude the controller reads
    err = euler_from_quat(quat_conjugate(quat_error(seen, q_r)))
    names = [f"wheel_{i + 1}" for i in range(tr.wheel_speed.shape[2])]
    series = {
        CLOCK: encode_clocks(stamps),
        ATTITUDE: encode_stamped_vectors(stamps, "inertial", q),
        BODY_RATE: encode_stamped_vectors(stamps, "body", tr.omega_BN_B[p]),
        ATTITUDE_SETPOINT: encode_stamped_vectors(stamps, "inertial", q_r),
        RATE_SETPOINT: encode_stamped_vectors(stamps, "reference", tr.omega_RN_R[p]),
        DISTURBANCE_TORQUE: encode_stamped_vectors(stamps, "body", tr.tau_ext_B[p]),
        "command": encode_stamped_vectors(stamps, "body", tr.u_cmd[p]),
        ATTITUDE_ERROR: encode_stamped_vectors(stamps, "body", err),
        WHEEL_TORQUE: encode_stamped_vectors(stamps, "body", tr.tau_c_B[p]),
        WHEEL_MOMENTUM: encode_stamped_vectors(stamps, "body", tr.h_wheels_B[p]),
        WHEEL_STATE: encode_joint_states(stamps, "", names, tr.wheel_angle[p], tr.wheel_speed[p],
                                         tr.wheel_effort[p]),
        TF: _frames(scn, stamps, q),
        ORBIT_TOPIC: _orbit(scn, stamps),
    }
    if tr.magnetic_field_B is not None:
        series[MAGNETIC_FIELD] = [serialize_message(magnetic_field_msg(b, np.zeros(3), int(t)))
                                  for b, t in zip(tr.magnetic_field_B[p], stamps, strict=True)]
    if tr.dipole_cmd_B is not None:  # the magnetorquers flew
        series[DIPOLE_CMD] = encode_stamped_vectors(stamps, "body", tr.dipole_cmd_B[p])
        series[MAGNETIC_TORQUE] = encode_stamped_vectors(stamps, "body", tr.magnetic_torque_B[p])
    return series


def _sensing_series(scn: Scenario, tr: Trajectory, p: int, stamps: np.ndarray) -> tuple[dict, list]:
    """The sensing loop's topics of episode ``p``, as the sensors and estimator nodes publish them: each step
    topic's series, and the star tracker's reports as (stamp = exposure time, message). The reports and the
    tachometer are the scenario's own sensors (its ``sensors.seed``) stepped again on the episode's truth."""
    suite = SensorSuite(scn.values["sensors"], scn.dt, 1)
    names = [f"wheel_{i + 1}" for i in range(tr.wheel_speed.shape[2])]
    gyro_var = np.full(3, suite.gyro.errors.white_std(scn.dt) ** 2)
    series = {
        IMU: [serialize_message(imu_msg(w, gyro_var, int(t))) for w, t in zip(tr.omega_BN_B_meas[p], stamps,
                                                                              strict=True)],
        WHEEL_SPEED: [serialize_message(joint_state_msg(names, np.zeros(0), suite.tachometer.sample(a, w),
                                                        np.zeros(0), int(t)))
                      for a, w, t in zip(tr.wheel_angle[p], tr.wheel_speed[p], stamps, strict=True)],
        ESTIMATE_ATTITUDE: encode_stamped_vectors(stamps, "inertial", tr.q_BN_est[p]),
        ESTIMATE_BODY_RATE: encode_stamped_vectors(stamps, "body", tr.omega_BN_B_est[p]),
        ESTIMATE_GYRO_BIAS: encode_stamped_vectors(stamps, "body", tr.gyro_bias_est[p]),
        ESTIMATE_ATTITUDE_SIGMA: encode_stamped_vectors(stamps, "body", tr.attitude_sigma[p]),
    }
    if tr.magnetometer_B is not None:
        var = suite.magnetometer.variance
        series[MAGNETOMETER] = [serialize_message(magnetic_field_msg(b, var, int(t)))
                                for b, t in zip(tr.magnetometer_B[p], stamps, strict=True)]
    star_var = suite.star_tracker.errors.sigma_B ** 2
    reports = []
    for k in range(stamps.size):
        r = suite.star_tracker.sample(tr.q_BN[p, k][None], k)
        if r is not None:
            t = r.exposure_step * int(round(scn.dt * 1e9))
            reports.append((t, serialize_message(star_tracker_msg(r.q_BN[0], star_var if r.valid else None, t))))
    return series, reports


def _write_faults(writer: BagWriter, scn: Scenario, stamps: np.ndarray) -> None:
    """Each fault's ``/diagnostics`` at the step it becomes active or ends, as the node that flies it publishes
    it."""
    dt_ns = int(round(scn.dt * 1e9))
    for node in dict.fromkeys(OWNER.values()):
        faults = faults_of(scn.values[node], node)
        for k, t in enumerate(stamps.tolist()):
            changes = changes_at(faults, k, dt_ns)
            if changes:
                writer.write(DIAGNOSTICS, serialize_message(fault_diagnostics_msg(changes, t, node)), t)


def _write_isolations(writer: BagWriter, scn: Scenario, tr: Trajectory, p: int, stamps: np.ndarray) -> None:
    """The wheels' ``/diagnostics`` of the step their FDIR isolated a wheel, as the wheels node publishes it."""
    if tr.fdir_isolated is None or not np.any(tr.fdir_isolated[p] > 0):
        return
    k = int(np.argmax(tr.fdir_isolated[p] > 0))
    msg = isolation_diagnostics_msg(int(tr.fdir_isolated[p, k]), int(stamps[k]),
                                    scn.param("wheels", "reallocate_on_fault"))
    writer.write(DIAGNOSTICS, serialize_message(msg), int(stamps[k]))


def _orbit(scn: Scenario, stamps: np.ndarray) -> list[bytes]:
    """The plant's ``orbit`` messages at ``stamps`` (ns), as it publishes them."""
    orbit = build_environment(scn)[0]
    return [serialize_message(odometry_msg((now := orbit.at(int(t))).r_N, now.v_N, int(t))) for t in stamps]


def _frames(scn: Scenario, stamps: np.ndarray, q_BN: np.ndarray) -> list[bytes]:
    """The recorder's ``/tf`` of every step: stamps (n,) ns, attitude (n, 4)."""
    scene = build_scene(scn.values)
    return TfLayout(scene.frames).encode(stamps, scene.rotation_series(stamps * 1e-9, q_BN))


def record_episode(scn: Scenario, tr: Trajectory, run_dir: str | Path, *, episode: int = 0,
                   controller_params: dict[str, Any] | None = None, controller: str | None = None,
                   duration: float | None = None) -> Path:
    """Write episode ``episode`` of an engine trajectory as a graph-recorded bag.

    Parameters
    ----------
    scn : Scenario
        The scenario the trajectory ran (its parameters go into the snapshot).
    tr : Trajectory
        Every step kept (stride 1) and the wheel angle and effort recorded
        (both drivers of :func:`attitude_sil.core.sim.engine.simulate` do).
    run_dir : path
        The bag directory to create.
    episode : int
        Which episode of the batch.
    controller_params : dict, optional
        The design's controller parameters (ROS values), as a graph episode
        would have set them through the parameter service.
    controller : str, optional
        ``controller_type`` the run started with.
    duration : float, optional
        The episode length the graph run was given (None: the scenario's), s.

    Returns
    -------
    Path
        The bag directory.

    Raises
    ------
    RunError
        A trajectory the graph would not have produced this way (a flexible
        plant's mode, thinned steps), or a bag that cannot be created.
    """
    stamps = _graph_stamps(scn, tr)
    params = dict(controller_params or {})
    extra = extra_parameters(scn, duration, controller, False)
    try:
        writer = BagWriter(run_dir, custom_data={PARAMETERS_KEY: scn.parameters_yaml({**extra, **params}),
                                                 SCENARIO_KEY: scn.scenario_yaml()})
    except (FileExistsError, ValueError, OSError) as exc:
        raise RunError(str(exc)) from None
    p = int(episode)
    try:
        # every topic, as the recorder registers them (the sensing loop's where it ran)
        field = tr.magnetic_field_B is not None
        magnetic = tr.dipole_cmd_B is not None
        sensing = tr.q_BN_est is not None
        for topic, type_name in {**recorded_topics(sensing, field=field, magnetic=magnetic), **VIEW_TOPICS}.items():
            writer.add_topic(_absolute(topic), type_name, offered_qos_yaml(topic), wait=False)
        _write_design(writer, params)
        series = _series(scn, tr, p, stamps)
        if sensing:
            sensed, reports = _sensing_series(scn, tr, p, stamps)
            series.update(sensed)
            writer.write_many([(_absolute(STAR_TRACKER), data, t) for t, data in reports])
        topics = {name: _absolute(name) for name in series if name != "command"}
        commands = [_absolute(COMMAND_TOPIC[kind]) for kind in tr.kind]
        writer.write_many([(commands[k] if name == "command" else topics[name], data[k], t)
                           for k, t in enumerate(stamps.tolist())  # step by step, as the graph publishes
                           for name, data in series.items()])
        _write_faults(writer, scn, stamps)
        _write_isolations(writer, scn, tr, p, stamps)
        t0 = int(stamps[0])  # the body model goes with the first attitude, as the recorder writes it
        writer.write(_absolute(BODY_MODEL), marker_array_cdr(t0, BODY, build_scene(scn.values).markers), t0)
    finally:
        writer.close()
    return writer.run_dir
