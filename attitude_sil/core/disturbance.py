"""External disturbance torques of paper 000, section 2.A, batch over episodes.

Models (any sum of them, chosen by name):

* ``noise`` — band-limited white noise as in the paper's Simulink block: a
  zero-order-held Gaussian sequence at ``sample_time`` T_s with variance
  ``power / T_s`` per body axis (paper: power 5e-6, T_s = 1 ms, giving about
  0-0.25 N m). The torque published for control step k is the mean of the
  held samples inside ``[t_k, t_k + dt]``, so the impulse it delivers equals
  the 1 ms signal's. Seeded per episode (numpy PCG64).
* ``gravity_gradient_linear`` — eq. 18:
  ``G_x = 3 mu / R^3 (I_zz - I_yy) phi``, ``G_y = 3 mu / R^3 (I_zz - I_xx) theta``,
  ``G_z = 0``, with roll and pitch from the attitude at t_k (eq. 9). The paper
  measures the angles from the orbit frame; with no orbit model here they are
  taken from the inertial frame, which is what eq. 18 does for a body that
  starts aligned with it.
"""

from __future__ import annotations

import numpy as np

from .quaternion import euler_from_quat

__all__ = ["DISTURBANCE_MODELS", "DisturbanceModel"]

DISTURBANCE_MODELS = ("noise", "gravity_gradient_linear")


class DisturbanceModel:
    """Sum of the selected disturbance models for P episodes.

    Parameters
    ----------
    models : sequence of str
        Names from :data:`DISTURBANCE_MODELS`; empty means no disturbance.
    dt : float
        Control period, s.
    inertia_diag : ndarray, shape (P, 3) or (3,)
        Principal inertias (for the gravity gradient), kg m^2.
    noise_power : ndarray, shape (3,)
        Noise power per body axis (N m)^2 s.
    noise_sample_time : float
        T_s, s; ``dt / T_s`` must be a whole number.
    seeds : sequence of int, length P
        One seed per episode.
    mu : float
        Gravitational parameter, m^3/s^2.
    orbit_radius : float
        Circular orbit radius, m.
    """

    def __init__(
        self,
        models,
        dt: float,
        inertia_diag: np.ndarray,
        noise_power: np.ndarray,
        noise_sample_time: float,
        seeds,
        mu: float,
        orbit_radius: float,
    ) -> None:
        unknown = [m for m in models if m not in DISTURBANCE_MODELS]
        if unknown:
            raise ValueError(
                f"unknown disturbance model {unknown[0]!r}; known: {', '.join(DISTURBANCE_MODELS)}"
            )
        self.models = tuple(models)
        self.dt = float(dt)
        self.seeds = [int(s) for s in seeds]
        self.n_episodes = len(self.seeds)
        inertia_diag = np.broadcast_to(np.asarray(inertia_diag, dtype=float), (self.n_episodes, 3))
        n2 = 3.0 * mu / orbit_radius**3
        self.gg_gain = np.stack(
            (n2 * (inertia_diag[:, 2] - inertia_diag[:, 1]), n2 * (inertia_diag[:, 2] - inertia_diag[:, 0])),
            axis=-1,
        )
        ratio = self.dt / noise_sample_time
        self.samples_per_step = int(round(ratio))
        if "noise" in self.models and (self.samples_per_step < 1 or abs(ratio - self.samples_per_step) > 1e-9):
            raise ValueError(
                f"noise.sample_time {noise_sample_time} s must divide the control period {self.dt} s"
            )
        self.noise_std = np.sqrt(np.asarray(noise_power, dtype=float) / noise_sample_time)
        self.reset()

    def reset(self) -> None:
        """Restart every episode's noise stream from its seed."""
        self.rngs = [np.random.Generator(np.random.PCG64(s)) for s in self.seeds]

    def torque(self, q_BN: np.ndarray) -> np.ndarray:
        """Disturbance torque held over the current step, (P, 3) N m.

        Parameters
        ----------
        q_BN : (P, 4) attitude at t_k
        """
        tau = np.zeros((q_BN.shape[0], 3))
        if "noise" in self.models:
            draws = np.stack(
                [rng.standard_normal((self.samples_per_step, 3)).mean(axis=0) for rng in self.rngs]
            )
            tau += draws * self.noise_std
        if "gravity_gradient_linear" in self.models:
            rpy = euler_from_quat(q_BN)
            tau[:, :2] += self.gg_gain * rpy[:, :2]
        return tau
