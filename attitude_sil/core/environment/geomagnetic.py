"""The Earth's magnetic field: IGRF-14 to degree 13, and its centred tilted dipole.

The main field is the gradient of a potential expanded in spherical harmonics
(IGRF-14; Alken et al., *Earth, Planets and Space*, 2021 for the 13th
generation's formulation, which the 14th keeps), in geocentric spherical
coordinates (r, colatitude theta, east longitude phi) of the Earth-fixed frame:

    V = a sum_n (a/r)^(n+1) sum_m (g_n^m cos m phi + h_n^m sin m phi) P_n^m(cos theta),

with a = 6371.2 km and P_n^m the Schmidt semi-normalised associated Legendre
functions. B = -grad V. The coefficients (nT) are shipped in
``data/igrf14.shc`` (its header names the source) at 5-year epochs and are
interpolated linearly in time between them; from 2025 to 2030 the file's last
column is the 2025 field plus the predicted secular variation. Outside
1900-2030 there are no coefficients: a one-line error.

The dipole model is the same expansion cut at degree 1: the field of a centred
dipole along -(g_1^1, h_1^1, g_1^0) in Earth-fixed axes, of the epoch.

Fields are in tesla. :func:`field_ecef` takes Earth-fixed positions;
:func:`field_eci` takes inertial ones with the sidereal angle
(:mod:`.earth_time`) and returns inertial components.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from attitude_sil.core.environment.earth_time import eci_to_ecef
from attitude_sil.errors import ScenarioError

__all__ = ["IGRF_FILE", "REFERENCE_RADIUS", "MAX_DEGREE", "FIELD_MODELS", "igrf_coefficients", "field_spherical",
           "field_ecef", "field_eci", "validity"]

#: the IGRF-14 coefficient file shipped with the package
IGRF_FILE = Path(__file__).with_name("data") / "igrf14.shc"
#: the reference radius a of the expansion, m
REFERENCE_RADIUS = 6371200.0
#: the expansion's highest degree
MAX_DEGREE = 13
#: ``environment.magnetic_field.model`` values and the degree each is cut at (none: no field)
FIELD_MODELS = {"none": 0, "dipole": 1, "igrf": MAX_DEGREE}


@lru_cache(maxsize=1)
def _table(path: Path = IGRF_FILE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The epochs (k,) (decimal years) and g, h (k, N + 1, N + 1) nT of a ``.shc`` file."""
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    header, epochs = rows[0], np.array([float(x) for x in rows[1]])
    nmax = int(header[1])
    g = np.zeros((epochs.size, nmax + 1, nmax + 1))
    h = np.zeros_like(g)
    for row in rows[2:]:
        n, m, values = int(row[0]), int(row[1]), np.array([float(x) for x in row[2:]])
        if m >= 0:
            g[:, n, m] = values
        else:
            h[:, n, -m] = values
    return epochs, g, h


def validity() -> tuple[float, float]:
    """The first and last decimal year the shipped coefficients cover."""
    epochs = _table()[0]
    return float(epochs[0]), float(epochs[-1])


def igrf_coefficients(year: float) -> tuple[np.ndarray, np.ndarray]:
    """g and h (N + 1, N + 1), tesla, at decimal ``year``, interpolated linearly between the file's epochs.

    Raises
    ------
    ScenarioError
        A year outside the coefficients' span.
    """
    epochs, g, h = _table()
    if not epochs[0] <= year <= epochs[-1]:
        raise ScenarioError(f"IGRF-14 covers {epochs[0]:.0f} to {epochs[-1]:.0f}; the epoch's year {year:.3f} is "
                            "outside it (environment.magnetic_field.model none flies any epoch)")
    k = min(int(np.searchsorted(epochs, year, side="right")) - 1, epochs.size - 2)
    w = (year - epochs[k]) / (epochs[k + 1] - epochs[k])
    return ((1.0 - w) * g[k] + w * g[k + 1]) * 1e-9, ((1.0 - w) * h[k] + w * h[k + 1]) * 1e-9


#: colatitude, rad, kept from each pole (:func:`field_ecef`)
POLE_GUARD = 1e-9


def _legendre(theta: np.ndarray, nmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Schmidt semi-normalised P_n^m(cos theta) and dP_n^m/dtheta, each (nmax + 1, nmax + 1, n_points)."""
    c, s = np.cos(theta), np.sin(theta)
    p = np.zeros((nmax + 1, nmax + 1, theta.size))
    dp = np.zeros_like(p)
    p[0, 0] = 1.0
    for n in range(1, nmax + 1):
        # the sectoral term from the one below it, then the column m by the three-term recursion in n
        k = 1.0 if n == 1 else np.sqrt((2.0 * n - 1.0) / (2.0 * n))
        p[n, n] = k * s * p[n - 1, n - 1]
        dp[n, n] = k * (c * p[n - 1, n - 1] + s * dp[n - 1, n - 1])
        for m in range(n):
            a = np.sqrt(n * n - m * m)
            b = np.sqrt((n - 1) ** 2 - m * m) if n - 1 > m else 0.0
            p[n, m] = ((2.0 * n - 1.0) * c * p[n - 1, m] - b * p[n - 2, m]) / a
            dp[n, m] = ((2.0 * n - 1.0) * (c * dp[n - 1, m] - s * p[n - 1, m]) - b * dp[n - 2, m]) / a
    return p, dp


def field_spherical(r_m, theta, phi, g: np.ndarray, h: np.ndarray, nmax: int) -> np.ndarray:
    """(B_r, B_theta, B_phi) (3, n) tesla at geocentric radius ``r_m`` (n,) m, colatitude ``theta`` and east
    longitude ``phi`` (n,) rad, for coefficients ``g``, ``h`` (tesla) cut at degree ``nmax``.

    ``B_phi`` divides by sin(theta): undefined on the poles themselves.
    """
    r_m, theta, phi = (np.atleast_1d(np.asarray(x, dtype=float)) for x in (r_m, theta, phi))
    p, dp = _legendre(theta, nmax)
    m = np.arange(nmax + 1)[:, None]
    cos_mp, sin_mp = np.cos(m * phi), np.sin(m * phi)
    out = np.zeros((3, r_m.size))
    for n in range(1, nmax + 1):
        ratio = (REFERENCE_RADIUS / r_m) ** (n + 2)
        gc = g[n, : n + 1, None] * cos_mp[: n + 1] + h[n, : n + 1, None] * sin_mp[: n + 1]
        gs = m[: n + 1] * (g[n, : n + 1, None] * sin_mp[: n + 1] - h[n, : n + 1, None] * cos_mp[: n + 1])
        out[0] += (n + 1) * ratio * np.sum(gc * p[n, : n + 1], axis=0)
        out[1] -= ratio * np.sum(gc * dp[n, : n + 1], axis=0)
        out[2] += ratio * np.sum(gs * p[n, : n + 1], axis=0)
    out[2] /= np.sin(theta)
    return out


def field_ecef(r_ecef: np.ndarray, year: float, model: str = "igrf") -> np.ndarray:
    """The main field (n, 3) tesla in Earth-fixed axes at Earth-fixed positions ``r_ecef`` (n, 3) m, at decimal
    ``year``, for ``model`` (:data:`FIELD_MODELS`)."""
    r_ecef = np.atleast_2d(np.asarray(r_ecef, dtype=float))
    nmax = FIELD_MODELS[model]
    if nmax == 0:
        return np.zeros_like(r_ecef)
    g, h = igrf_coefficients(year)
    x, y, z = r_ecef[:, 0], r_ecef[:, 1], r_ecef[:, 2]
    r = np.sqrt(x * x + y * y + z * z)
    # on a pole B_phi's 1/sin(theta) is 0/0 (its limit is finite): evaluated POLE_GUARD rad away, a few mm at
    # the surface, where the field differs by far less than a picotesla
    theta, phi = np.clip(np.arccos(z / r), POLE_GUARD, np.pi - POLE_GUARD), np.arctan2(y, x)
    b_r, b_t, b_p = field_spherical(r, theta, phi, g, h, nmax)
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
    return np.stack([b_r * st * cp + b_t * ct * cp - b_p * sp,
                     b_r * st * sp + b_t * ct * sp + b_p * cp,
                     b_r * ct - b_t * st], axis=-1)


def field_eci(r_eci: np.ndarray, theta_gmst, year: float, model: str = "igrf") -> np.ndarray:
    """The main field (n, 3) tesla in inertial axes at inertial positions ``r_eci`` (n, 3) m, the Earth turned by
    sidereal angles ``theta_gmst`` (n,) rad, at decimal ``year`` (one for the episode: the field's secular change
    over an episode is below a nanotesla a day)."""
    rot = eci_to_ecef(np.asarray(theta_gmst, dtype=float))  # (n, 3, 3): x_E = R x_N
    r_e = np.einsum("nij,nj->ni", rot, np.atleast_2d(r_eci))
    return np.einsum("nji,nj->ni", rot, field_ecef(r_e, year, model))  # back to N: R^T b_E
