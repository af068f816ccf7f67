"""The orbit of an episode, step by step, as the guidance, the disturbances and the plant read it.

``orbit.model`` chooses it:

* ``circular`` (the default, as before): radius ``orbit.radius``, mean motion
  Omega_0 = sqrt(mu / r^3), LVLH at t = 0 from ``orbit.lvlh_initial_rpy_deg``
  turning about its y axis
  (:func:`~attitude_sil.core.plant.disturbance.lvlh_attitude`);
* ``keplerian_j2``: the classical elements ``orbit.semi_major_axis`` ...
  ``orbit.true_anomaly_deg`` at ``orbit.epoch``, propagated under two-body
  gravity and J2 (``orbit.j2``) by :class:`~.orbit.OrbitPropagator` in blocks
  of :data:`BLOCK_STEPS` steps, each from the end of the one before: every
  reader of an episode (a node, the stepwise engine) gets the same numbers
  whatever order it asks in. The LVLH frame and its rate come from r and v
  (:func:`~.orbit.lvlh_from_state`), the gravity-gradient gain is 3 mu / r^3
  and the speed |v|.

:class:`FieldAlongOrbit` is the geomagnetic field where the spacecraft is
(``environment.magnetic_field.model``): at the orbit's position, the Earth
turned by the sidereal angle of the epoch plus t, at the epoch's year.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from attitude_sil.core.environment.earth_time import decimal_year, epoch_from_text, gmst_rad, julian_date
from attitude_sil.core.environment.geomagnetic import FIELD_MODELS, field_eci, igrf_coefficients
from attitude_sil.core.environment.orbit import (
    J2_EARTH,
    R_EARTH,
    Elements,
    OrbitPropagator,
    gravity_acceleration,
    lvlh_from_state,
    norm3,
)
from attitude_sil.core.plant.disturbance import lvlh_attitude, orbit_rate
from attitude_sil.core.plant.quaternion import quat_from_euler, quat_to_dcm

__all__ = ["ORBIT_MODELS", "BLOCK_STEPS", "OrbitSample", "Ephemeris", "FieldAlongOrbit"]

#: ``orbit.model`` values
ORBIT_MODELS = ("circular", "keplerian_j2")
#: steps propagated at once (keplerian_j2)
BLOCK_STEPS = 1000
#: steps whose field is evaluated at once (:meth:`FieldAlongOrbit.field_N`)
FIELD_CHUNK = 4096


@dataclass(frozen=True)
class OrbitSample:
    """The orbit at one step.

    Attributes
    ----------
    q_LN : (4,) the LVLH frame (x y z w)
    omega_LN_L : (3,) its rate in L, rad/s
    gg_gain : float, 3 mu / r^3, 1/s^2
    speed : float, |v|, m/s
    r_N, v_N : (3,) position (m) and velocity (m/s) in N
    """

    q_LN: np.ndarray
    omega_LN_L: np.ndarray
    gg_gain: float
    speed: float
    r_N: np.ndarray
    v_N: np.ndarray


class Ephemeris:
    """The orbit of ``values`` (a node's ``orbit.*`` parameters) at the steps of period ``dt`` s."""

    def __init__(self, values: dict, dt: float) -> None:
        self.model = values.get("orbit.model", "circular")
        self.mu = float(values["orbit.mu"])
        self.dt_ns = int(round(dt * 1e9))
        self.epoch = epoch_from_text(values.get("orbit.epoch", "2026-01-01T00:00:00Z"), "orbit.epoch")
        if self.model == "circular":
            self.radius = float(values["orbit.radius"])
            self.rate = orbit_rate(self.mu, self.radius)
            self.q_LN0 = quat_from_euler(np.radians(values["orbit.lvlh_initial_rpy_deg"]))
            self.propagator = None
        else:
            el = Elements(values["orbit.semi_major_axis"], values["orbit.eccentricity"],
                          *(math.radians(values[f"orbit.{k}_deg"]) for k in ("inclination", "raan", "arg_perigee",
                                                                             "true_anomaly")))
            self.j2 = J2_EARTH if values["orbit.j2"] else 0.0
            self.propagator = OrbitPropagator(el.check("orbit"), self.mu, self.j2)
            self._starts = {0: (self.propagator.r0, self.propagator.v0)}  # block -> its first state
            self._block = -1
            self._states: tuple = ()  # the block's frames (_frames)

    def at(self, t_ns: int) -> OrbitSample:
        """The orbit at step time ``t_ns`` (ns, a whole number of steps)."""
        t = t_ns * 1e-9
        if self.propagator is None:
            q = lvlh_attitude(t, self.q_LN0, self.rate)
            r_L = np.array([0.0, 0.0, self.radius])
            v_L = np.array([self.radius * self.rate, 0.0, 0.0])
            r_nl = quat_to_dcm(q)
            return OrbitSample(q, np.array([0.0, self.rate, 0.0]), 3.0 * self.rate**2,
                               float(np.sqrt(self.mu / self.radius)), r_nl @ r_L, r_nl @ v_L)
        block, i = divmod(t_ns // self.dt_ns, BLOCK_STEPS)
        q, omega, gg, speed, r, v = self._frames(block)
        return OrbitSample(q[i], omega[i], float(gg[i]), float(speed[i]), r[i], v[i])

    def _frames(self, block: int) -> tuple:
        """Block ``block``'s steps (propagated from the block before's end): LVLH frames (n, 4) and rates (n, 3),
        3 mu / r^3 (n,), speeds (n,), positions and velocities (n, 3), computed for the whole block at once."""
        if block != self._block:
            for b in range(max(self._starts) + 1, block + 1):  # blocks not reached yet, in order
                r, v = self._propagate(b - 1)
                self._starts[b] = (r[-1], v[-1])
            r, v = self._propagate(block)
            q, omega = lvlh_from_state(r, v, gravity_acceleration(r, self.mu, self.j2, R_EARTH))
            self._states = (q, omega, 3.0 * self.mu / norm3(r) ** 3, norm3(v), r, v)
            self._block = block
        return self._states

    def _propagate(self, block: int) -> tuple[np.ndarray, np.ndarray]:
        """Block ``block``'s states at its BLOCK_STEPS + 1 steps, from its first state."""
        r0, v0 = self._starts[block]
        prop = OrbitPropagator.from_state(r0, v0, self.mu, self.j2)
        return prop.states(np.arange(BLOCK_STEPS + 1) * (self.dt_ns * 1e-9))



@njit(cache=True, inline="always")
def body_field(q_BN, p, b0, b1, b2, out, r) -> None:
    """Row ``r`` of ``out`` (., 3): the field (b0, b1, b2) in N seen in B, R_NB^T b, for the attitude in row
    ``p`` of ``q_BN`` (., 4) (R_NB as :func:`~attitude_sil.core.plant.quaternion.quat_to_dcm`)."""
    x, y, z, w = q_BN[p, 0], q_BN[p, 1], q_BN[p, 2], q_BN[p, 3]
    out[r, 0] = (1 - 2 * (y * y + z * z)) * b0 + 2 * (x * y + z * w) * b1 + 2 * (x * z - y * w) * b2
    out[r, 1] = 2 * (x * y - z * w) * b0 + (1 - 2 * (x * x + z * z)) * b1 + 2 * (y * z + x * w) * b2
    out[r, 2] = 2 * (x * z + y * w) * b0 + 2 * (y * z - x * w) * b1 + (1 - 2 * (x * x + y * y)) * b2


@njit(cache=True)
def _body_fields(q_BN, b_N, out) -> None:
    # every row: the field of row p of b_N (N, 3) in the frame of row p of q_BN (N, 4)
    for p in range(q_BN.shape[0]):
        body_field(q_BN, p, b_N[p, 0], b_N[p, 1], b_N[p, 2], out, p)


class FieldAlongOrbit:
    """The main geomagnetic field at the spacecraft of ``orbit``, by ``model`` (``none``, ``dipole``, ``igrf``).

    Raises
    ------
    ScenarioError
        ``igrf`` with an epoch outside the coefficients' years (one line).
    """

    def __init__(self, orbit: Ephemeris, model: str, epochs=None) -> None:
        if model not in FIELD_MODELS:
            raise ValueError(f"unknown field model {model!r}")  # the schema's choices refuse it first
        self.orbit, self.model = orbit, model
        # one epoch per episode (a Monte Carlo's dispersed epoch: the Earth turned another way under the same
        # orbit), or None: the orbit's for all
        self.epochs = None if epochs is None else [epoch_from_text(str(e), "orbit.epoch") for e in epochs]
        self.years = [decimal_year(e) for e in (self.epochs or [orbit.epoch])]
        self.year = self.years[0]
        self._cached: tuple[int, np.ndarray] = (-1, np.zeros((0, 3)))  # (chunk, its field): _chunk
        if model != "none":
            for year in self.years:  # an epoch outside IGRF-14: one line now, not at the first step
                igrf_coefficients(year)

    def field_N(self, t_ns) -> np.ndarray:
        """The field (n, 3) tesla in N at step times ``t_ns`` (n,) ns (whole steps of the orbit's period); (P, n, 3)
        with an epoch per episode.

        Evaluated :data:`FIELD_CHUNK` steps at a time, chunks aligned at step 0
        (the expansion holds (N + 1)^2 Legendre values per point), the last
        chunk kept: every reader of an episode (the plant node a step at a
        time, the stepwise driver, the record afterwards) gets the same bits.
        """
        t_ns = np.atleast_1d(np.asarray(t_ns, dtype=np.int64))
        if t_ns.size == 1:  # a step at a time (the nodes, the stepwise driver): its row of the chunk
            c, i = divmod(int(t_ns[0]) // self.orbit.dt_ns, FIELD_CHUNK)
            return self._chunk(c)[..., i:i + 1, :].copy()
        chunks = t_ns // self.orbit.dt_ns // FIELD_CHUNK
        out = np.empty(self._chunk(int(chunks[0])).shape[:-2] + (t_ns.size, 3))
        for c in np.unique(chunks):
            sel = chunks == c
            out[..., sel, :] = self._chunk(int(c))[..., t_ns[sel] // self.orbit.dt_ns - int(c) * FIELD_CHUNK, :]
        return out

    def _chunk(self, c: int) -> np.ndarray:
        """The field (FIELD_CHUNK, 3) in N at the steps of chunk ``c``; (P, FIELD_CHUNK, 3) with an epoch per
        episode, each as that epoch alone gives it."""
        if self._cached[0] != c:
            t_ns = (c * FIELD_CHUNK + np.arange(FIELD_CHUNK, dtype=np.int64)) * self.orbit.dt_ns
            r_N = np.array([self.orbit.at(int(t)).r_N for t in t_ns])
            fields = [field_eci(r_N, gmst_rad(julian_date(e, t_ns * 1e-9)), y, self.model)
                      for e, y in zip(self.epochs or [self.orbit.epoch], self.years, strict=True)]
            self._cached = (c, fields[0] if self.epochs is None else np.stack(fields))
        return self._cached[1]

    def field_B(self, t_ns, q_BN: np.ndarray) -> np.ndarray:
        """The field in B (..., n, 3) tesla for attitudes ``q_BN`` (..., n, 4) at step times ``t_ns`` (n,) ns:
        R_NB^T b_N (:func:`body_field`); with an epoch per episode, ``q_BN`` is (P, n, 4)."""
        q = np.asarray(q_BN, dtype=float)
        b = np.broadcast_to(self.field_N(t_ns), q.shape[:-1] + (3,))
        out = np.empty(q.shape[:-1] + (3,))
        _body_fields(np.ascontiguousarray(q.reshape(-1, 4)), np.ascontiguousarray(b.reshape(-1, 3)),
                     out.reshape(-1, 3))
        return out
