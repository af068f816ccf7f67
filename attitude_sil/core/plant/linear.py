"""The linearised spacecraft model of paper 000 (eq. 20-28), as matrices and as a plant.

State ``x = (ω̃ (3), g̃ (3), h̃ (3))``: body rate, quaternion vector part and
wheel momentum, deviations from an operating point ``(ω_0, g = 0, h_0)``;
input the control torque ``N_c`` (3)::

    ẋ = A x + B_u N_c,
    A = [[I^-1 A_ωω, 0, I^-1 A_ωh], [½ I_3, 0, 0], [0, 0, 0]],   B_u = [I^-1; 0; -I_3]

with ``A_ωω = -∂(ω × (I ω + h))/∂ω`` and ``A_ωh = -S(ω_0)`` at the operating
point (eq. 22-26). The Jacobian is computed from eq. 4 here: the printed
eq. 23-25 flip the signs of the inertia terms relative to their h terms (at
the usual operating point ω_0 = 0, h_0 = 0 both vanish and the model is the
double integrator ``ω̇ = I^-1 N_c``, ``ġ = ω/2``).

:func:`linear_model` gives (A, B) for analysis (python-control, root locus);
:class:`LinearizedPlant` runs the same model in the lockstep (plant
``model: linearized``), integrated exactly per held step, with the attitude
published as the unit quaternion of ``(g, 1)`` - the paper's "scalar element
assumed to be 1".
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.plant.plants import exact_discretization
from attitude_sil.core.plant.quaternion import cross_matrix
from attitude_sil.core.plant.rigid_body import BodyState

__all__ = ["linear_model", "LinearizedPlant"]


def linear_model(inertia: np.ndarray, omega0: np.ndarray | None = None,
                 h0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(A (9, 9), B (9, 3)) of paper 000 eq. 20-28 at the operating point (ω_0, h_0).

    Parameters
    ----------
    inertia : (3, 3) kg m^2
    omega0 : (3,) rad/s, default 0
    h0 : (3,) N m s, default 0
    """
    inertia = np.asarray(inertia, dtype=float)
    w = np.zeros(3) if omega0 is None else np.asarray(omega0, dtype=float)
    h = np.zeros(3) if h0 is None else np.asarray(h0, dtype=float)
    inv = np.linalg.inv(inertia)
    # d(ω × (Iω + h))/dω = S(ω) I - S(Iω + h)
    a_ww = -(cross_matrix(w) @ inertia - cross_matrix(inertia @ w + h))
    a_wh = -cross_matrix(w)
    a = np.zeros((9, 9))
    a[0:3, 0:3] = inv @ a_ww
    a[0:3, 6:9] = inv @ a_wh
    a[3:6, 0:3] = 0.5 * np.eye(3)
    b = np.zeros((9, 3))
    b[0:3] = inv
    b[6:9] = -np.eye(3)
    return a, b


class LinearizedPlant:
    """Paper 000's linearised body in the lockstep; see the module docstring.

    The control torque input is the wheels' mean torque plus the external
    torque (eq. 20 has ``N_e = 0``; adding it keeps disturbances comparable).
    The wheel momentum is a state of the model, so the wheels' message is not used.
    """

    def __init__(self, inertia: np.ndarray, dt: float, q0: np.ndarray, omega0: np.ndarray) -> None:
        self.dt = float(dt)
        self.q0 = np.asarray(q0, dtype=float)
        self.omega0 = np.asarray(omega0, dtype=float)
        n = self.q0.shape[0]
        inertia = np.broadcast_to(np.asarray(inertia, dtype=float), (n, 3, 3))
        self.phi_T = np.empty((n, 9, 9))
        self.gamma_T = np.empty((n, 3, 9))
        for p in range(n):
            a, b = linear_model(inertia[p], self.omega0[p])
            phi, gam = exact_discretization(a, b, self.dt)
            self.phi_T[p], self.gamma_T[p] = phi.T, gam.T
        self.reset()

    @property
    def n_episodes(self) -> int:
        return self.q0.shape[0]

    def reset(self) -> None:
        sign = np.where(self.q0[:, 3:4] < 0, -1.0, 1.0)
        g0 = (self.q0 * sign)[:, :3] / np.abs(self.q0[:, 3:4])  # vector part of (g, 1)
        self.x = np.concatenate([np.zeros_like(self.omega0), g0, np.zeros_like(self.omega0)], axis=-1)
        self._publish_state()

    def _publish_state(self) -> None:
        g = self.x[:, 3:6]
        q = np.concatenate([g, np.ones((g.shape[0], 1))], axis=-1)
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        self.state = BodyState(q, self.omega0 + self.x[:, 0:3], self.x[:, 6:9])

    def advance(self, tau_c_B: np.ndarray, h_wheels_B: np.ndarray, tau_ext_B: np.ndarray) -> BodyState:
        """One exact step with the torque held."""
        u = np.asarray(tau_c_B, dtype=float) + np.asarray(tau_ext_B, dtype=float)
        self.x = np.einsum("pi,pij->pj", self.x, self.phi_T) + np.einsum("pi,pij->pj", u, self.gamma_T)
        self._publish_state()
        return self.state

