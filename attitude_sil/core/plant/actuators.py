"""Actuators other than the PMDC reaction wheels, batch over episodes.

Same interface as :class:`attitude_sil.core.sim.models.Wheels`: ``advance(cmd,
torque_mode)`` holds a body-axis command over one step and returns a
:class:`~attitude_sil.core.trajectory.WheelStep` (momentum at t_k, mean torque on
the body over the step, per-actuator position, velocity, effort).

* :class:`TorqueActuator` — an ideal torquer per body axis saturated at
  ``torque_limit`` (paper 001's magnetic torque rods, 1.2 mN m; paper 002's
  10 N m; paper 004's normalised 1.3). It stores no momentum.
* :class:`NoActuator` — nothing on the wheels node (``actuator: none``): a
  spacecraft on magnetorquers alone, whose rods make the law's torque demand
  (the controller's ``torque_actuator: magnetorquers``). No torque, no joints.
* :class:`SpeedLoopWheels` — paper 003's 1U CubeSat wheels: three wheels on
  the body axes, each the identified motor ``K / (a2 s^2 + a1 s + 1)`` (speed
  out, rpm) inside the paper's wheel-speed PID ``kp + ki/s + kd N s/(s+N)``.
  The command is the drive's analog speed reference in volts
  (``rpm_per_volt``), signed so a positive command spins the wheel negative
  and gives the body positive momentum; it is clipped to the speed limit. The
  loop is linear, so each step is integrated exactly with the matrix
  exponential; body torque is ``-dh/dt`` with ``h = J_w omega`` (the mean over
  the step, so momentum is exchanged exactly).
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.plant.plants import exact_discretization
from attitude_sil.core.trajectory import WheelStep
from attitude_sil.errors import ScenarioError

__all__ = ["TorqueActuator", "NoActuator", "SpeedLoopWheels"]

RPM = 2.0 * np.pi / 60.0


class TorqueActuator:
    """Ideal saturated torquer on each body axis; see the module docstring."""

    names = ["torquer_x", "torquer_y", "torquer_z"]

    def __init__(self, torque_limit: float, n_episodes: int) -> None:
        self.limit = float(torque_limit)
        self.n_episodes = n_episodes

    def reset(self) -> None:
        """Nothing to reset: the torquer has no state."""

    def advance(self, cmd_B: np.ndarray, torque_mode: bool = True):

        if not torque_mode:
            raise ScenarioError("the torque actuator takes torque_cmd; set the controller's command: torque")
        tau = np.clip(np.asarray(cmd_B, dtype=float), -self.limit, self.limit)
        zero = np.zeros_like(tau)
        return WheelStep(zero, tau, zero, zero, tau)


class NoActuator:
    """No torque actuator on the wheels node; see the module docstring."""

    names: list[str] = []

    def __init__(self, n_episodes: int) -> None:
        self.n_episodes = n_episodes

    def reset(self) -> None:
        """Nothing to reset."""

    def advance(self, cmd_B: np.ndarray, torque_mode: bool = True):
        """No torque and no momentum whatever the command (P, 3); no joints."""
        zero = np.zeros_like(np.asarray(cmd_B, dtype=float))
        none = np.zeros((zero.shape[0], 0))
        return WheelStep(zero, zero, none, none, none)


class SpeedLoopWheels:
    """Paper 003 wheels with their speed loop; see the module docstring.

    Parameters
    ----------
    motor_gain, a2, a1 : identified motor K / (a2 s^2 + a1 s + 1)
    kp, ki, kd, n : wheel-speed PID
    rotor_inertia : J_w, kg m^2
    speed_max_rpm : float
    rpm_per_volt : float
    dt : float, s
    n_episodes : int
    """

    names = ["wheel_x", "wheel_y", "wheel_z"]

    def __init__(self, motor_gain, a2, a1, kp, ki, kd, n, rotor_inertia, speed_max_rpm, rpm_per_volt, dt,
                 n_episodes) -> None:
        self.j_w = float(rotor_inertia)
        self.speed_max = float(speed_max_rpm)
        self.rpm_per_volt = float(rpm_per_volt)
        self.dt = float(dt)
        self.n_episodes = n_episodes
        # states: motor speed y (rpm), its rate (rpm/s), PID integral z, derivative filter d, wheel angle (rad)
        # motor: a2 y'' + a1 y' + y = K u;  PID: e = r - y, u = kp e + ki z + kd n (e - d)
        k = motor_gain
        # u = kp (r - y) + ki z + kd n (r - y - d)
        gu_y, gu_z, gu_d, gu_r = -(kp + kd * n), ki, -kd * n, kp + kd * n
        a = np.zeros((5, 5))
        b = np.zeros((5, 1))
        a[0, 1] = 1.0
        a[1, 0] = (-1.0 + k * gu_y) / a2
        a[1, 1] = -a1 / a2
        a[1, 2] = k * gu_z / a2
        a[1, 3] = k * gu_d / a2
        b[1, 0] = k * gu_r / a2
        a[2, 0] = -1.0  # z' = r - y
        b[2, 0] = 1.0
        a[3, 0] = -n  # d' = n (r - y - d)
        a[3, 3] = -n
        b[3, 0] = n
        a[4, 0] = RPM  # wheel angle' = y in rad/s
        phi, gam = exact_discretization(a, b, self.dt)
        self.phi_T = phi.T.copy()
        self.gamma = gam[:, 0].copy()
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros((self.n_episodes, 3, 5))

    def advance(self, cmd_B: np.ndarray, torque_mode: bool = False):

        if torque_mode:
            raise ScenarioError("the speed-loop wheels take voltage_cmd (a speed reference); set command: voltage")
        x = self.x
        ref = np.clip(-self.rpm_per_volt * np.asarray(cmd_B, dtype=float), -self.speed_max, self.speed_max)
        h0 = self.j_w * RPM * x[:, :, 0]
        self.x = x @ self.phi_T + ref[:, :, None] * self.gamma
        h1 = self.j_w * RPM * self.x[:, :, 0]
        return WheelStep(h0, -(h1 - h0) / self.dt, x[:, :, 4], RPM * x[:, :, 0], self.j_w * RPM * x[:, :, 1])
