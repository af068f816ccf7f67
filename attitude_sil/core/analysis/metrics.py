"""Step-response metrics and the paper 000 cost, batch over episodes.

All functions take a time vector ``t`` (K+1,) and arrays with a leading
episode axis. Times are measured from the step time. A metric that the
response never reaches (a time constant of a response that never gets to
63.2 %) is NaN, and so is a cost built from it.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.analysis.magnetic import MagneticFigures, magnetic_columns, magnetic_figures
from attitude_sil.core.analysis.metric_rows import Sums
from attitude_sil.core.analysis.pointing import pointing_columns, pointing_errors, pointing_metrics, pointing_start
from attitude_sil.core.plant.fdir import fdir_columns
from attitude_sil.core.plant.quaternion import euler_from_quat, quat_error, quat_multiply
from attitude_sil.core.trajectory import EpisodeSummary, Trajectory, all_finite


def principal_angle(q_BN: np.ndarray, q_RN: np.ndarray) -> np.ndarray:
    """Angle of the attitude error rotation Q (Rodrigues), shape (...), rad."""
    q = quat_error(q_BN, q_RN)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), q[..., 3])


def _axis_turn(axis: int, deg: float) -> np.ndarray:
    v = np.zeros(4)
    v[axis] = np.sin(np.radians(deg) / 2)
    v[3] = np.cos(np.radians(deg) / 2)
    return v


#: paper 001: settled when the error angle stays below that of R1(0.1 deg) R2(0.1 deg) R3(0.1 deg)
PAPER_001_SETTLING_ANGLE = float(2.0 * np.arccos(
    quat_multiply(quat_multiply(_axis_turn(0, 0.1), _axis_turn(1, 0.1)), _axis_turn(2, 0.1))[3]))

__all__ = ["METRIC_KEYS", "episode_report", "summarize", "step_summary",
           "step_metrics", "metrics_from_trajectory", "segment_metrics", "tracking_metrics", "scenario_metrics",
           "principal_angle", "PAPER_001_SETTLING_ANGLE", "flexible_split"]


def _first_crossing(t: np.ndarray, y: np.ndarray, level: float | np.ndarray) -> np.ndarray:
    """First time each row of y (P, K) reaches ``level`` (P,), linearly interpolated; NaN if never."""
    level = np.broadcast_to(np.asarray(level, dtype=float), (y.shape[0],))[:, None]
    above = y >= level
    idx = np.argmax(above, axis=1)
    hit = above[np.arange(y.shape[0]), idx]
    out = np.full(y.shape[0], np.nan)
    for p in np.nonzero(hit)[0]:
        i = idx[p]
        if i == 0:
            out[p] = t[0]
        else:
            y0, y1 = y[p, i - 1], y[p, i]
            frac = (level[p, 0] - y0) / (y1 - y0) if y1 != y0 else 0.0
            out[p] = t[i - 1] + frac * (t[i] - t[i - 1])
    return out


def step_metrics(
    t: np.ndarray,
    y: np.ndarray,
    r: np.ndarray,
    y0: np.ndarray,
    step_time: float = 0.0,
    settling_band: float = 0.02,
) -> dict[str, np.ndarray]:
    """Metrics of a step from ``y0`` to ``r`` on one axis.

    Parameters
    ----------
    t : (K+1,) s
    y : (P, K+1) response, rad
    r : (P,) final setpoint, rad
    y0 : (P,) value before the step, rad
    step_time : float, s
    settling_band : float
        Fraction of the step size.

    Returns
    -------
    dict of (P,) arrays: ``time_constant_s`` (63.2 %), ``rise_time_s`` (10-90 %),
    ``settling_time_s`` (first time after which |y - r| stays within the band),
    ``overshoot_pct``, ``steady_state_error_rad`` (|r - y| at the end), and the
    error integrals ``iae``, ``ise``, ``itae`` of ``r - y`` after the step.
    """
    r = np.asarray(r, dtype=float)
    y0 = np.asarray(y0, dtype=float)
    after = t >= step_time - 1e-12
    ta = t[after] - step_time
    ya = y[:, after]
    span = r - y0
    safe = np.where(span == 0.0, 1.0, span)
    frac = (ya - y0[:, None]) / safe[:, None]
    tc = _first_crossing(ta, frac, 0.632)
    t10 = _first_crossing(ta, frac, 0.1)
    t90 = _first_crossing(ta, frac, 0.9)
    overshoot = np.maximum(0.0, np.max(frac, axis=1) - 1.0) * 100.0
    outside = np.abs(ya - r[:, None]) > settling_band * np.abs(span)[:, None]
    settle = np.full(y.shape[0], np.nan)
    for p in range(y.shape[0]):
        idx = np.nonzero(outside[p])[0]
        if idx.size == 0:
            settle[p] = 0.0
        elif idx[-1] < ta.size - 1:
            settle[p] = ta[idx[-1] + 1]
    err = r[:, None] - ya
    dts = np.diff(ta)
    # trapezoidal integrals
    iae = np.sum(0.5 * (np.abs(err[:, 1:]) + np.abs(err[:, :-1])) * dts, axis=1)
    ise = np.sum(0.5 * (err[:, 1:] ** 2 + err[:, :-1] ** 2) * dts, axis=1)
    itae = np.sum(0.5 * (ta[1:] * np.abs(err[:, 1:]) + ta[:-1] * np.abs(err[:, :-1])) * dts, axis=1)
    zero_step = span == 0.0
    for arr in (tc, t10, t90, overshoot, settle):
        arr[zero_step] = np.nan
    return {
        "time_constant_s": tc,
        "rise_time_s": t90 - t10,
        "settling_time_s": settle,
        "overshoot_pct": overshoot,
        "steady_state_error_rad": np.abs(err[:, -1]),
        "iae": iae,
        "ise": ise,
        "itae": itae,
    }


def metrics_from_trajectory(
    t: np.ndarray,
    q_BN: np.ndarray,
    q_RN: np.ndarray,
    tau_c_B: np.ndarray,
    axis: int = 0,
    step_time: float = 0.0,
    settling_band: float = 0.02,
    tau_d: float = 1.5,
    w_os: float = 1.0,
) -> dict[str, np.ndarray]:
    """Step metrics, control effort and cost J of a run.

    Parameters
    ----------
    t : (K+1,) s
    q_BN, q_RN : (P, K+1, 4) attitude and setpoint
    tau_c_B : (P, K+1, 3) N m, mean control torque of each step (the last
        entry, after the final state, is not counted)
    axis : int, body axis of the step (0 roll, 1 pitch, 2 yaw)
    step_time, settling_band : see :func:`step_metrics`
    tau_d, w_os : desired time constant (s) and overshoot weight of
        ``J = |tau - tau_d| + w_os OS`` (paper 000 eq. 19, OS in percent)

    Returns
    -------
    dict of (P,) arrays: those of :func:`step_metrics` plus
    ``control_effort_Nms`` (sum of ||tau_c|| dt) and ``cost_J``.
    """
    y = euler_from_quat(q_BN)[..., axis]
    ref = euler_from_quat(q_RN)[..., axis]
    before = t < step_time - 1e-12
    y0 = ref[:, np.nonzero(before)[0][-1]] if before.any() else euler_from_quat(q_BN[:, 0])[..., axis]
    m = step_metrics(t, y, ref[:, -1], y0, step_time, settling_band)
    dt = np.diff(t)
    m["control_effort_Nms"] = np.sum(np.linalg.norm(tau_c_B[:, :-1], axis=-1) * dt, axis=1)
    m["cost_J"] = np.abs(m["time_constant_s"] - tau_d) + w_os * m["overshoot_pct"]
    return m


def tracking_metrics(
    t: np.ndarray,
    q_BN: np.ndarray,
    q_RN: np.ndarray,
    tau_c_B: np.ndarray,
    settling_angle: float = PAPER_001_SETTLING_ANGLE,
    beta: float = 1.0,
) -> dict[str, np.ndarray]:
    """Paper 001's figures of a tracking manoeuvre.

    ``settling_time_s``: first time after which the principal error angle
    stays below ``settling_angle`` (NaN if it never settles);
    ``control_effort_Nms``: Ce = sum ||tau|| dt (eq. 9); ``fitness_f``:
    f = -(Ts + beta Ce) (eq. 8); ``final_error_rad``; ``iae`` and ``ise`` of
    the error angle.
    """
    zeta = principal_angle(q_BN, q_RN)
    outside = zeta > settling_angle
    settle = np.full(zeta.shape[0], np.nan)
    for p in range(zeta.shape[0]):
        idx = np.nonzero(outside[p])[0]
        if idx.size == 0:
            settle[p] = t[0]
        elif idx[-1] < t.size - 1:
            settle[p] = t[idx[-1] + 1]
    dt = np.diff(t)
    ce = np.sum(np.linalg.norm(tau_c_B[:, :-1], axis=-1) * dt, axis=1)
    return {
        "settling_time_s": settle,
        "control_effort_Nms": ce,
        "fitness_f": -(settle + beta * ce),
        "final_error_rad": zeta[:, -1],
        "iae": np.sum(0.5 * (zeta[:, 1:] + zeta[:, :-1]) * dt, axis=1),
        "ise": np.sum(0.5 * (zeta[:, 1:] ** 2 + zeta[:, :-1] ** 2) * dt, axis=1),
    }


def scenario_metrics(t: np.ndarray, q_BN: np.ndarray, q_RN: np.ndarray, tau_c_B: np.ndarray, scenario_values: dict,
                     step_time: float = 0.0) -> dict[str, np.ndarray]:
    """The metrics a scenario asks for (``scenario.metrics.mode``), batch (P, ...) arrays in and (P,) out.

    * ``step``: :func:`metrics_from_trajectory` on ``metrics.axis``;
    * ``regulation``: the same, from the initial angle to the setpoint, plus
      ``mse`` (paper 002 eq. 10, the mean of the squared error in rad^2);
    * ``tracking``: :func:`tracking_metrics`.
    """
    s = scenario_values
    mode = s["metrics.mode"]
    if mode == "tracking":
        angle = s["metrics.settling_angle_deg"]
        return tracking_metrics(t, q_BN, q_RN, tau_c_B,
                                PAPER_001_SETTLING_ANGLE if angle < 0 else np.radians(angle), s["metrics.beta"])
    m = metrics_from_trajectory(t, q_BN, q_RN, tau_c_B, axis=s["metrics.axis"], step_time=step_time,
                                settling_band=s["metrics.settling_band"], tau_d=s["metrics.tau_d"],
                                w_os=s["metrics.w_os"])
    if mode == "regulation":
        err = euler_from_quat(q_RN)[..., s["metrics.axis"]] - euler_from_quat(q_BN)[..., s["metrics.axis"]]
        m["mse"] = np.mean(err**2, axis=1)
        m["max_abs_error_rad"] = np.max(np.abs(err), axis=1)
        # a disturbance with no step (paper 004's impulse): settled once |error| stays
        # within the band of its peak
        band = s["metrics.settling_band"] * m["max_abs_error_rad"]
        for p in np.nonzero(np.isnan(m["settling_time_s"]))[0]:
            idx = np.nonzero(np.abs(err[p]) > band[p])[0]
            if idx.size and idx[-1] < t.size - 1:
                m["settling_time_s"][p] = t[idx[-1] + 1]
    return m


def flexible_split(t: np.ndarray, theta: np.ndarray, alpha: np.ndarray, target: float,
                   settling_band: float = 0.02) -> dict[str, np.ndarray]:
    """Paper 002's two responses, settled separately: the rigid body and the appendage.

    ``rigid_settling_time_s``: first time after which the rigid angle theta
    (P, K+1) stays within ``settling_band`` of its initial distance from
    ``target``; ``flexible_settling_time_s``: first time after which the
    deflection alpha (P, K+1) stays within ``settling_band`` of its peak
    magnitude. NaN: not settled by the end of the run.
    """
    out = {}
    for key, err, scale in (("rigid_settling_time_s", theta - target, np.abs(theta[:, 0] - target)),
                            ("flexible_settling_time_s", alpha, np.max(np.abs(alpha), axis=1))):
        settle = np.full(err.shape[0], np.nan)
        for p in range(err.shape[0]):
            idx = np.nonzero(np.abs(err[p]) > settling_band * scale[p])[0]
            if idx.size == 0:
                settle[p] = t[0]
            elif idx[-1] < t.size - 1:
                settle[p] = t[idx[-1] + 1]
        out[key] = settle
    return out


def summarize(tr: Trajectory, scenario_values: dict, step_time: float = 0.0) -> EpisodeSummary:
    """The :class:`EpisodeSummary` of whole trajectories (what the compiled running sums give directly).

    ``tr`` needs ``t``, ``q_BN``, ``q_RN``, ``omega_BN_B``, ``tau_c_B`` and
    ``u_cmd``; ``wheel_speed`` may be None.
    """
    with np.errstate(invalid="ignore"):
        m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B, scenario_values, step_time=step_time)
    if tr.q_BN_est is not None:  # the sensing loop ran: the pointing figures of a budget, per episode
        m.update(pointing_columns(tr.t, tr.q_BN, tr.q_RN, tr.q_BN_est, scenario_values, m["settling_time_s"]))
    if tr.omega_BN_B is not None and tr.h_wheels_B is not None:  # detumbling, and the magnetorquers' figures
        m.update(magnetic_columns(tr.t, tr.omega_BN_B, tr.h_wheels_B, tr.dipole_cmd_B,
                                  scenario_values["metrics.detumble_rate_deg_s"]))
    if tr.fdir_isolated is not None:  # the wheels' FDIR ran: what it isolated, when
        m.update(fdir_columns(tr.t, tr.fdir_isolated))
    finite = all_finite(tr.omega_BN_B, tr.u_cmd)  # the running sums' rule (Sums.finite): rate and command
    no_wheels = tr.wheel_speed is None or tr.wheel_speed.shape[-1] == 0
    peak_ws = None if no_wheels else np.max(np.abs(np.nan_to_num(tr.wheel_speed, nan=np.inf)), axis=(1, 2))
    return EpisodeSummary(metrics=m, finite=finite,
                          peak_command=np.max(np.abs(np.nan_to_num(tr.u_cmd, nan=np.inf)), axis=(1, 2)),
                          peak_wheel_speed=peak_ws)


def step_summary(sums: np.ndarray, scenario_values: dict, span: np.ndarray) -> EpisodeSummary:
    """An :class:`EpisodeSummary` from the compiled driver's running sums of a ``step`` scenario.

    Parameters
    ----------
    sums : (P, len(Sums))
        Running sums (:func:`attitude_sil.core.sim.batch.run_compiled` with ``sums``).
    scenario_values : dict
        The ``scenario`` node's values (``metrics.tau_d``, ``metrics.w_os``).
    span : (P,) rad
        Size of each episode's step (final minus initial angle); a zero step
        has no time constant, rise, settling or overshoot (NaN), as in
        :func:`step_metrics`.
    """
    tc, t10, t90, f_max, settle = (sums[:, c].copy() for c in (Sums.time_constant_s, Sums.t10_s, Sums.t90_s,
                                                                Sums.max_fraction, Sums.settling_time_s))
    overshoot = np.maximum(0.0, f_max - 1.0) * 100.0
    zero_step = np.asarray(span) == 0.0
    for arr in (tc, t10, t90, overshoot, settle):
        arr[zero_step] = np.nan
    m = {"time_constant_s": tc, "rise_time_s": t90 - t10, "settling_time_s": settle, "overshoot_pct": overshoot}
    for c in (Sums.steady_state_error_rad, Sums.iae, Sums.ise, Sums.itae, Sums.control_effort_Nms):
        m[c.name] = sums[:, c].copy()
    m["cost_J"] = np.abs(tc - scenario_values["metrics.tau_d"]) + scenario_values["metrics.w_os"] * overshoot
    return EpisodeSummary(metrics=m, finite=sums[:, Sums.finite] > 0.5, peak_command=sums[:, Sums.peak_command].copy(),
                          peak_wheel_speed=sums[:, Sums.peak_wheel_speed].copy())


def segment_metrics(
    t: np.ndarray,
    q_BN: np.ndarray,
    q_RN: np.ndarray,
    tau_c_B: np.ndarray,
    u_cmd: np.ndarray,
    k0: int,
    k1: int,
    axis: int = 0,
) -> dict[str, float]:
    """Error and effort figures of one episode over steps ``k0 <= k < k1``.

    For comparing controllers that ran one after the other (scheduled swaps).

    Parameters
    ----------
    t : (K+1,) s
    q_BN, q_RN : (K+1, 4)
    tau_c_B, u_cmd : (K+1, 3) torque on the body (N m) and command
    k0, k1 : int, step range
    axis : int, body axis of the error figures

    Returns
    -------
    dict: ``t_start_s``, ``t_end_s``, ``iae``, ``ise`` (rectangle rule over the
    steps), ``max_abs_error_rad``, ``rms_error_rad``, ``control_effort_Nms``,
    ``max_abs_command``.
    """
    err = (euler_from_quat(q_RN[k0:k1]) - euler_from_quat(q_BN[k0:k1]))[:, axis]
    dt = np.diff(t[k0:k1 + 1]) if k1 < t.size else np.append(np.diff(t[k0:k1]), t[1] - t[0])
    dt = dt[: err.size]
    return {
        "t_start_s": float(t[k0]),
        "t_end_s": float(t[min(k1, t.size - 1)]),
        "iae": float(np.sum(np.abs(err) * dt)),
        "ise": float(np.sum(err**2 * dt)),
        "max_abs_error_rad": float(np.max(np.abs(err))),
        "rms_error_rad": float(np.sqrt(np.mean(err**2))),
        "control_effort_Nms": float(np.sum(np.linalg.norm(tau_c_B[k0:k1], axis=-1) * dt)),
        "max_abs_command": float(np.max(np.abs(u_cmd[k0:k1]))),
    }


#: the ``--json`` keys that come from the metrics (null where the scenario has none;
#: docs/architecture.md, "Command line")
METRIC_KEYS = ("time_constant_s", "rise_time_s", "settling_time_s", "overshoot_pct", "steady_state_error_rad",
               "control_effort_Nms", "cost_J", "iae", "ise", "itae")

#: further keys some scenarios define
_EXTRA_KEYS = ("mse", "max_abs_error_rad", "fitness_f", "final_error_rad")


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def episode_report(scn, tr, controller_type: str, duration_s: float, wall_s: float,
                   schedule: list[tuple[float, int, str]] | None = None) -> dict:
    """The metrics of one episode (P = 1) as the ``run --json`` object, without ``bag``.

    Parameters
    ----------
    scn : Scenario
    tr : Trajectory
        One episode (P = 1), from the graph or the batch engine.
    controller_type : str
        The law at the start.
    duration_s, wall_s : float
        Simulated and wall time, s.
    schedule : list of (time s, step, controller_type), optional
        Scheduled swaps: adds ``segments``, the metrics of each controller's stretch.
    """
    s = scn.values["scenario"]
    n = tr.q_BN.shape[1]
    m = scenario_metrics(tr.t, tr.q_BN[:1], tr.q_RN[:1], tr.tau_actuators_B[:1], s,
                         step_time=scn.param("guidance", "step_time"))
    out: dict = {
        "scenario": scn.name,
        "controller_type": controller_type,
        "sim_time_s": float(duration_s),
        "wall_time_s": float(wall_s),
        "real_time_factor": float(duration_s / wall_s) if wall_s > 0 else None,
    }
    for key in METRIC_KEYS:
        out[key] = _finite_or_none(float(m[key][0])) if key in m else None
    for key in _EXTRA_KEYS:
        if key in m:
            out[key] = _finite_or_none(float(m[key][0]))
    ape, ake = pointing_errors(tr.q_BN[0], tr.q_RN[0], None if tr.q_BN_est is None else tr.q_BN_est[0])
    settle = float(m["settling_time_s"][0]) if "settling_time_s" in m else None
    out.update(pointing_metrics(tr.t, ape, ake, pointing_start(s, settle)))
    figures = MagneticFigures(s["metrics.detumble_rate_deg_s"], scn.has_magnetorquers)
    if figures.enabled:
        out.update(magnetic_figures(figures, tr.t, tr.omega_BN_B[0], tr.h_wheels_B[0],
                                    None if tr.dipole_cmd_B is None else tr.dipole_cmd_B[0]))
    if schedule:
        bounds = [0] + [k for _, k, _ in schedule] + [n]
        kinds = [controller_type] + [kind for _, _, kind in schedule]
        out["segments"] = [
            {"controller_type": kind, **segment_metrics(tr.t, tr.q_BN[0], tr.q_RN[0], tr.tau_actuators_B[0],
                                                        tr.u_cmd[0], k0, k1, axis=s["metrics.axis"])}
            for kind, k0, k1 in zip(kinds, bounds[:-1], bounds[1:], strict=True) if k1 > k0
        ]
    return out
