"""Decode the messages of one graph episode into a :class:`~attitude_sil.core.trajectory.Trajectory`.

A graph run returns the batch engine's type with P = 1, so one vocabulary
(``q_BN``, ``omega_BN_B``, ``q_RN``, ``u_cmd``, ``tau_c_B``, ...) runs from the
graph to the metrics and cost functions.
"""

from __future__ import annotations

import numpy as np
from rclpy.serialization import deserialize_message

from attitude_sil.core.analysis.running_metrics import EpisodeAccumulator
from attitude_sil.core.trajectory import Trajectory
from attitude_sil.ros.contract import (
    APPLIED_COMMAND_TOPIC,
    ATTITUDE,
    ATTITUDE_SETPOINT,
    BODY_RATE,
    COMMAND_TOPIC,
    DIPOLE_CMD,
    DISTURBANCE_TORQUE,
    ESTIMATE_ATTITUDE,
    ESTIMATE_ATTITUDE_SIGMA,
    ESTIMATE_BODY_RATE,
    ESTIMATE_GYRO_BIAS,
    MAGNETIC_FIELD,
    MAGNETIC_TORQUE,
    MAGNETOMETER,
    RATE_SETPOINT,
    STEP_TOPICS,
    WHEEL_CMD,
    WHEEL_MOMENTUM,
    WHEEL_STATE,
    WHEEL_TORQUE,
    message_class,
)
from attitude_sil.ros.convert import decode_step_messages
from attitude_sil.storage.cdr import stamped_values

__all__ = ["KEPT_TOPICS", "StepAssembler", "command_topics", "trajectory_from_messages"]

#: the topics an episode keeps in memory to build its trajectory
KEPT_TOPICS = (ATTITUDE, BODY_RATE, ATTITUDE_SETPOINT, RATE_SETPOINT, WHEEL_TORQUE, WHEEL_MOMENTUM,
               DISTURBANCE_TORQUE, WHEEL_STATE, *COMMAND_TOPIC.values(), *APPLIED_COMMAND_TOPIC.values(), WHEEL_CMD,
               ESTIMATE_ATTITUDE, ESTIMATE_BODY_RATE, ESTIMATE_GYRO_BIAS, ESTIMATE_ATTITUDE_SIGMA, MAGNETIC_FIELD,
               MAGNETOMETER, DIPOLE_CMD, MAGNETIC_TORQUE)


def command_topics(kept) -> dict[str, str]:
    """Where each step's command is: the wheels' applied commands where there are any (a controller on a timer
    of its own sends commands at its ticks, not one per step), else the controller's command topics."""
    if any(kept.get(topic) for topic in APPLIED_COMMAND_TOPIC.values()):
        return APPLIED_COMMAND_TOPIC
    return COMMAND_TOPIC

#: Trajectory field <- topic present only in some runs: the sensing loop's, the field at the spacecraft
_OPTIONAL_FIELDS = {"q_BN_est": ESTIMATE_ATTITUDE, "omega_BN_B_est": ESTIMATE_BODY_RATE,
                    "gyro_bias_est": ESTIMATE_GYRO_BIAS, "attitude_sigma": ESTIMATE_ATTITUDE_SIGMA,
                    "magnetic_field_B": MAGNETIC_FIELD, "magnetometer_B": MAGNETOMETER, "dipole_cmd_B": DIPOLE_CMD,
                    "magnetic_torque_B": MAGNETIC_TORQUE}

#: Trajectory field <- topic
_FIELDS = {"q_BN": ATTITUDE, "omega_BN_B": BODY_RATE, "q_RN": ATTITUDE_SETPOINT, "tau_c_B": WHEEL_TORQUE,
           "h_wheels_B": WHEEL_MOMENTUM, "tau_ext_B": DISTURBANCE_TORQUE, "omega_RN_R": RATE_SETPOINT}


def _wheel_states(items: list[tuple[int, bytes]]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Stamps (n,) and [angle, speed, effort], each (n, wheels), of the ``wheel_state`` messages."""
    by_t: dict[int, bytes] = {}
    for t, data in items:
        by_t.setdefault(t, data)  # the first copy of a stamp, as in the nodes
    cls = message_class(STEP_TOPICS[WHEEL_STATE])
    times = sorted(by_t)
    msgs = [deserialize_message(by_t[t], cls) for t in times]
    out = []
    for field in ("position", "velocity", "effort"):
        a = np.array([list(getattr(m, field)) for m in msgs], dtype=float)
        out.append(a if a.ndim == 2 else np.zeros((len(msgs), 0)))  # wheels without names: a torque actuator
    return np.array(times, dtype=np.int64), out


def trajectory_from_messages(kept: dict[str, list[tuple[int, bytes]]]) -> Trajectory:
    """Serialized step messages -> a P = 1 Trajectory over the steps every topic holds.

    Parameters
    ----------
    kept : dict
        ``topic -> [(stamp ns, CDR bytes), ...]`` for the topics of
        :data:`KEPT_TOPICS` (the recorder's in-memory copies). A stamp received
        twice keeps its first copy.

    Returns
    -------
    Trajectory
        Arrays of shape (1, n, .) where n is the number of steps present on
        every topic, with the command of each step taken from whichever
        command topic carried it (``kind`` says which): the wheels'
        ``applied/*`` where the bag has them (:func:`command_topics`); a step
        commanded on ``wheel_cmd`` has kind ``wheel`` and, as its body-axis
        command, the torque the wheels made of it (``wheel_torque``).
    """
    arrays: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, topic in _FIELDS.items():
        arrays[name] = decode_step_messages(topic, kept.get(topic, []))
    commands: dict[int, tuple[str, np.ndarray]] = {}
    for kind, topic in command_topics(kept).items():
        times, values = decode_step_messages(topic, kept.get(topic, []))
        for t, v in zip(times, values, strict=True):
            commands.setdefault(int(t), (kind, v))
    made = dict(zip(arrays["tau_c_B"][0].tolist(), arrays["tau_c_B"][1], strict=True))
    for t, _ in kept.get(WHEEL_CMD, []):  # a per-wheel command: the body torque the wheels made of it
        if int(t) in made:
            commands.setdefault(int(t), ("wheel", made[int(t)]))
    wheel_t, (angle, speed, effort) = _wheel_states(kept.get(WHEEL_STATE, []))
    estimates = {name: decode_step_messages(topic, kept[topic]) for name, topic in _OPTIONAL_FIELDS.items()
                 if kept.get(topic)}
    n = min([len(t) for t, _ in (*arrays.values(), *estimates.values())] + [len(commands), len(wheel_t)])
    times = arrays["q_BN"][0][:n]
    cmd_times = sorted(commands)[:n]
    return Trajectory(
        **{name: values[None, :n] for name, (_, values) in estimates.items()},
        t=times * 1e-9,
        q_BN=arrays["q_BN"][1][None, :n],
        omega_BN_B=arrays["omega_BN_B"][1][None, :n],
        q_RN=arrays["q_RN"][1][None, :n],
        h_wheels_B=arrays["h_wheels_B"][1][None, :n],
        u_cmd=np.array([commands[t][1] for t in cmd_times]).reshape(1, n, 3),
        tau_c_B=arrays["tau_c_B"][1][None, :n],
        tau_ext_B=arrays["tau_ext_B"][1][None, :n],
        wheel_speed=speed[None, :n],
        kind=[commands[t][0] for t in cmd_times],
        wheel_angle=angle[None, :n],
        wheel_effort=effort[None, :n],
        omega_RN_R=arrays["omega_RN_R"][1][None, :n],
    )


class StepAssembler:
    """Hands an :class:`EpisodeAccumulator` each step of a live episode once its messages are all in.

    A step needs ``attitude``, ``attitude_setpoint``, ``wheel_torque`` and its
    command (``voltage_cmd``, ``torque_cmd`` or ``wheel_cmd``, whose body-axis
    command is the step's ``wheel_torque``; with ``applied`` the wheels'
    ``applied/*`` of it), and ``estimate/attitude`` with
    ``estimate=True`` (the sensing loop runs), and ``body_rate``,
    ``wheel_momentum`` (and ``dipole_cmd`` and ``magnetic_torque``, which
    the effort counts with the wheels' torque) where the accumulator's
    detumbling and momentum figures report; steps go to the accumulator in
    stamp order, the first copy of a message counting (as
    :func:`trajectory_from_messages` takes them). Only the steps not yet
    complete are held: a few in a lockstep run.
    """

    _WIDTH = {ATTITUDE: 4, ATTITUDE_SETPOINT: 4, WHEEL_TORQUE: 3}

    def __init__(self, accumulator: EpisodeAccumulator, estimate: bool = False, applied: bool = False) -> None:
        self.accumulator = accumulator
        # where each step's command is: the wheels' applied commands for a controller on a timer of its own
        self.commands = tuple((APPLIED_COMMAND_TOPIC if applied else COMMAND_TOPIC).values())
        # the stamped parts of a step and their widths (with the sensing loop, a step waits for its estimate too)
        self.width = {**self._WIDTH, ESTIMATE_ATTITUDE: 4} if estimate else dict(self._WIDTH)
        figures = accumulator.figures  # detumbling and momentum figures: the rate, the momentum, the dipole
        if figures.enabled:
            self.width.update({BODY_RATE: 3, WHEEL_MOMENTUM: 3,
                               **({DIPOLE_CMD: 3, MAGNETIC_TORQUE: 3} if figures.magnetorquers else {})})
        self.pending: dict[int, dict[str, np.ndarray]] = {}
        self.done = -1  # stamp of the last step handed on, ns
        self.steps = 0

    def add(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """One message of a kept topic (the recorder's sink)."""
        if topic in self.commands:
            part = "command"
            width = 3
        elif topic == WHEEL_CMD:  # a per-wheel command: its step's body-axis command is the torque made of it
            part, width = "command", 0
        elif topic in self.width:
            part, width = topic, self.width[topic]
        else:
            return
        if stamp_ns <= self.done:
            return  # a second copy of a step already handed on
        values = stamped_values(data, width) if width else np.zeros(0)
        if values is None:
            return
        self.pending.setdefault(stamp_ns, {}).setdefault(part, values.copy())
        while self.pending:
            first = min(self.pending)
            parts = self.pending[first]
            if len(parts) < len(self.width) + 1:  # and the command
                return
            del self.pending[first]
            magnetic = (parts[BODY_RATE], parts[WHEEL_MOMENTUM], parts.get(DIPOLE_CMD)) if BODY_RATE in parts else None
            tau = parts[WHEEL_TORQUE] + parts[MAGNETIC_TORQUE] if MAGNETIC_TORQUE in parts else parts[WHEEL_TORQUE]
            command = parts["command"] if parts["command"].size else parts[WHEEL_TORQUE]
            self.accumulator.add(first * 1e-9, parts[ATTITUDE], parts[ATTITUDE_SETPOINT], tau,  # the actuators'
                                 command, parts.get(ESTIMATE_ATTITUDE), magnetic)
            self.done = first
            self.steps += 1
