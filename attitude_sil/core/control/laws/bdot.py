"""``bdot``: magnetic detumbling, B-dot (Avanzini and Giulietti 2012); the wheels idle.

While ``bdot`` is the active law the controller commands the magnetorquers

    m = -(k / |B|) db/dt,   b = B / |B|,

from the field it reads (``magnetic_field``, or the ``magnetometer`` with
``feedback: estimate``), db/dt the backward difference of b over the control
period (zero at an episode's first step). For a body turning fast against
the orbit db/dt is about -omega x b, so the torque m x B is about
-k (I - b b^T) omega: it damps the body rate normal to the field. Avanzini and Giulietti (J. Guid. Control Dyn.
35(4), 2012, "Magnetic detumbling of a rigid spacecraft") give the gain of
fastest decay, k* = 2 n (1 + sin xi_m) J_min (:func:`detumble_gain`): n the
mean motion, xi_m the orbit's inclination to the geomagnetic equator, J_min
the smallest principal inertia. ``bdot.gain`` 0 (the default) takes it: the
runner fills it in from the plant's orbit and inertia.

The attitude command (the law's compiled step) is zero: the wheels hold
still. The dipole itself is :class:`BDot`, run by the controller's magnetic
channel (:class:`attitude_sil.core.control.momentum.DipoleCommand`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.control.law import Law
from attitude_sil.core.paramspec import double

__all__ = ["LAW", "BDot", "detumble_gain"]


class Params(NamedTuple):
    """B-dot's record: nothing the attitude step reads."""

    u_max: float


@njit(cache=True, inline="always")
def step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u):
    """The attitude command: zero, the wheels idle (the dipole is the magnetic channel's)."""
    for i in range(3):
        u[p, i] = 0.0


def _record(values, n: int, dt: float) -> Params:
    return Params(float(values["output_limit"]))


def detumble_gain(mean_motion: float, xi_m: float, j_min: float) -> float:
    """Avanzini and Giulietti's k* = 2 n (1 + sin xi_m) J_min, N m s, for the mean motion ``mean_motion``
    rad/s, the orbit's inclination to the geomagnetic equator ``xi_m`` rad and the smallest principal
    inertia ``j_min`` kg m^2."""
    return 2.0 * mean_motion * (1.0 + math.sin(xi_m)) * j_min


@njit(cache=True, inline="always")
def bdot_row(b_B, p, previous, has_previous, gain, dt, out) -> None:
    """Row ``p``: B-dot's dipole into ``out`` (., 3) A m^2 for the field read ``b_B`` (., 3) tesla, gain ``gain``
    N m s, from the last reading's direction ``previous`` (., 3) (``has_previous`` False: the episode's first
    step, no dipole), which becomes this reading's (zero where the field is zero)."""
    b0, b1, b2 = b_B[p, 0], b_B[p, 1], b_B[p, 2]
    norm = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    u0 = u1 = u2 = 0.0
    if norm > 0.0:
        u0, u1, u2 = b0 / norm, b1 / norm, b2 / norm
    out[p, 0] = out[p, 1] = out[p, 2] = 0.0
    if has_previous and norm > 0.0:
        out[p, 0] = -gain * ((u0 - previous[p, 0]) / dt) / norm
        out[p, 1] = -gain * ((u1 - previous[p, 1]) / dt) / norm
        out[p, 2] = -gain * ((u2 - previous[p, 2]) / dt) / norm
    previous[p, 0], previous[p, 1], previous[p, 2] = u0, u1, u2


@njit(cache=True)
def _bdot_rows(b_B, previous, has_previous, gain, dt, out) -> None:
    # every row, gain (P,) or one for all
    for p in range(b_B.shape[0]):
        bdot_row(b_B, p, previous, has_previous, gain[p if gain.shape[0] > 1 else 0], dt, out)


class BDot:
    """The B-dot dipole of P episodes, gains ``gain`` (P,) or scalar, N m s, control period ``dt`` s."""

    def __init__(self, gain, dt: float) -> None:
        self.gain = np.ascontiguousarray(np.asarray(gain, dtype=float).reshape(-1))
        self.dt = float(dt)
        self.previous: np.ndarray | None = None  # the last reading's direction (P, 3)

    def dipole(self, b_B: np.ndarray) -> np.ndarray:
        """The dipole (P, 3) A m^2 for the field read this step ``b_B`` (P, 3) tesla in B (:func:`bdot_row`);
        remembers its direction for the next step's difference (zero at the first step and where the field is
        zero)."""
        b = np.ascontiguousarray(b_B, dtype=float)
        first = self.previous is None
        if first:
            self.previous = np.zeros_like(b)
        m = np.empty_like(b)
        _bdot_rows(b, self.previous, not first, self.gain, self.dt, m)
        return m


LAW = Law(
    name="bdot",
    summary="B-dot magnetic detumbling, m = -(k/|B|) db/dt (Avanzini and Giulietti 2012); the wheels idle",
    params=(
        double("gain", 0.0, "gain k, N m s (0: Avanzini and Giulietti's k* = 2 n (1 + sin xi_m) J_min, which "
               "the runner fills in from the plant's orbit and inertia)", min=0.0),
    ),
    state={},
    record=_record,
    step=step,
)
