"""The orbit: classical elements, the two-body and J2 accelerations, and a propagator over an episode.

Frames and constants:

* positions and velocities are in the inertial frame N (m, m/s);
* the Earth's gravity is the point mass plus its oblateness J2 (EGM96:
  mu = 3.986004418e14 m^3/s^2, J2 = 1.0826267e-3, R_e = 6378136.3 m);
* the orbit frame LVLH (L) has x along the track, y the orbit normal
  (r x v) and z the zenith (r): paper 001's frame. On a circular orbit it
  turns about its y axis at the mean motion
  (:func:`attitude_sil.core.plant.disturbance.lvlh_attitude`); on any
  orbit :func:`lvlh_from_state` gives it from r and v;
* elements are classical: semi-major axis a (m), eccentricity e, inclination
  i, right ascension of the ascending node Omega, argument of perigee omega
  and true anomaly nu (rad) (Vallado, *Fundamentals of Astrodynamics and
  Applications*, 4th ed., algorithms 9 and 10).

:class:`OrbitPropagator` integrates Cowell's equation (the sum of the
accelerations) with an 8th-order Dormand-Prince method at a relative
tolerance of 1e-12 and samples it at the times asked for: the whole episode
at once, so every node and the batch engine read the same numbers, and a
10-orbit run costs a fraction of a second. With J2 = 0 the two-body energy and
angular momentum hold to about 1e-11 over a day (a test holds 1e-10).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from attitude_sil.core.plant.quaternion import cross, quat_from_dcm
from attitude_sil.errors import ScenarioError

__all__ = ["MU_EARTH", "J2_EARTH", "R_EARTH", "Elements", "elements_to_state", "state_to_elements",
           "gravity_acceleration", "OrbitPropagator", "nodal_regression_rate", "lvlh_from_state", "norm3"]

#: Earth's gravitational parameter, m^3/s^2 (EGM96)
MU_EARTH = 3.986004418e14
#: Earth's second zonal harmonic, unnormalised (EGM96)
J2_EARTH = 1.0826267e-3
#: the equatorial radius J2 refers to, m (EGM96)
R_EARTH = 6378136.3
#: the propagator's absolute tolerance: 1 micrometre on position, 1 nm/s on velocity (the relative 1e-12 rules)
_ATOL = np.array([1e-6, 1e-6, 1e-6, 1e-9, 1e-9, 1e-9])


@dataclass(frozen=True)
class Elements:
    """Classical orbital elements: a (m), e, and the angles i, raan, argp, nu (rad)."""

    a: float
    e: float
    i: float
    raan: float
    argp: float
    nu: float

    def check(self, where: str = "orbit") -> Elements:
        """The elements of a closed orbit above the Earth's surface, or a one-line ScenarioError."""
        values = (self.a, self.e, self.i, self.raan, self.argp, self.nu)
        if not all(math.isfinite(v) for v in values):
            raise ScenarioError(f"{where}: the elements are not finite: {values}")
        if not 0.0 <= self.e < 1.0:
            raise ScenarioError(f"{where}: eccentricity {self.e} is not in [0, 1): a closed orbit is needed")
        if self.a * (1.0 - self.e) <= R_EARTH:
            raise ScenarioError(f"{where}: perigee radius {self.a * (1.0 - self.e):.0f} m is inside the Earth "
                                f"(equatorial radius {R_EARTH:.0f} m)")
        if not 0.0 <= self.i <= math.pi:
            raise ScenarioError(f"{where}: inclination {math.degrees(self.i)} deg is not in [0, 180]")
        return self


def _perifocal_to_inertial(raan: float, i: float, argp: float) -> np.ndarray:
    """R3(-raan) R1(-i) R3(-argp): perifocal (P, Q, W) components to inertial ones."""
    co, so, ci, si, cw, sw = (math.cos(raan), math.sin(raan), math.cos(i), math.sin(i), math.cos(argp),
                              math.sin(argp))
    return np.array([[co * cw - so * sw * ci, -co * sw - so * cw * ci, so * si],
                     [so * cw + co * sw * ci, -so * sw + co * cw * ci, -co * si],
                     [sw * si, cw * si, ci]])


def elements_to_state(el: Elements, mu: float = MU_EARTH) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) m and velocity (3,) m/s in N of the elements ``el``."""
    p = el.a * (1.0 - el.e**2)
    r_pf = p / (1.0 + el.e * math.cos(el.nu)) * np.array([math.cos(el.nu), math.sin(el.nu), 0.0])
    v_pf = math.sqrt(mu / p) * np.array([-math.sin(el.nu), el.e + math.cos(el.nu), 0.0])
    rot = _perifocal_to_inertial(el.raan, el.i, el.argp)
    return rot @ r_pf, rot @ v_pf


def state_to_elements(r: np.ndarray, v: np.ndarray, mu: float = MU_EARTH) -> Elements:
    """The osculating elements of position ``r`` (3,) m and velocity ``v`` (3,) m/s (angles in [0, 2 pi))."""
    r, v = np.asarray(r, dtype=float), np.asarray(v, dtype=float)
    h = np.cross(r, v)
    node = np.cross([0.0, 0.0, 1.0], h)
    rn, hn, nn = np.linalg.norm(r), np.linalg.norm(h), np.linalg.norm(node)
    e_vec = np.cross(v, h) / mu - r / rn
    e = float(np.linalg.norm(e_vec))
    a = 1.0 / (2.0 / rn - float(v @ v) / mu)
    i = math.acos(max(-1.0, min(1.0, h[2] / hn)))
    raan = math.atan2(node[1], node[0]) % (2.0 * math.pi) if nn > 0.0 else 0.0
    # the argument of perigee from the node, the true anomaly from perigee (circular: from the node)
    ref = node / nn if nn > 0.0 else np.array([1.0, 0.0, 0.0])
    if e > 1e-12:
        argp = _angle_in_plane(ref, e_vec / e, h / hn)
        nu = _angle_in_plane(e_vec / e, r / rn, h / hn)
    else:
        argp, nu = 0.0, _angle_in_plane(ref, r / rn, h / hn)
    return Elements(float(a), e, i, raan, argp, nu)


def _angle_in_plane(a: np.ndarray, b: np.ndarray, normal: np.ndarray) -> float:
    """The angle from unit vector ``a`` to ``b`` about ``normal``, in [0, 2 pi)."""
    return math.atan2(float(np.cross(a, b) @ normal), float(a @ b)) % (2.0 * math.pi)


def gravity_acceleration(r: np.ndarray, mu: float = MU_EARTH, j2: float = J2_EARTH,
                         r_e: float = R_EARTH) -> np.ndarray:
    """Point-mass plus J2 acceleration (m/s^2) at inertial positions ``r`` (..., 3) m (Vallado eq. 8-30)."""
    r = np.asarray(r, dtype=float)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    rn2 = x * x + y * y + z * z
    rn = np.sqrt(rn2)
    k = -mu / (rn2 * rn)
    zr2 = z * z / rn2
    f = 1.5 * j2 * (r_e * r_e / rn2)
    return np.stack([k * x * (1.0 + f * (1.0 - 5.0 * zr2)), k * y * (1.0 + f * (1.0 - 5.0 * zr2)),
                     k * z * (1.0 + f * (3.0 - 5.0 * zr2))], axis=-1)


def nodal_regression_rate(el: Elements, mu: float = MU_EARTH, j2: float = J2_EARTH, r_e: float = R_EARTH) -> float:
    """First-order secular drift of the node under J2, rad/s: -3/2 n J2 (R_e / p)^2 cos i (Vallado eq. 9-41)."""
    n = math.sqrt(mu / el.a**3)
    p = el.a * (1.0 - el.e**2)
    return -1.5 * n * j2 * (r_e / p) ** 2 * math.cos(el.i)


class OrbitPropagator:
    """The orbit from elements at t = 0, integrated under two-body gravity and J2.

    Parameters
    ----------
    elements : Elements
        The osculating elements at t = 0 (the epoch).
    mu, j2, r_e : float
        Gravity model (J2 = 0: the two-body problem).
    """

    def __init__(self, elements: Elements, mu: float = MU_EARTH, j2: float = J2_EARTH, r_e: float = R_EARTH) -> None:
        self.elements = elements.check()
        self.mu, self.j2, self.r_e = float(mu), float(j2), float(r_e)
        self.r0, self.v0 = elements_to_state(elements, mu)

    @classmethod
    def from_state(cls, r0: np.ndarray, v0: np.ndarray, mu: float = MU_EARTH, j2: float = J2_EARTH,
                   r_e: float = R_EARTH) -> OrbitPropagator:
        """The propagator from position ``r0`` (3,) m and velocity ``v0`` (3,) m/s in N at t = 0."""
        prop = cls(state_to_elements(r0, v0, mu), mu, j2, r_e)
        prop.r0, prop.v0 = np.array(r0, dtype=float), np.array(v0, dtype=float)  # the state itself, not re-made
        return prop

    def _rhs(self, _t: float, y: np.ndarray) -> np.ndarray:
        return np.concatenate([y[3:], gravity_acceleration(y[:3], self.mu, self.j2, self.r_e)])

    def states(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (n, 3) m and velocity (n, 3) m/s in N at the increasing times ``t_s`` (n,) s from the epoch."""
        t_s = np.asarray(t_s, dtype=float)
        if t_s.size == 0:
            return np.zeros((0, 3)), np.zeros((0, 3))
        if t_s[-1] == 0.0:
            return np.tile(self.r0, (t_s.size, 1)), np.tile(self.v0, (t_s.size, 1))
        sol = solve_ivp(self._rhs, (0.0, float(t_s[-1])), np.concatenate([self.r0, self.v0]), method="DOP853",
                        t_eval=t_s, rtol=1e-12, atol=_ATOL)
        return sol.y[:3].T.copy(), sol.y[3:].T.copy()


def lvlh_from_state(r: np.ndarray, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The LVLH frame of positions ``r``, velocities ``v`` and accelerations ``a`` (..., 3) in N: (q_LN (..., 4),
    omega_LN in L (..., 3) rad/s), row by row.

    omega_LN = (0, |h| / r^2, r a_h / |h|): the track's turn, and the orbit
    plane's turn about the zenith under the acceleration's out-of-plane part
    a_h (J2), as the frame of Hill turns (Schaub and Junkins, *Analytical
    Mechanics of Space Systems*, section 14.3).
    """
    r, v, a = (np.asarray(u, dtype=float) for u in (r, v, a))
    h = cross(r, v)  # written out: np.cross costs several times more
    rn, hn = norm3(r)[..., None], norm3(h)[..., None]
    z, y = r / rn, h / hn
    x = cross(y, z)
    a_h = a[..., 0:1] * y[..., 0:1] + a[..., 1:2] * y[..., 1:2] + a[..., 2:3] * y[..., 2:3]
    omega = np.concatenate([np.zeros_like(rn), hn / rn**2, rn * a_h / hn], axis=-1)
    return quat_from_dcm(np.stack([x, y, z], axis=-1)), omega


def norm3(u: np.ndarray) -> np.ndarray:
    """|u| (...) of vectors ``u`` (..., 3), summed in component order (the same bits for one row or many)."""
    return np.sqrt(u[..., 0] * u[..., 0] + u[..., 1] * u[..., 1] + u[..., 2] * u[..., 2])
