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

from attitude_sil.core.plant.quaternion import cross
from attitude_sil.errors import ScenarioError

__all__ = ["Magnetorquers", "rod_axes"]


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
        self.axes = np.asarray(axes, dtype=float)
        self.max_dipole = float(max_dipole)
        self.allocation = np.linalg.pinv(self.axes.T)  # (n, 3): the rods' minimum-norm share of a body dipole

    @property
    def n_rods(self) -> int:
        return self.axes.shape[0]

    def rod_dipoles(self, m_cmd_B: np.ndarray) -> np.ndarray:
        """Each rod's dipole (P, n) A m^2 for body dipole commands ``m_cmd_B`` (P, 3), clipped rod by rod."""
        d = np.asarray(m_cmd_B, dtype=float) @ self.allocation.T
        return np.clip(d, -self.max_dipole, self.max_dipole)

    def dipole_B(self, m_cmd_B: np.ndarray) -> np.ndarray:
        """The body dipole (P, 3) A m^2 the rods make for ``m_cmd_B`` (P, 3): A^T d."""
        return self.rod_dipoles(m_cmd_B) @ self.axes

    def torque(self, m_cmd_B: np.ndarray, b_B: np.ndarray) -> np.ndarray:
        """The torque on the body (P, 3) N m, m x B, for commands ``m_cmd_B`` (P, 3) A m^2 in the field
        ``b_B`` (P, 3) tesla in B."""
        return cross(self.dipole_B(m_cmd_B), np.asarray(b_B, dtype=float))
