"""What one step of the wheels and one whole episode produce: the project's one vocabulary.

``q_BN`` (attitude of B in N, ``(x, y, z, w)``), ``omega_BN_B`` (rad/s),
``q_RN`` (setpoint), ``h_wheels_B`` (N m s), ``u_cmd`` (V or N m),
``tau_c_B`` and ``tau_ext_B`` (N m): the same names run from the nodes through
the batch engine and the graph decoder to the cost functions.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ["EpisodeSummary", "Trajectory", "WheelStep", "all_finite"]



def all_finite(*arrays: np.ndarray | None) -> np.ndarray | None:
    """Per episode, whether every value of ``arrays`` (each (P, ...); None skipped) stayed finite, (P,) bool;
    None when every array is None."""
    rows = [a.reshape(a.shape[0], -1) for a in arrays if a is not None]
    if not rows:
        return None
    return np.all([np.all(np.isfinite(a), axis=1) for a in rows], axis=0)

@dataclass
class WheelStep:
    """What the wheels publish for step k (all at or from t_k)."""

    h_wheels_B: np.ndarray  # (P, 3) momentum at t_k
    tau_c_B: np.ndarray  # (P, 3) mean torque on the body over [t_k, t_k+1]
    position: np.ndarray  # (P, n) rad at t_k
    velocity: np.ndarray  # (P, n) rad/s at t_k
    effort: np.ndarray  # (P, n) N m motor torque at t_k



@dataclass
class Trajectory:
    """Batch run result; arrays hold step k = 0..K on axis 1.

    Attributes
    ----------
    t : (K+1,) s
    q_BN : (P, K+1, 4)
    omega_BN_B : (P, K+1, 3) rad/s
    q_RN : (P, K+1, 4) setpoint
    h_wheels_B : (P, K+1, 3) N m s
    u_cmd : (P, K+1, 3) controller command (V, or N m for a torque law)
    kind : list of str, per step: ``voltage`` or ``torque``
    tau_c_B : (P, K+1, 3) mean wheel torque on the body over [t_k, t_k+1], N m
    tau_ext_B : (P, K+1, 3) disturbance torque, N m
    wheel_speed : (P, K+1, n) rad/s
    wheel_angle : (P, K+1, n) rad, or None
    wheel_effort : (P, K+1, n) motor torque, N m, or None
    omega_RN_R : (P, K+1, 3) rate setpoint, rad/s, or None

    The batch engine (:func:`attitude_sil.core.sim.engine.simulate`) and a graph
    run (:func:`attitude_sil.graph.trajectory.trajectory_from_messages`, P = 1)
    both return this type, so the cost functions and metrics take either.
    An array the run was asked not to keep (``simulate(keep=...)``) is None.
    """

    t: np.ndarray
    q_BN: np.ndarray | None
    omega_BN_B: np.ndarray | None
    q_RN: np.ndarray | None
    h_wheels_B: np.ndarray | None
    u_cmd: np.ndarray | None
    tau_c_B: np.ndarray | None
    tau_ext_B: np.ndarray | None
    wheel_speed: np.ndarray | None
    kind: list
    wheel_angle: np.ndarray | None = None
    wheel_effort: np.ndarray | None = None
    omega_RN_R: np.ndarray | None = None
    #: the sensing loop's arrays (docs/sensors.md), None without it: the estimate of q_BN (P, K+1, 4), of
    #: omega_BN_B (P, K+1, 3) rad/s and of the gyro bias (P, K+1, 3) rad/s, the filter's 1-sigma attitude
    #: error per body axis (P, K+1, 3) rad, the gyro's reading (P, K+1, 3) rad/s and its true bias then
    q_BN_est: np.ndarray | None = None
    omega_BN_B_est: np.ndarray | None = None
    gyro_bias_est: np.ndarray | None = None
    attitude_sigma: np.ndarray | None = None
    omega_BN_B_meas: np.ndarray | None = None
    gyro_bias_true: np.ndarray | None = None
    #: the geomagnetic field at the spacecraft in B (P, K+1, 3) tesla, where the scenario has one
    #: (``environment.magnetic_field.model``), else None
    magnetic_field_B: np.ndarray | None = None
    #: the magnetometer's reading of it (P, K+1, 3) tesla, where the sensing loop runs too
    magnetometer_B: np.ndarray | None = None
    #: where the magnetorquers fly (docs/orbit-and-field.md): the dipole commanded (P, K+1, 3) A m^2 in B and
    #: the rods' torque on the body (P, K+1, 3) N m, held over [t_k, t_k+1]; else None
    dipole_cmd_B: np.ndarray | None = None
    magnetic_torque_B: np.ndarray | None = None
    #: where the wheels' FDIR runs (docs/faults.md): each wheel's tachometer residual at t_k (P, K+1, n) rad,
    #: and the wheel it has isolated by then (P, K+1), 1..n (0: none); else None
    fdir_residual: np.ndarray | None = None
    fdir_isolated: np.ndarray | None = None

    @property
    def tau_actuators_B(self) -> np.ndarray | None:
        """The torque the actuators put on the body (P, K+1, 3) N m, what paper 001's Ce (eq. 9) sums: the
        wheels' ``tau_c_B`` and, where they fly, the rods' ``magnetic_torque_B``."""
        if self.magnetic_torque_B is None or self.tau_c_B is None:
            return self.tau_c_B
        return self.tau_c_B + self.magnetic_torque_B

    def every(self, stride: int) -> Trajectory:
        """Every ``stride``-th step (k = 0, stride, 2 stride, ...), as views."""
        keep = slice(None, None, int(stride))

        def cut(a):
            return None if a is None else a[:, keep]

        return Trajectory(**{f.name: self.t[keep] if f.name == "t" else self.kind[keep] if f.name == "kind"
                             else cut(getattr(self, f.name)) for f in fields(self)})


@dataclass
class EpisodeSummary:
    """What an evaluation needs of P episodes, without their trajectories: O(P) memory.

    Attributes
    ----------
    metrics : dict of (P,) arrays
        The scenario's metrics (:func:`attitude_sil.core.analysis.metrics.scenario_metrics`).
    finite : (P,) bool
        Body rate and command stayed finite at every step.
    peak_command : (P,)
        Largest |command| component over the run (inf if one was not finite).
    peak_wheel_speed : (P,) rad/s, or None
        Largest |wheel speed| over the run (None without wheels).
    """

    metrics: dict
    finite: np.ndarray
    peak_command: np.ndarray
    peak_wheel_speed: np.ndarray | None = None
