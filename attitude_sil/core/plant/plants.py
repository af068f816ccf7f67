"""Single-axis plant models of papers 002 and 004, batch over episodes.

Both are linear with inputs held over each control step, so each step is
integrated exactly with the matrix exponential of the augmented system
``[[A, B], [0, 0]]``. They present the same interface as
:class:`attitude_sil.core.sim.models.Plant` (``state.q_BN``, ``state.omega_BN_B``,
``advance``, ``reset``): the attitude is a rotation about the model's axis, so
the rest of the graph (controller, recorder, metrics) is unchanged.

* :class:`FlexibleAxisPlant` — paper 002 eq. 1-3: ``theta'' = b tau``,
  ``alpha'' = k1 tau - w^2 alpha``, total attitude ``y = theta + k2 alpha``.
  The published attitude is y about ``flex.axis``; alpha is published on its
  own topic. The torque is the actuator's plus the disturbance about the axis.
* :class:`PitchNormalizedPlant` — paper 004 eq. 1-2 in normalised units:
  ``theta' = q``, ``q' = -q + H/(1+eps) + e + T_d``, ``H' = T_d`` with the
  paper's disturbance rejection ``e = delta_e - H/(1+eps)`` applied to the
  controller's ``delta_e``, so ``q' = -q + delta_e + T_d``. Time is the paper's
  normalised time; the pitch axis is body y.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.plant.rigid_body import BodyState

__all__ = ["FLEXIBLE_CASES", "FlexibleAxisPlant", "PitchNormalizedPlant", "exact_discretization"]

#: paper 002 section IV.A: nominal and the four mismatch cases (k1, k2, omega^2)
FLEXIBLE_CASES = {
    "nominal": (0.076, 0.076, 4.509),
    "case1": (0.076, 0.076, 1.7),
    "case2": (0.76, 0.076, 4.509),
    "case3": (0.076, 0.114, 1.7),
    "case4": (0.114, 0.2, 1.7),
}


def exact_discretization(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma) with ``x[k+1] = Phi x[k] + Gamma u[k]`` for u held over dt.

    Parameters
    ----------
    a : (n, n), b : (n, m)
    """
    from scipy.linalg import expm  # here: scipy.linalg is a seventh of a node process's import time

    n, m = b.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = a
    aug[:n, n:] = b
    e = expm(aug * dt)
    return e[:n, :n], e[:n, n:]


def _axis_attitude(angle: np.ndarray, rate: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """q_BN and omega_BN_B of a rotation by ``angle`` (rad) about one body axis at ``rate`` (rad/s).

    ``quat_from_euler`` of an angle on one axis, written out: the same numbers
    (the other axes' products are exact zeros) without 12 trigonometric calls per step.
    """
    q = np.zeros(angle.shape + (4,))
    w = np.zeros(angle.shape + (3,))
    half = angle / 2
    q[..., axis] = np.sin(half)
    q[..., 3] = np.cos(half)
    w[..., axis] = rate
    return q, w


class FlexibleAxisPlant:
    """Flexible single-axis satellite (paper 002); state (theta, theta', alpha, alpha').

    Parameters
    ----------
    b, k1, k2, omega_sq : float or (P,) arrays
    axis : int, body axis
    dt : float, s
    theta0, rate0, alpha0 : (P,) initial rigid angle (rad), rigid rate (rad/s), deflection (rad)
    """

    def __init__(self, b, k1, k2, omega_sq, axis: int, dt: float, theta0, rate0, alpha0) -> None:
        self.axis = int(axis)
        self.dt = float(dt)
        self.theta0 = np.atleast_1d(np.asarray(theta0, dtype=float))
        n = self.theta0.shape[0]
        self.rate0 = np.broadcast_to(np.asarray(rate0, dtype=float), (n,)).copy()
        self.alpha0 = np.broadcast_to(np.asarray(alpha0, dtype=float), (n,)).copy()
        params = np.broadcast_to(np.stack(np.broadcast_arrays(
            np.asarray(b, float), np.asarray(k1, float), np.asarray(k2, float), np.asarray(omega_sq, float)),
            axis=-1), (n, 4))
        self.k2 = params[:, 2].copy()
        self.phi_T = np.empty((n, 4, 4))
        self.gamma = np.empty((n, 4))
        cache: dict[tuple, tuple] = {}
        for p in range(n):
            key = tuple(params[p])
            if key not in cache:
                bb, k1p, _, w2 = key
                a = np.array([[0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1], [0, 0, -w2, 0]], dtype=float)
                phi, gam = exact_discretization(a, np.array([[0.0], [bb], [0.0], [k1p]]), self.dt)
                cache[key] = (phi.T, gam[:, 0])
            self.phi_T[p], self.gamma[p] = cache[key]
        self.reset()

    @property
    def n_episodes(self) -> int:
        return self.theta0.shape[0]

    def reset(self) -> None:
        self.x = np.stack([self.theta0, self.rate0, self.alpha0, np.zeros_like(self.theta0)], axis=-1)
        self._publish_state()

    def _publish_state(self) -> None:
        y = self.x[:, 0] + self.k2 * self.x[:, 2]
        y_dot = self.x[:, 1] + self.k2 * self.x[:, 3]
        q, w = _axis_attitude(y, y_dot, self.axis)
        self.state = BodyState(q, w, np.zeros_like(w))

    @property
    def alpha(self) -> np.ndarray:
        """(P, 2): flexible deflection alpha (rad) and its rate (rad/s)."""
        return self.x[:, 2:4]

    def advance(self, tau_c_B: np.ndarray, h_wheels_B: np.ndarray, tau_ext_B: np.ndarray) -> BodyState:
        """Integrate one step exactly with the torque about the axis held."""
        u = np.asarray(tau_c_B)[:, self.axis] + np.asarray(tau_ext_B)[:, self.axis]
        self.x = np.einsum("pi,pij->pj", self.x, self.phi_T) + u[:, None] * self.gamma
        self._publish_state()
        return self.state


class PitchNormalizedPlant:
    """Normalised pitch axis with a reaction wheel (paper 004); state (theta, q, H).

    Parameters
    ----------
    epsilon : float, wheel-to-satellite inertia ratio (enters only through the
        applied voltage e = delta_e - H/(1+eps), which the state does not need)
    dt : float, normalised time step
    theta0, q0, h0 : (P,) initial angle (rad), normalised rate and momentum
    """

    axis = 1

    def __init__(self, epsilon: float, dt: float, theta0, q0, h0) -> None:
        self.epsilon = float(epsilon)
        self.dt = float(dt)
        self.theta0 = np.atleast_1d(np.asarray(theta0, dtype=float))
        n = self.theta0.shape[0]
        self.q0 = np.broadcast_to(np.asarray(q0, dtype=float), (n,)).copy()
        self.h0 = np.broadcast_to(np.asarray(h0, dtype=float), (n,)).copy()
        a = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0]])
        b = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]])  # inputs (delta_e, T_d)
        phi, gam = exact_discretization(a, b, self.dt)
        self.phi_T, self.gamma_T = phi.T.copy(), gam.T.copy()
        self.reset()

    @property
    def n_episodes(self) -> int:
        return self.theta0.shape[0]

    def reset(self) -> None:
        self.x = np.stack([self.theta0, self.q0, self.h0], axis=-1)
        self._publish_state()

    def _publish_state(self) -> None:
        q, w = _axis_attitude(self.x[:, 0], self.x[:, 1], self.axis)
        self.state = BodyState(q, w, np.zeros_like(w))

    @property
    def momentum(self) -> np.ndarray:
        """(P,) normalised total momentum H."""
        return self.x[:, 2]

    def advance(self, tau_c_B: np.ndarray, h_wheels_B: np.ndarray, tau_ext_B: np.ndarray) -> BodyState:
        """One exact step with delta_e (actuator output about pitch) and T_d held."""
        u = np.stack([np.asarray(tau_c_B)[:, 1], np.asarray(tau_ext_B)[:, 1]], axis=-1)
        self.x = self.x @ self.phi_T + u @ self.gamma_T
        self._publish_state()
        return self.state
