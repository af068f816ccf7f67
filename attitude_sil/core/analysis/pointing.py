"""Pointing figures a budget uses: absolute performance and knowledge errors (ECSS-E-ST-60-10C).

APE (absolute performance error): the attitude's error from the setpoint; AKE (absolute knowledge error):
the estimate's error from the true attitude. Both per body axis (the small rotation of
:func:`attitude_sil.core.plant.quaternion.attitude_error_B`, rad), summarised over the samples after a start
time (the settling of the manoeuvre: a budget rates the pointing phase, not the slew) as their RMS and the
99th percentile of their magnitude, as ECSS-E-ST-60-10C states an error with a probability level.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.plant.quaternion import attitude_error_B

__all__ = ["POINTING_KEYS", "POINTING_COLUMNS", "pointing_errors", "pointing_metrics", "pointing_start",
           "pointing_columns"]

#: the ``--json`` keys (each a list of 3, per body axis, rad; null where not defined)
POINTING_KEYS = ("ape_rms_rad", "ape_p99_rad", "ake_rms_rad", "ake_p99_rad")

#: the same figures as one column per axis (a Monte Carlo table's, whose percentiles the campaign reports)
POINTING_COLUMNS = tuple(f"{key[:-4]}_{axis}_rad" for key in POINTING_KEYS for axis in "xyz")


def pointing_errors(q_BN: np.ndarray, q_RN: np.ndarray, q_BN_est: np.ndarray | None = None):
    """APE (..., 3) and AKE (..., 3) rad (None without an estimate) of attitudes, setpoints and estimates (..., 4)."""
    ape = attitude_error_B(q_RN, q_BN)
    ake = None if q_BN_est is None else attitude_error_B(q_BN, q_BN_est)
    return ape, ake


def pointing_start(scenario_values: dict, settling_time_s: float | None) -> float | None:
    """Where the figures start, s: ``metrics.pointing_after_s`` if set (>= 0), else the settling time; None if
    the run never settled (a pointing phase it did not reach has no figures)."""
    after = float(scenario_values["metrics.pointing_after_s"])
    if after >= 0.0:
        return after
    if settling_time_s is not None and np.isfinite(settling_time_s):
        return float(settling_time_s)
    return None


def _summary(err: np.ndarray | None, keep: np.ndarray) -> tuple[list | None, list | None]:
    if err is None or not np.any(keep):
        return None, None
    e = err[keep]
    return (np.sqrt(np.mean(e * e, axis=0)).tolist(), np.percentile(np.abs(e), 99.0, axis=0).tolist())


def pointing_metrics(t: np.ndarray, ape: np.ndarray, ake: np.ndarray | None, start_s: float | None) -> dict:
    """RMS and 99th percentile of |error| per body axis (lists of 3, rad) over the samples at t >= ``start_s``.

    Parameters
    ----------
    t : (n,) s
    ape, ake : (n, 3) rad (``ake`` None without an estimator)
    start_s : float or None
        None: no figures (the run never settled).

    Returns
    -------
    dict
        :data:`POINTING_KEYS` and ``pointing_from_s`` (``start_s``); a figure with no sample after the start
        is None.
    """
    if start_s is None:
        return {**dict.fromkeys(POINTING_KEYS), "pointing_from_s": None}
    keep = np.asarray(t) >= start_s - 1e-9
    ape_rms, ape_p99 = _summary(ape, keep)
    ake_rms, ake_p99 = _summary(ake, keep)
    return {"ape_rms_rad": ape_rms, "ape_p99_rad": ape_p99, "ake_rms_rad": ake_rms, "ake_p99_rad": ake_p99,
            "pointing_from_s": float(start_s)}


def pointing_columns(t: np.ndarray, q_BN: np.ndarray, q_RN: np.ndarray, q_BN_est: np.ndarray | None,
                     scenario_values: dict, settling_time_s: np.ndarray) -> dict[str, np.ndarray]:
    """:data:`POINTING_COLUMNS` of P episodes, (P,) each (NaN where not defined): their figures as
    :func:`pointing_metrics` gives them one by one, from trajectories (P, n, 4) and settling times (P,) s."""
    P = q_BN.shape[0]
    out = {name: np.full(P, np.nan) for name in POINTING_COLUMNS}
    ape, ake = pointing_errors(q_BN, q_RN, q_BN_est)
    for p in range(P):
        m = pointing_metrics(t, ape[p], None if ake is None else ake[p],
                             pointing_start(scenario_values, float(settling_time_s[p])))
        for key in POINTING_KEYS:
            if m[key] is not None:
                for axis, v in zip("xyz", m[key], strict=True):
                    out[f"{key[:-4]}_{axis}_rad"][p] = v
    return out
