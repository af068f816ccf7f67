"""Time and Earth rotation: a UTC epoch, Julian dates, decimal years, sidereal time, inertial to Earth-fixed.

Conventions (stated, since a simulator of attitude needs them to metres, not
to centimetres):

* the inertial frame N is the mean equator and equinox of the epoch's date,
  taken as GCRF; precession, nutation and polar motion are left out, so N and
  the Earth-fixed frame E differ by a rotation about z by the Greenwich mean
  sidereal time (about 1e-4 rad of error in the field's direction over decades);
* UT1 = UTC (|UT1 - UTC| < 0.9 s: under 7e-5 rad of Earth rotation);
* GMST from the IAU 1982 expression (Vallado, *Fundamentals of Astrodynamics
  and Applications*, 4th ed., eq. 3-47), evaluated at each time.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime

import numpy as np

from attitude_sil.errors import ScenarioError

__all__ = ["JD_J2000", "EARTH_ROTATION_RATE", "epoch_from_text", "julian_date", "decimal_year", "gmst_rad",
           "eci_to_ecef"]

#: Julian date of J2000.0 (2000-01-01 12:00 TT, here UTC)
JD_J2000 = 2451545.0
#: Earth's rotation rate relative to the mean equinox (GMST's rate), rad/s (Vallado, eq. 3-40)
EARTH_ROTATION_RATE = 7.2921158553e-5
_JD_UNIX = 2440587.5  # Julian date of 1970-01-01 00:00 UTC


def epoch_from_text(text: str, where: str = "epoch") -> datetime:
    """An ISO 8601 UTC time (``2026-01-01T00:00:00Z``; a date alone is its midnight) as an aware datetime.

    Raises
    ------
    ScenarioError
        A text that is no such time, or one with an offset other than UTC.
    """
    try:
        when = datetime.fromisoformat(str(text).strip())
    except ValueError:
        raise ScenarioError(f"{where}: {text!r} is not an ISO 8601 UTC time such as 2026-01-01T00:00:00Z") from None
    if when.tzinfo is None:
        return when.replace(tzinfo=UTC)
    if when.utcoffset().total_seconds() != 0.0:
        raise ScenarioError(f"{where}: {text!r} is not in UTC (give Z or +00:00)")
    return when.astimezone(UTC)


def julian_date(epoch: datetime, t_s=0.0):
    """Julian date (UTC) of ``epoch`` plus ``t_s`` seconds (scalar or array)."""
    return _JD_UNIX + (epoch.timestamp() + np.asarray(t_s, dtype=float)) / 86400.0


def decimal_year(epoch: datetime, t_s: float = 0.0) -> float:
    """The year of ``epoch`` plus ``t_s`` s as a decimal: 2026.0 at the year's start, by the days of that year."""
    when = datetime.fromtimestamp(epoch.timestamp() + t_s, tz=UTC)
    start = datetime(when.year, 1, 1, tzinfo=UTC)
    length = (datetime(when.year + 1, 1, 1, tzinfo=UTC) - start).total_seconds()
    return when.year + (when - start).total_seconds() / length


def gmst_rad(jd_ut1) -> np.ndarray:
    """Greenwich mean sidereal time (rad, in [0, 2 pi)) at Julian date ``jd_ut1`` (IAU 1982, Vallado eq. 3-47)."""
    t = (np.asarray(jd_ut1, dtype=float) - JD_J2000) / 36525.0
    seconds = 67310.54841 + (876600.0 * 3600.0 + 8640184.812866) * t + 0.093104 * t**2 - 6.2e-6 * t**3
    return np.mod(seconds, 86400.0) * (2.0 * math.pi / 86400.0)


def eci_to_ecef(theta_rad) -> np.ndarray:
    """The rotation matrix (..., 3, 3) taking inertial components to Earth-fixed ones at sidereal angle
    ``theta_rad``: a rotation of the axes about z by theta (x_E = R x_N)."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, s, zero], -1), np.stack([-s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)
