"""Momentum management: the cross-product law that dumps the wheels' momentum through the magnetorquers.

Beside any attitude law (``momentum.mode: cross_product``), each step the
controller commands the dipole

    m = k (h_err x B) / |B|^2,   h_err = h_w - h_target,

whose torque m x B = -k (I - b b^T) h_err (b = B / |B|) is the component of
-k h_err normal to the field: the attitude law holds the body, so the wheels
take that torque and h_err decays at rate k along the directions the field
sweeps (Camillo and Markley's cross-product law; Basilisk's
``mtbMomentumManagement`` and 42's H x B unloading are this law). Over an
orbit the decay is exp(-k <I - b b^T> t), <.> the orbit average in B; a
direction the field never leaves cannot be dumped.

Its parameters are the controller's (``momentum.*``,
:data:`MOMENTUM_PARAMS`), so no attitude law changes. :class:`DipoleCommand`
is the controller's magnetic channel: this law, or B-dot while ``bdot`` is
the active law, or, on a spacecraft with no wheels (``torque_actuator:
magnetorquers``), the attitude law's torque demand tau made by the rods:

    m = B x tau / |B|^2,   m x B = (I - b b^T) tau,

the demand's component normal to the field (Basilisk's ``torque2Dipole``);
the component along B is lost.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from attitude_sil.core.control.laws.bdot import LAW as BDOT_LAW
from attitude_sil.core.control.laws.bdot import BDot
from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.paramspec import double as _d
from attitude_sil.core.paramspec import double_array as _da

__all__ = ["MOMENTUM_MODES", "TORQUE_ACTUATORS", "torque_dipole", "MOMENTUM_PARAMS", "CrossProductDumping",
           "DipoleCommand", "BDOT", "PER_EPISODE_SCALARS"]

#: the law whose dipole is B-dot's (``controller_type: bdot``)
BDOT = BDOT_LAW.name

#: ``momentum.mode`` values
MOMENTUM_MODES = ("none", "cross_product")

#: ``torque_actuator`` values: where a torque law's demand goes
TORQUE_ACTUATORS = ("wheels", "magnetorquers")

#: the controller's magnetic channel's parameters: momentum management, and the rods as the torque actuator
MOMENTUM_PARAMS = [
    ParamSpec("torque_actuator", "string", "wheels",
              "where a torque law's demand goes: wheels (torque_cmd, made by the wheels node) or magnetorquers "
              "(a spacecraft on rods alone, wheels actuator none: the dipole B x tau / |B|^2 on dipole_cmd, which "
              "makes the demand's component normal to the field; torque_cmd carries the demand, unmade)",
              choices=TORQUE_ACTUATORS),
    ParamSpec("momentum.mode", "string", "none",
              "momentum management beside the attitude law: none, or cross_product (the dipole k (h_w - "
              "h_target) x B / |B|^2 on dipole_cmd, for the magnetorquers; needs a field model)",
              choices=MOMENTUM_MODES),
    _d("momentum.gain", 1.0e-3, "gain k of the cross-product law, 1/s (the decay rate of the wheel momentum "
       "normal to the field; assumed: a time constant of a sixth of a low orbit)", min=0.0, runtime=True),
    _da("momentum.target", [0.0, 0.0, 0.0], "wheel momentum the law dumps towards, N m s in B", lengths=(3,),
        runtime=True),
]


#: the magnetic channel's scalar parameters it takes one per episode (a batch's candidates in one run; a law's
#: record holds a scalar once for all its episodes)
PER_EPISODE_SCALARS = ("momentum.gain", f"{BDOT}.gain")


@njit(cache=True, inline="always")
def torque_dipole_row(tau_B, b_B, p, out) -> None:
    """Row ``p``: the dipole m = B x tau / |B|^2 into ``out`` (., 3) A m^2 for the torque demand ``tau_B`` (., 3)
    N m in the field ``b_B`` (., 3) tesla (zero where the field is zero)."""
    b0, b1, b2 = b_B[p, 0], b_B[p, 1], b_B[p, 2]
    t0, t1, t2 = tau_B[p, 0], tau_B[p, 1], tau_B[p, 2]
    bb = b0 * b0 + b1 * b1 + b2 * b2
    out[p, 0] = out[p, 1] = out[p, 2] = 0.0
    if bb > 0.0:
        out[p, 0] = (b1 * t2 - b2 * t1) / bb
        out[p, 1] = (b2 * t0 - b0 * t2) / bb
        out[p, 2] = (b0 * t1 - b1 * t0) / bb


@njit(cache=True, inline="always")
def dumping_row(h_wheels_B, b_B, p, gain, target_B, out) -> None:
    """Row ``p``: the cross-product law's dipole m = k (h_w - h_target) x B / |B|^2 into ``out`` (., 3) A m^2,
    gain ``gain`` 1/s, target ``target_B`` (3,) N m s (zero where the field is zero)."""
    b0, b1, b2 = b_B[p, 0], b_B[p, 1], b_B[p, 2]
    a0, a1, a2 = h_wheels_B[p, 0] - target_B[0], h_wheels_B[p, 1] - target_B[1], h_wheels_B[p, 2] - target_B[2]
    bb = b0 * b0 + b1 * b1 + b2 * b2
    out[p, 0] = out[p, 1] = out[p, 2] = 0.0
    if bb > 0.0:
        out[p, 0] = gain * (a1 * b2 - a2 * b1) / bb
        out[p, 1] = gain * (a2 * b0 - a0 * b2) / bb
        out[p, 2] = gain * (a0 * b1 - a1 * b0) / bb


@njit(cache=True)
def _torque_dipoles(tau_B, b_B, out) -> None:
    for p in range(b_B.shape[0]):
        torque_dipole_row(tau_B, b_B, p, out)


@njit(cache=True)
def _dumping_dipoles(h_wheels_B, b_B, gain, target_B, out) -> None:
    # gain (P,) or one for all, target (P, 3) or one for all
    for p in range(b_B.shape[0]):
        dumping_row(h_wheels_B, b_B, p, gain[p if gain.shape[0] > 1 else 0],
                    target_B[p if target_B.shape[0] > 1 else 0], out)


def torque_dipole(tau_B: np.ndarray, b_B: np.ndarray) -> np.ndarray:
    """The dipole (P, 3) A m^2 whose torque in the field ``b_B`` (P, 3) tesla is the component of ``tau_B``
    (P, 3) N m normal to it: m = B x tau / |B|^2 (zero where the field is zero), both in B
    (:func:`torque_dipole_row`)."""
    b = np.ascontiguousarray(b_B, dtype=float)
    out = np.empty_like(b)
    _torque_dipoles(np.ascontiguousarray(np.broadcast_to(tau_B, b.shape), dtype=float), b, out)
    return out


class CrossProductDumping:
    """The cross-product law of P episodes, gain ``gain`` 1/s (scalar or (P,)) towards ``target_B`` N m s
    ((3,) or (P, 3))."""

    def __init__(self, gain, target_B) -> None:
        self.gain = np.ascontiguousarray(np.asarray(gain, dtype=float).reshape(-1))
        self.target_B = np.ascontiguousarray(np.asarray(target_B, dtype=float).reshape(-1, 3))

    def dipole(self, h_wheels_B: np.ndarray, b_B: np.ndarray) -> np.ndarray:
        """The dipole command (P, 3) A m^2 for wheel momenta ``h_wheels_B`` (P, 3) N m s in the field ``b_B``
        (P, 3) tesla, both in B (zero where the field is zero; :func:`dumping_row`)."""
        b = np.ascontiguousarray(b_B, dtype=float)
        out = np.empty_like(b)
        _dumping_dipoles(np.ascontiguousarray(np.broadcast_to(h_wheels_B, b.shape), dtype=float), b, self.gain,
                         self.target_B, out)
        return out


class DipoleCommand:
    """The controller's dipole each step: B-dot (:class:`~attitude_sil.core.control.laws.bdot.BDot`) while
    ``bdot`` is the active law, else the attitude law's torque demand through the rods where they are the
    torque actuator (``torque_rods``), else the momentum law ``dumping`` (None: ``momentum.mode: none``, no
    dipole).

    B-dot's difference runs every step, whichever law is active, so a swap to
    it starts from the previous step's field, not from zero.
    """

    def __init__(self, dumping: CrossProductDumping | None, bdot: BDot, torque_rods: bool = False) -> None:
        self.dumping = dumping
        self.bdot = bdot
        self.torque_rods = torque_rods

    def dipole(self, active: str, h_wheels_B: np.ndarray, b_B: np.ndarray,
               tau_cmd_B: np.ndarray | None = None) -> np.ndarray:
        """The dipole command (P, 3) A m^2 of step k under law ``active``, from the wheel momentum
        ``h_wheels_B`` (P, 3) N m s, the field read ``b_B`` (P, 3) tesla and the law's torque demand
        ``tau_cmd_B`` (P, 3) N m (read with ``torque_rods`` only), all at t_k in B."""
        m_bdot = self.bdot.dipole(b_B)
        if active == BDOT:
            return m_bdot
        if self.torque_rods:
            return torque_dipole(tau_cmd_B, b_B)
        if self.dumping is None:
            return np.zeros_like(m_bdot)
        return self.dumping.dipole(h_wheels_B, b_B)
