"""Attitude controllers, batch over episodes.

Every controller maps the state at t_k (attitude, body rate) and the setpoint
(reference attitude and rate) to a body-axis command held over
``[t_k, t_k + dt]``. ``compute`` advances the controller's own state by one
step, so it must be called exactly once per control step.
"""

from __future__ import annotations

import numpy as np

from .kernels import pid_step

__all__ = ["PID", "CONTROLLER_TYPES"]

#: controller types the controller node accepts; later issues add the others.
CONTROLLER_TYPES = ("pid",)


class PID:
    """Per-axis PID on the quaternion error vector (paper 000 eq. 19, 2nd).

    ``u = Kp e + Ki ∫e dt + Kd N s / (s + N) e`` per body axis, with ``e`` the
    quaternion error vector of :func:`~attitude_sil.core.quaternion.error_vector`.

    Discretisation at the control period ``dt`` (state held between steps):

    * derivative filter: low-pass state ``x_f`` of ``N / (s + N)`` discretised
      exactly for a held error, ``x_f[k+1] = a x_f[k] + (1 - a) e[k]`` with
      ``a = exp(-N dt)``; derivative term ``N (e[k] - x_f[k])``. ``x_f`` starts
      at 0, so a step at t = 0 gives the derivative kick a continuous PID has.
    * integrator: forward Euler, ``I[k+1] = I[k] + e[k] dt``;
    * the error vector is :func:`~attitude_sil.core.quaternion.error_vector`;
    * output saturation at ``±u_max`` with anti-windup by conditional
      integration: the integrator holds while the output is saturated and the
      error pushes further into the limit.

    Parameters
    ----------
    kp, ki, kd, n : array_like, shape (P, 3) or (3,)
        Gains per episode and body axis; ``n`` in rad/s.
    dt : float
        Control period, s.
    u_max : float
        Output limit (V for voltage-driven wheels).
    """

    def __init__(self, kp, ki, kd, n, dt: float, u_max: float) -> None:
        self.dt = float(dt)
        self.u_max = float(u_max)
        self.set_gains(kp, ki, kd, n)
        self.integral: np.ndarray | None = None
        self.filter_state: np.ndarray | None = None

    def set_gains(self, kp, ki, kd, n) -> None:
        """Replace the gains (arrays broadcastable to (P, 3)); state is kept."""
        self.kp = np.atleast_2d(np.asarray(kp, dtype=float))
        self.ki = np.atleast_2d(np.asarray(ki, dtype=float))
        self.kd = np.atleast_2d(np.asarray(kd, dtype=float))
        self.n = np.atleast_2d(np.asarray(n, dtype=float))
        self.a = np.exp(-self.n * self.dt)
        self._gains = None  # contiguous (P, 3) copies for the kernel, made on first use

    def reset(self, n_episodes: int) -> None:
        """Zero the integrator and derivative-filter states for P episodes."""
        self.integral = np.zeros((n_episodes, 3))
        self.filter_state = np.zeros((n_episodes, 3))

    def compute(
        self,
        q_BN: np.ndarray,
        omega_BN_B: np.ndarray,
        q_RN: np.ndarray,
        omega_RN_R: np.ndarray,
    ) -> np.ndarray:
        """Command for step k, shape (P, 3); advances the controller state.

        Parameters
        ----------
        q_BN, q_RN : (P, 4) attitude and reference attitude
        omega_BN_B, omega_RN_R : (P, 3) rad/s (unused by the PID, which
            differentiates the attitude error through its filter)
        """
        if self.integral is None:
            self.reset(q_BN.shape[0])
        if self._gains is None or self._gains[0].shape != self.integral.shape:
            shape = self.integral.shape
            self._gains = [np.ascontiguousarray(np.broadcast_to(g, shape))
                           for g in (self.kp, self.ki, self.kd, self.n, self.a)]
        gains = self._gains
        return pid_step(np.ascontiguousarray(q_BN, dtype=float), np.ascontiguousarray(q_RN, dtype=float),
                        *gains, self.integral, self.filter_state, self.dt, self.u_max)
