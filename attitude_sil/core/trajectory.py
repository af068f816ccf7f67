"""What one step of the wheels and one whole episode produce: the project's one vocabulary.

``q_BN`` (attitude of B in N, ``(x, y, z, w)``), ``omega_BN_B`` (rad/s),
``q_RN`` (setpoint), ``h_wheels_B`` (N m s), ``u_cmd`` (V or N m),
``tau_c_B`` and ``tau_ext_B`` (N m): the same names run from the nodes through
the batch engine and the graph decoder to the cost functions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory", "WheelStep"]


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

    The batch engine (:func:`attitude_sil.core.engine.simulate`) and a graph
    run (:func:`attitude_sil.graph.trajectory.trajectory_from_messages`, P = 1)
    both return this type, so the cost functions and metrics take either.
    """

    t: np.ndarray
    q_BN: np.ndarray
    omega_BN_B: np.ndarray
    q_RN: np.ndarray
    h_wheels_B: np.ndarray
    u_cmd: np.ndarray
    tau_c_B: np.ndarray
    tau_ext_B: np.ndarray
    wheel_speed: np.ndarray
    kind: list
