"""``usque``: the unscented quaternion estimator, the example of an attitude filter in a package of its own.

This file is the whole filter. Installed with ``pip install ./examples/custom_estimator``,
it registers through the entry point ``attitude_sil.estimators`` (see
``pyproject.toml``) and is then an ``estimator.type`` like the built-in
``mekf``: in the graph's ``estimator`` node, the stepwise driver, ``tune`` and
``montecarlo``. The guide is docs/sensors.md of attitude_sil.

The filter is USQUE (Crassidis and Markley, "Unscented filtering for
spacecraft attitude estimation", JGCD 26(4), 2003), on the gyro and star
tracker models of attitude_sil. Its error state is x = (dp, db): dp the
generalised Rodrigues parameters of the attitude error (a = 1, f = 2 (a + 1),
their eqs. 32-33: about the rotation vector for small angles) and db the gyro
bias error. Where the MEKF propagates one estimate and a linearised
covariance, USQUE propagates 2n + 1 = 13 sigma points through the exact
attitude kinematics (their eqs. 34-42):

* sigma points from ``(n + lambda) (P + Qbar)`` (Cholesky columns, both
  signs), Qbar = dt/2 [(sigma_v^2 - sigma_u^2 dt^2 / 6) I, 0; 0, sigma_u^2 I]
  (their eq. 43);
* each point's attitude q_i = q ⊗ dq(dp_i) and bias b_i, propagated with its
  own rate omega - b_i over dt;
* their errors dp_i about the propagated centre point, the mean and the
  covariance with weights lambda / (n + lambda) and 1 / (2 (n + lambda)),
  plus Qbar; the mean error is then folded into the attitude and reset to 0.

A star tracker report is an attitude: its residual is the GRP of
q_est* ⊗ q_meas, a measurement of dp with the tracker's noise. The model is
linear in the state, so the unscented update is the Kalman update with
H = [I 0] (Joseph form); the correction is folded into the attitude. A late
report rolls back to its exposure and propagates again, as attitude_sil's
MEKF does, as far back as ``reach_steps``; an older one is dropped.

Quaternions are (x, y, z, w), q_BN; the error is in the body frame,
q_true = q_est ⊗ dq, as everywhere in attitude_sil.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.plant.quaternion import quat_conjugate, quat_multiply, quat_normalize, rotation_quaternion
from attitude_sil.core.sensing.estimator import Estimate, Estimator
from attitude_sil.core.sensing.mekf import R_FLOOR, MekfSettings

A, F = 1.0, 4.0  # the GRP's a and f = 2 (a + 1)
N = 6  # the error state's dimension


def grp(dq: np.ndarray) -> np.ndarray:
    """The GRP (..., 3) of error quaternions dq (..., 4), the short way (their eq. 33)."""
    dq = np.where(dq[..., 3:4] < 0.0, -dq, dq)
    return F * dq[..., :3] / (A + dq[..., 3:4])


def grp_quaternion(dp: np.ndarray) -> np.ndarray:
    """The error quaternion (..., 4) of GRP dp (..., 3) (their eq. 32, with a = 1)."""
    s = np.sum(dp * dp, axis=-1, keepdims=True)
    w = (-A * s + F * np.sqrt(F * F + (1.0 - A * A) * s)) / (F * F + s)
    return np.concatenate([(A + w) * dp / F, w], axis=-1)


class Usque:
    """USQUE on P episodes (module docstring), stepped as attitude_sil's drivers step a filter."""

    def __init__(self, settings: MekfSettings, dt: float, n_episodes: int, reach_steps: int, lam: float) -> None:
        self.dt, self.n, self.reach, self.lam = float(dt), int(n_episodes), int(reach_steps), float(lam)
        sv, su = settings.gyro_arw, settings.bias_walk
        self.Qbar = 0.5 * self.dt * np.diag([sv**2 - su**2 * self.dt**2 / 6.0] * 3 + [su**2] * 3)
        self.W0, self.Wi = self.lam / (N + self.lam), 0.5 / (N + self.lam)
        self.set_star_tracker_variance(np.asarray(settings.star_tracker_sigma, dtype=float) ** 2)
        self.q = np.array(np.broadcast_to(quat_normalize(settings.initial_q_BN), (self.n, 4)))
        self.b = np.zeros((self.n, 3))
        p0 = np.diag([settings.initial_attitude_sigma**2] * 3 + [settings.initial_bias_sigma**2] * 3)
        self.P = np.array(np.broadcast_to(p0, (self.n, N, N)))
        self.k = 0
        self.dropped = 0
        self._history: dict[int, tuple] = {}  # step -> (prior q, b, P, gyro reading)

    def set_star_tracker_variance(self, variance: np.ndarray) -> None:
        """The tracker's variance (3,) rad^2, floored as the MEKF floors it (a perfect tracker would make the
        covariance singular, and its Cholesky factor fail)."""
        self.R = np.diag(np.maximum(np.sqrt(np.asarray(variance, dtype=float)), R_FLOOR) ** 2)

    def _propagate(self, q, b, P, w_meas):
        """The 13 sigma points of (q, b, P + Qbar) over one step on the gyro reading ``w_meas`` (P, 3)."""
        S = np.linalg.cholesky((N + self.lam) * (P + self.Qbar))  # (P, 6, 6), lower
        sig = np.concatenate([np.zeros((self.n, 1, N)), np.swapaxes(S, 1, 2), -np.swapaxes(S, 1, 2)], axis=1)
        q_i = quat_multiply(q[:, None], grp_quaternion(sig[..., :3]))  # (P, 13, 4)
        b_i = b[:, None] + sig[..., 3:]
        q_i = quat_normalize(quat_multiply(q_i, rotation_quaternion((w_meas[:, None] - b_i) * self.dt)))
        chi = np.concatenate([grp(quat_multiply(quat_conjugate(q_i[:, :1]), q_i)), b_i], axis=-1)
        weights = np.full(2 * N + 1, self.Wi)
        weights[0] = self.W0
        mean = np.einsum("i,pij->pj", weights, chi)
        d = chi - mean[:, None]
        P = np.einsum("i,pij,pik->pjk", weights, d, d) + self.Qbar
        return quat_normalize(quat_multiply(q_i[:, 0], grp_quaternion(mean[:, :3]))), mean[:, 3:], P

    def _update(self, q, b, P, q_meas):
        z = grp(quat_multiply(quat_conjugate(q), q_meas))  # the GRP of the residual rotation
        K = np.swapaxes(np.linalg.solve(P[:, :3, :3] + self.R, np.swapaxes(P[:, :, :3], 1, 2)), 1, 2)  # (P, 6, 3)
        dx = np.einsum("pij,pj->pi", K, z)
        ikh = np.eye(N) - np.concatenate([K, np.zeros((self.n, N, 3))], axis=-1)
        P = ikh @ P @ np.swapaxes(ikh, 1, 2) + K @ self.R @ np.swapaxes(K, 1, 2)
        return quat_normalize(quat_multiply(q, grp_quaternion(dx[:, :3]))), b + dx[:, 3:], 0.5 * (
            P + np.swapaxes(P, 1, 2))

    def step(self, k: int, omega_meas_B: np.ndarray, star_tracker=None) -> Estimate:
        """Step ``k``: propagate on the gyro reading (P, 3) of [t_(k-1), t_k], take the report due at k (or
        None), return the estimate at t_k."""
        j = star_tracker.exposure_step if star_tracker is not None and star_tracker.valid else None
        if k != self.k or (j is not None and j > k):  # refused before anything moves
            raise ValueError(f"usque stepped at step {k} (expected {self.k}) with a report of step {j}")
        w = np.asarray(omega_meas_B, dtype=float)
        if k > 0:
            self.q, self.b, self.P = self._propagate(self.q, self.b, self.P, w)
        self._history[k] = (self.q, self.b, self.P, w)
        if j is not None and j not in self._history:
            self.dropped += 1  # older than the filter keeps
        elif j is not None:
            q, b, P = self._update(*self._history[j][:3], star_tracker.q_BN)
            self._history[j] = (q, b, P, self._history[j][3])
            for i in range(j + 1, k + 1):
                q, b, P = self._propagate(q, b, P, self._history[i][3])
                self._history[i] = (q, b, P, self._history[i][3])
            self.q, self.b, self.P = q, b, P
        for old in [i for i in self._history if i < k + 1 - self.reach]:
            del self._history[old]
        self.k = k + 1
        return Estimate(q_BN=self.q, omega_BN_B=w - self.b, gyro_bias=self.b,
                        attitude_sigma=np.sqrt(np.diagonal(self.P, axis1=1, axis2=2)[:, :3]), cov=self.P)


def build(values: dict, gyro_arw: float, star_tracker_sigma: np.ndarray, dt: float, n_episodes: int,
          reach_steps: int) -> Usque:
    """USQUE of the ``estimator`` parameters (``lambda``: its own, the sigma points' spread)."""
    settings = MekfSettings.from_values(values, gyro_arw, star_tracker_sigma)
    return Usque(settings, dt, n_episodes, reach_steps, values["lambda"])


ESTIMATOR = Estimator(
    name="usque",
    description="unscented quaternion estimator (Crassidis and Markley 2003), the example plugin",
    build=build,
    params=(ParamSpec("lambda", "double", 1.0, "the sigma points' spread lambda (n + lambda scales the "
                      "covariance; 1 in Crassidis and Markley)", min=0.0, min_exclusive=True, max=100.0),),
)
