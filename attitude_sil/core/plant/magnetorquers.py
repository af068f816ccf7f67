"""Magnetic torquer rods: a body dipole command made by a set of rods, each saturated, and the torque m x B.

A rod i lies along the unit axis a_i (in B) and makes a dipole d_i a_i,
|d_i| <= d_max. The rods' layout is the matrix A (n, 3) whose rows are the
a_i, so three orthogonal rods (paper 001: Hawai'iSat-1's three 25 A m^2 rods)
and HST's four bars (paper 000: "four magnetorquer bars") are one model.
A body dipole command m_cmd is shared among the rods by the minimum-norm
solution of A^T d = m_cmd, d = pinv(A^T) m_cmd; each rod is then clipped to
+-d_max on its own (a rod's driver saturates alone, so a large command turns
as well as shrinks); the body dipole made is m = A^T d and the torque on the
body, held over the step with the field of its start, is tau = m x B.
Nothing along the field can be made: m x B is normal to B.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from attitude_sil.core.faults import HeldFaults
from attitude_sil.errors import ScenarioError

__all__ = ["Magnetorquers", "rod_axes", "rods_torque_row"]


def rod_axes(flat, where: str = "magnetorquers.rods.axes") -> np.ndarray:
    """The rods' unit axes (n, 3) from ``flat`` (3 n values, row by row, in B).

    Raises
    ------
    ScenarioError
        Not a whole number of 3-vectors, a zero axis, or axes that do not span
        the three body axes (some dipole could never be made).
    """
    a = np.asarray(flat, dtype=float)
    if a.size == 0 or a.size % 3:
        raise ScenarioError(f"{where}: {a.size} values; give 3 per rod (its axis in B), row by row")
    a = a.reshape(-1, 3)
    norms = np.linalg.norm(a, axis=1)
    if np.any(norms == 0.0):
        raise ScenarioError(f"{where}: rod {int(np.argmin(norms)) + 1} has a zero axis")
    a = a / norms[:, None]
    if np.linalg.matrix_rank(a) < 3:
        raise ScenarioError(f"{where}: the rods' axes span fewer than 3 body axes; some dipoles cannot be made")
    return a


class Magnetorquers:
    """Rods along ``axes`` (n, 3) in B, each saturated at ``max_dipole`` A m^2.

    Parameters
    ----------
    axes : (n, 3)
        Unit axes of the rods in B (:func:`rod_axes`).
    max_dipole : float
        Saturation of each rod, A m^2.
    """

    def __init__(self, axes: np.ndarray, max_dipole: float) -> None:
        self.axes = np.ascontiguousarray(axes, dtype=float)
        self.max_dipole = float(max_dipole)
        # (n, 3): the rods' minimum-norm share of a body dipole
        self.allocation = np.ascontiguousarray(np.linalg.pinv(self.axes.T))
        self.faults = HeldFaults()  # off and stuck, on the command

    def command_at(self, m_cmd_B: np.ndarray, k: int) -> np.ndarray:
        """The dipole command (P, 3) the rods take at step ``k``: ``m_cmd_B``, or while a fault is active none
        (``off``) or the one of the step before it (``stuck``: the drivers hold their last current)."""
        return self.faults.apply(np.asarray(m_cmd_B, dtype=float), k)

    @property
    def n_rods(self) -> int:
        return self.axes.shape[0]

    def rod_dipoles(self, m_cmd_B: np.ndarray) -> np.ndarray:
        """Each rod's dipole (P, n) A m^2 for body dipole commands ``m_cmd_B`` (P, 3), clipped rod by rod."""
        return self._run(m_cmd_B, 0.0)[0]

    def dipole_B(self, m_cmd_B: np.ndarray) -> np.ndarray:
        """The body dipole (P, 3) A m^2 the rods make for ``m_cmd_B`` (P, 3): A^T d."""
        return self._run(m_cmd_B, 0.0)[1]

    def torque(self, m_cmd_B: np.ndarray, b_B: np.ndarray) -> np.ndarray:
        """The torque on the body (P, 3) N m, m x B, for commands ``m_cmd_B`` (P, 3) A m^2 in the field
        ``b_B`` (P, 3) tesla in B (:func:`rods_torque_row`)."""
        return self._run(m_cmd_B, b_B)[2]

    def _run(self, m_cmd_B, b_B) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # the rods' dipoles, the body dipole they make and its torque in the field b_B (0.0: none)
        m = np.ascontiguousarray(m_cmd_B, dtype=float)
        d, made, tau = np.empty((m.shape[0], self.n_rods)), np.empty_like(m), np.empty_like(m)
        _rods_torques(m, np.ascontiguousarray(np.broadcast_to(b_B, m.shape), dtype=float), self.axes,
                      self.allocation, self.max_dipole, d, made, tau)
        return d, made, tau


@njit(cache=True, inline="always")
def rods_torque_row(m_cmd_B, b_B, p, axes, allocation, max_dipole, d, made, tau) -> None:
    """Row ``p``: the rods' dipoles ``d`` (., n) for the command ``m_cmd_B`` (., 3) A m^2 (allocation (n, 3),
    each clipped to +-``max_dipole``), the body dipole they make ``made`` (., 3) = A^T d and its torque in the
    field ``b_B`` (., 3) tesla, ``tau`` (., 3) = made x B, N m."""
    n = axes.shape[0]
    m0, m1, m2 = m_cmd_B[p, 0], m_cmd_B[p, 1], m_cmd_B[p, 2]
    for i in range(n):
        di = m0 * allocation[i, 0] + m1 * allocation[i, 1] + m2 * allocation[i, 2]
        d[p, i] = min(max(di, -max_dipole), max_dipole)
    for j in range(3):
        acc = 0.0
        for i in range(n):
            acc += d[p, i] * axes[i, j]
        made[p, j] = acc
    a0, a1, a2 = made[p, 0], made[p, 1], made[p, 2]
    b0, b1, b2 = b_B[p, 0], b_B[p, 1], b_B[p, 2]
    tau[p, 0] = a1 * b2 - a2 * b1
    tau[p, 1] = a2 * b0 - a0 * b2
    tau[p, 2] = a0 * b1 - a1 * b0


@njit(cache=True)
def _rods_torques(m_cmd_B, b_B, axes, allocation, max_dipole, d, made, tau) -> None:
    for p in range(m_cmd_B.shape[0]):
        rods_torque_row(m_cmd_B, b_B, p, axes, allocation, max_dipole, d, made, tau)
