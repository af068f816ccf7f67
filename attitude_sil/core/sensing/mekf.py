"""The attitude estimator: a multiplicative extended Kalman filter on attitude and gyro bias.

The standard formulation (Lefferts, Markley and Shuster, "Kalman filtering for spacecraft attitude
estimation", JGCD 5(5), 1982; Crassidis and Junkins, *Optimal Estimation of Dynamic Systems*, 2nd ed.,
sec. 7.2, Table 7.1), written for this package's convention: Hamilton quaternions in (x, y, z, w) order,
q_BN maps body vectors to inertial ones, and the error is a small rotation in the body frame,
q_true = q_est ⊗ dq(d_alpha). State: q_est (P, 4) and the gyro bias b_est (P, 3) rad/s; error state
x = (d_alpha, d_b) with covariance P_cov (P, 6, 6).

Gyro model of the filter: omega_meas = omega_true + b + eta_v, db/dt = eta_u, with eta_v of density
sigma_v (rad/s^0.5, the gyro's angle random walk, from its message's covariance times dt) and eta_u of
density sigma_u (rad/s^1.5, the filter's own bias-walk parameter).

Propagation over [t_(k-1), t_k] with the reading of that interval (the gyro's mean rate over it, a delta
angle: :mod:`attitude_sil.core.sensing.models`), omega = omega_meas,k - b_est:
q_est <- q_est ⊗ exp(omega dt / 2) (exact for a noise-free gyro); P <- Phi P Phi^T + Q with
Phi = [[exp(-[omega x] dt), -int_0^dt exp(-[omega x] s) ds], [0, I]] in closed form, and Q of Crassidis
and Junkins eq. 7.49 (sigma_v^2 dt + sigma_u^2 dt^3 / 3, -sigma_u^2 dt^2 / 2, sigma_u^2 dt).

Update with a star tracker attitude q_meas = q_true ⊗ dq(v), v ~ N(0, R) in the body frame: residual
z = 2 vec(q_est* ⊗ q_meas) (short way), H = [I 0], Joseph form for P, then q_est <- q_est ⊗ dq(d_alpha),
b_est <- b_est + d_b.

One step k: propagate to t_k on the reading of step k, then update with a report due at step k, then
publish the estimate at t_k (the rate estimate is the bias-corrected mean rate of the last interval).

Latency: the tracker reports exposure j at step k = j + latency. The filter keeps its prior and the gyro
reading of each step since the oldest exposure still to come; a report rolls back to step j, updates there
and propagates again to step k with the stored gyro readings, rewriting the stored states on the way (so a
report whose window overlaps an earlier one's sees its update). No report at a step, or one marked invalid
(an outage), is no update: the filter propagates on the gyro alone and its covariance grows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from attitude_sil.core.plant.quaternion import (
    attitude_error_B,
    cross_matrix,
    quat_from_euler,
    quat_multiply,
    quat_normalize,
    rotation_quaternion,
    small_rotation,
)
from attitude_sil.core.sensing.models import DEG
from attitude_sil.errors import ScenarioError

__all__ = ["MekfSettings", "Mekf", "Estimate", "transition"]

#: smallest star-tracker noise the update assumes, rad (a perfect tracker would make the update singular)
R_FLOOR = 1e-9


def transition(omega: np.ndarray, dt: float) -> np.ndarray:
    """Phi (P, 6, 6) of the error state over dt for the held rate omega (P, 3) rad/s (module docstring)."""
    P = omega.shape[0]
    W = cross_matrix(omega)
    W2 = W @ W
    n = np.linalg.norm(omega, axis=-1)[:, None, None]
    th = n * dt
    small = th < 1e-3
    safe = np.where(small, 1.0, n)
    # the closed forms' coefficients, by their series where theta is small (error < 1e-15 of the terms)
    c1 = np.where(small, dt - n**2 * dt**3 / 6.0, np.sin(th) / safe)
    c2 = np.where(small, dt**2 / 2.0 - n**2 * dt**4 / 24.0, (1.0 - np.cos(th)) / safe**2)
    c3 = np.where(small, dt**3 / 6.0 - n**2 * dt**5 / 120.0, (th - np.sin(th)) / safe**3)
    eye = np.broadcast_to(np.eye(3), (P, 3, 3))
    phi = np.zeros((P, 6, 6))
    phi[:, :3, :3] = eye - c1 * W + c2 * W2
    phi[:, :3, 3:] = -(eye * dt - c2 * W + c3 * W2)
    phi[:, 3:, 3:] = eye
    return phi


@dataclass(frozen=True)
class MekfSettings:
    """The filter's own parameters (SI units).

    Attributes
    ----------
    gyro_arw : float
        sigma_v, rad/s^0.5 (the gyro's angle random walk).
    bias_walk : float
        sigma_u, rad/s^1.5.
    star_tracker_sigma : (3,) rad
        1-sigma noise of the tracker per body axis (the R of the update).
    initial_q_BN : (4,) or (P, 4)
        Initial attitude estimate.
    initial_attitude_sigma : float
        1-sigma of the initial attitude error per axis, rad.
    initial_bias_sigma : float
        1-sigma of the initial bias error per axis, rad/s.
    """

    gyro_arw: float
    bias_walk: float
    star_tracker_sigma: tuple
    initial_q_BN: np.ndarray
    initial_attitude_sigma: float
    initial_bias_sigma: float

    @classmethod
    def from_values(cls, estimator: dict, gyro_arw: float, star_tracker_sigma) -> MekfSettings:
        """From the ``estimator`` node's parameters (``initial_attitude_rpy_deg`` (3,) or (P, 3)) and the
        sensors' noise (SI units)."""
        rpy = estimator["initial_attitude_rpy_deg"]
        return cls(gyro_arw=float(gyro_arw),
                   bias_walk=estimator["bias_walk_deg_h_rt_h"] * DEG / 3600.0 / 60.0,
                   star_tracker_sigma=tuple(np.asarray(star_tracker_sigma, dtype=float)),
                   initial_q_BN=quat_from_euler(np.radians(np.asarray(rpy, dtype=float))),
                   initial_attitude_sigma=estimator["initial_attitude_sigma_deg"] * DEG,
                   initial_bias_sigma=estimator["initial_bias_sigma_deg_h"] * DEG / 3600.0)


@dataclass
class Estimate:
    """The filter's output at step k (all (P, ...)).

    Attributes
    ----------
    q_BN : (P, 4)
    omega_BN_B : (P, 3) rad/s, bias-corrected rate
    gyro_bias : (P, 3) rad/s
    attitude_sigma : (P, 3) rad, 1-sigma per body axis
    cov : (P, 6, 6)
    """

    q_BN: np.ndarray
    omega_BN_B: np.ndarray
    gyro_bias: np.ndarray
    attitude_sigma: np.ndarray
    cov: np.ndarray


class Mekf:
    """The multiplicative EKF on P episodes (module docstring).

    Parameters
    ----------
    settings : MekfSettings
    dt : float
        Control step, s.
    n_episodes : int
    latency_steps : int
        How far back a report may reach, in steps: the tracker's latency, or more (``star_tracker.max_age_s``).
        An older report is dropped (counted in ``dropped``), as a filter drops a measurement older than its
        buffer: a tracker slowed by a ``latency`` fault beyond it is, to the filter, a tracker off.
    """

    def __init__(self, settings: MekfSettings, dt: float, n_episodes: int = 1, latency_steps: int = 0) -> None:
        self.s = settings
        self.dt = float(dt)
        self.n = int(n_episodes)
        self.latency_steps = int(latency_steps)
        sv, su = settings.gyro_arw, settings.bias_walk
        dt = self.dt
        q = np.zeros((6, 6))
        q[:3, :3] = (sv**2 * dt + su**2 * dt**3 / 3.0) * np.eye(3)
        q[:3, 3:] = q[3:, :3] = -(su**2 * dt**2 / 2.0) * np.eye(3)
        q[3:, 3:] = su**2 * dt * np.eye(3)
        self.Q = q
        self.set_star_tracker_variance(np.asarray(settings.star_tracker_sigma, dtype=float) ** 2)
        self.reset()

    def set_star_tracker_variance(self, variance) -> None:
        """The tracker's noise variance (3,) rad^2 per body axis, as its message reports it (the R of the update)."""
        sigma = np.sqrt(np.asarray(variance, dtype=float))
        self.R = np.diag(np.maximum(sigma, R_FLOOR) ** 2)

    def reset(self) -> None:
        """Step 0: the initial estimate and covariance, no history."""
        s = self.s
        self.k = 0
        self.q = np.array(np.broadcast_to(quat_normalize(s.initial_q_BN), (self.n, 4)))
        self.b = np.zeros((self.n, 3))
        p0 = np.diag([s.initial_attitude_sigma**2] * 3 + [s.initial_bias_sigma**2] * 3)
        self.P = np.array(np.broadcast_to(p0, (self.n, 6, 6)))
        self._history: dict[int, tuple] = {}  # step -> (prior q, b, P, gyro reading) at that step
        self.dropped = 0  # star tracker reports older than the history (latency_steps)

    def _propagate(self, q, b, P, omega_meas):
        w = omega_meas - b
        q = quat_normalize(quat_multiply(q, rotation_quaternion(w * self.dt)))
        phi = transition(w, self.dt)
        P = phi @ P @ np.swapaxes(phi, -1, -2) + self.Q
        return q, b, 0.5 * (P + np.swapaxes(P, -1, -2))

    def _update(self, q, b, P, q_meas):
        z = attitude_error_B(q, q_meas)  # (P, 3)
        PHt = P[:, :, :3]  # P H^T, H = [I 0]
        S = P[:, :3, :3] + self.R
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)  # (P, 6, 3)
        dx = np.einsum("pij,pj->pi", K, z)
        ikh = np.eye(6) - np.concatenate([K, np.zeros((self.n, 6, 3))], axis=-1)
        P = ikh @ P @ np.swapaxes(ikh, -1, -2) + K @ self.R @ np.swapaxes(K, -1, -2)
        q = quat_normalize(quat_multiply(q, small_rotation(dx[:, :3])))
        return q, b + dx[:, 3:], 0.5 * (P + np.swapaxes(P, -1, -2))

    def step(self, k: int, omega_meas_B: np.ndarray, star_tracker=None) -> Estimate:
        """Step ``k``: propagate to t_k on the gyro reading (P, 3) of [t_(k-1), t_k], update with the
        tracker's report (or None), and return the estimate at t_k.

        ``star_tracker`` is a :class:`~attitude_sil.core.sensing.models.StarTrackerReport` (exposure step,
        q_BN (P, 4), valid).
        """
        if k != self.k:
            raise ScenarioError(f"estimator stepped at step {k}, expected step {self.k}")
        j = star_tracker.exposure_step if star_tracker is not None and star_tracker.valid else None
        if j is not None and j > k:  # refused before anything moves: the filter stays at step k - 1
            raise ScenarioError(f"estimator: a star tracker report at step {k} of exposure step {j}, after it")
        w_meas = np.asarray(omega_meas_B, dtype=float)
        if k > 0:
            self.q, self.b, self.P = self._propagate(self.q, self.b, self.P, w_meas)
        self._history[k] = (self.q, self.b, self.P, w_meas)
        if j is not None and j not in self._history:  # older than the filter keeps: dropped
            self.dropped += 1
        elif j is not None:
            q, b, P, w = self._history[j]
            q, b, P = self._update(q, b, P, star_tracker.q_BN)
            self._history[j] = (q, b, P, w)
            for i in range(j + 1, k + 1):
                w = self._history[i][3]
                q, b, P = self._propagate(q, b, P, w)
                self._history[i] = (q, b, P, w)
            self.q, self.b, self.P = q, b, P
        for old in [i for i in self._history if i < k + 1 - self.latency_steps]:
            del self._history[old]
        self.k = k + 1
        return Estimate(q_BN=self.q, omega_BN_B=w_meas - self.b, gyro_bias=self.b,
                        attitude_sigma=np.sqrt(np.diagonal(self.P, axis1=-2, axis2=-1)[:, :3]), cov=self.P)
