"""The sensor models: a rate gyro, a star tracker, the wheels' Hall-sensor tachometers and a magnetometer.

Every model holds a leading episode axis P and is advanced once per control step k (t_k = k dt), in the
order the lockstep runs it (docs/sensors.md): :meth:`SensorSuite.sample` takes the plant's truth at t_k
and returns what the hardware reports at t_k. Noise comes from :mod:`attitude_sil.core.sensing.noise`,
one seeded stream per error source.

Gyro (per body axis, the standard rate-integrating gyro error model: IEEE Std 952-1997 annex C; Crassidis
and Junkins, *Optimal Estimation of Dynamic Systems*, 2nd ed., sec. 7.2.1). A rate-integrating gyro reports
the angle turned over each sample interval (a delta angle), here as its mean rate: the reading at t_k is
over [t_(k-1), t_k], omega_true = rotation vector of q_BN(t_(k-1))* ⊗ q_BN(t_k) / dt (at k = 0, the rate at
t_0), so a filter that integrates the readings follows a manoeuvre without the error a held sampled rate
makes (1/2 alpha dt^2 a step)::

    omega_meas = (I + diag(s)) (I - [m x]) omega_true + b_0 + b_gm + b_rw + N / sqrt(dt) n_k

with ``N`` the angle random walk (rad/s^0.5), ``b_gm`` a first-order Gauss-Markov bias of steady-state
standard deviation B (the bias instability) and correlation time tau, ``b_rw`` a rate random walk of
density K (rad/s^1.5), ``b_0`` a constant bias, ``s`` the scale-factor errors and ``m`` the small
misalignment angles of the sensor axes; then quantised to the resolution and clipped at the range.
Discretely, with phi = exp(-dt / tau)::

    b_gm[k+1] = phi b_gm[k] + B sqrt(1 - phi^2) n,    b_rw[k+1] = b_rw[k] + K sqrt(dt) n

Its Allan variance is the sum of the three sources' (IEEE Std 952 annex C):
``N^2 / T + K^2 T / 3 + (2 B^2 tau / T) (1 - tau / (2T) (3 - 4 e^(-T/tau) + e^(-2T/tau)))``
(:func:`allan_variance_model`), which the tests recover from a long run.

Star tracker: q_meas = q_true ⊗ dq(d), d ~ N(0, diag(sigma_cross^2, sigma_cross^2, sigma_about^2)) in the
body frame with sigma_about on the boresight axis. An exposure every 1 / rate_hz s (t_j = j / rate_hz) is
reported latency_s later, stamped with its exposure time t_j; an exposure inside a scheduled outage reports
no attitude (REP 145: orientation_covariance[0] = -1). A ``latency E`` fault makes the reports of its window
(of report time) carry the newest exposure at least latency_s + E old, at the same report steps: the first
reports of the window have nothing new (no attitude, stamped with the exposure they would have carried), and
at its end the tracker reports its newest exposure again, the ones the delay held back passed over.

Gyro faults (docs/faults.md), per axis over their window of steps, on the reading as above:
``scale K`` multiplies it by K, ``bias_jump B`` adds B deg/h, ``spike S`` adds S deg/s to one reading (or
to each in its ``for`` window), ``stuck`` holds the reading of the step before, ``off`` reads 0. The filter
is not told.

Magnetometer: the gyro's static errors on the true field in B (scale factor, misalignment, bias), white
noise, quantisation and saturation (:class:`Magnetometer`); it samples the field the plant publishes, where
the scenario has one.

Tachometer: a wheel's Hall sensors give counts_per_rev edges per revolution; the reading at t_k is the
count change over [t_(k-1), t_k] times 2 pi / (counts_per_rev dt) (rad/s), so it is quantised to that step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from attitude_sil.core.faults import Fault, HeldFaults, fault_steps, faults_of, first_step, outage_windows
from attitude_sil.core.plant.quaternion import (
    cross_matrix,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    rotation_vector,
    small_rotation,
)
from attitude_sil.core.sensing.noise import normals
from attitude_sil.errors import ScenarioError

__all__ = ["DEG", "ARCSEC", "GyroErrors", "Gyro", "StarTrackerErrors", "StarTracker", "StarTrackerReport",
           "Tachometer", "SensorSuite", "SensorSample", "allan_variance_model", "TrackerSchedule",
           "MagnetometerErrors", "Magnetometer"]

DEG = np.pi / 180.0
ARCSEC = DEG / 3600.0


@dataclass(frozen=True)
class GyroErrors:
    """A gyro's error parameters in SI units (per body axis where a 3-vector).

    Attributes
    ----------
    arw : float
        Angle random walk N, rad/s^0.5 (white rate noise density).
    bias_instability : float
        Steady-state standard deviation B of the Gauss-Markov bias, rad/s.
    correlation_time : float
        Its correlation time tau, s.
    rrw : float
        Rate random walk K, rad/s^1.5.
    bias : (3,) or (P, 3) rad/s
        Constant bias b_0 (one per episode where a Monte Carlo disperses it).
    scale_factor : (3,)
        Scale-factor errors s (dimensionless; 1e-6 per ppm).
    misalignment : (3,) rad
        Small rotation m of the sensor axes from the body axes.
    resolution : float
        Quantisation step, rad/s (0: none).
    range : float
        Saturation, rad/s.
    """

    arw: float = 0.0
    bias_instability: float = 0.0
    correlation_time: float = 300.0
    rrw: float = 0.0
    bias: tuple | np.ndarray = (0.0, 0.0, 0.0)
    scale_factor: tuple = (0.0, 0.0, 0.0)
    misalignment: tuple = (0.0, 0.0, 0.0)
    resolution: float = 0.0
    range: float = np.inf

    @classmethod
    def from_values(cls, v: dict) -> GyroErrors:
        """From the ``sensors`` node's parameters (``gyro.*``, datasheet units)."""
        return cls(arw=v["gyro.arw_deg_rt_h"] * DEG / 60.0,
                   bias_instability=v["gyro.bias_instability_deg_h"] * DEG / 3600.0,
                   correlation_time=v["gyro.bias_correlation_time_s"],
                   rrw=v["gyro.rrw_deg_h_rt_h"] * DEG / 3600.0 / 60.0,
                   bias=np.asarray(v["gyro.bias_deg_h"], dtype=float) * DEG / 3600.0,
                   scale_factor=tuple(np.asarray(v["gyro.scale_factor_ppm"], dtype=float) * 1e-6),
                   misalignment=tuple(np.asarray(v["gyro.misalignment_urad"], dtype=float) * 1e-6),
                   resolution=v["gyro.resolution_deg_s"] * DEG,
                   range=v["gyro.range_deg_s"] * DEG)

    def white_std(self, dt: float) -> float:
        """Standard deviation of one sample's white noise, N / sqrt(dt), rad/s."""
        return self.arw / np.sqrt(dt)


def allan_variance_model(T: np.ndarray, arw: float, bias_instability: float, correlation_time: float,
                         rrw: float) -> np.ndarray:
    """Allan variance (rad/s)^2 at cluster times T (s) of white rate noise, a Gauss-Markov bias and a rate
    random walk (IEEE Std 952-1997 annex C, eq. C.2, C.4 and the exponentially correlated term)."""
    T = np.asarray(T, dtype=float)
    tau = correlation_time
    x = T / tau
    gm = (2.0 * bias_instability**2 * tau / T) * (1.0 - (3.0 - 4.0 * np.exp(-x) + np.exp(-2.0 * x)) / (2.0 * x))
    return arw**2 / T + rrw**2 * T / 3.0 + gm


def sensor_axes(scale_factor, misalignment) -> np.ndarray:
    """C (3, 3) of a three-axis sensor: ``(I + diag(s)) (I - [m x])``, scale-factor errors s and the small
    misalignment angles m (rad) of its axes (x_sensor = C x_true)."""
    return (np.eye(3) + np.diag(scale_factor)) @ (np.eye(3) - cross_matrix(misalignment))


def quantise_and_clip(x: np.ndarray, resolution: float, limit: float) -> np.ndarray:
    """A reading ``x`` rounded to steps of ``resolution`` (0: none) and clipped at +-``limit``."""
    if resolution > 0.0:
        x = np.round(x / resolution) * resolution
    return np.clip(x, -limit, limit)


class Gyro:
    """A three-axis rate gyro on P episodes (module docstring: the error model).

    Parameters
    ----------
    errors : GyroErrors
    dt : float
        Sample period (the control step), s.
    seeds : (P,) int
        One seed per episode.
    """

    def __init__(self, errors: GyroErrors, dt: float, seeds: np.ndarray) -> None:
        self.errors = errors
        self.dt = float(dt)
        self.seeds = np.asarray(seeds, dtype=np.int64)
        self.dt_ns = int(round(self.dt * 1e9))
        self.faults: list[tuple[Fault, int, int]] = []  # (fault, first step, end step): :meth:`add_fault`
        e = errors
        #: omega_sensor = C omega_true
        self.C = sensor_axes(e.scale_factor, e.misalignment)
        self.phi = float(np.exp(-self.dt / e.correlation_time))
        self.reset()

    @property
    def n_episodes(self) -> int:
        return self.seeds.shape[0]

    def reset(self) -> None:
        """Step 0: the Gauss-Markov bias drawn from its steady state, the random walk at zero."""
        e = self.errors
        self.k = 0
        self._q_last = np.zeros(0)
        self.b_gm = e.bias_instability * normals(self.seeds, 0, "gyro_markov_init")
        self.b_rw = np.zeros((self.n_episodes, 3))
        self.last = None  # the reading of the step before (P, 3), for a stuck axis
        self.held = {}  # a stuck axis: the reading it holds (P,)

    def add_fault(self, fault: Fault, step: int | None = None) -> None:
        """A ``gyro.<axis>`` fault, from ``step`` (default: its time's) for its duration; a spike without
        ``for`` is one reading."""
        start, end = fault_steps(fault, self.dt_ns, step)
        if fault.mode == "spike" and fault.duration_s is None:
            end = start + 1
        self.faults.append((fault, start, end))

    def _faulted(self, w: np.ndarray, k: int) -> np.ndarray:
        """The reading ``w`` (P, 3) at step ``k`` with the faults active then (module docstring)."""
        w = w.copy()
        for f, start, end in self.faults:
            if not start <= k < end:
                continue
            i = "xyz".index(f.index)
            if f.mode == "scale":
                w[:, i] *= f.value
            elif f.mode == "bias_jump":
                w[:, i] += math.radians(f.value) / 3600.0
            elif f.mode == "spike":
                w[:, i] += math.radians(f.value)
            elif f.mode == "stuck":
                w[:, i] = self.held.setdefault((i, start), w[:, i].copy() if self.last is None else self.last[:, i])
            else:  # off
                w[:, i] = 0.0
        return w

    @property
    def drift(self) -> np.ndarray:
        """The bias the gyro adds now (P, 3) rad/s: constant, Gauss-Markov and random walk."""
        return np.asarray(self.errors.bias) + self.b_gm + self.b_rw

    def true_rate(self, q_BN: np.ndarray, omega_BN_B: np.ndarray, k: int) -> np.ndarray:
        """The mean body rate (P, 3) over [t_(k-1), t_k] from the attitudes at both ends (at k = 0: the rate)."""
        q_BN = np.asarray(q_BN, dtype=float)
        if k == 0:
            w = np.array(omega_BN_B, dtype=float)
        else:
            w = rotation_vector(quat_multiply(quat_conjugate(self._q_last), q_BN)) / self.dt
        self._q_last = q_BN.copy()
        return w

    def sample(self, q_BN: np.ndarray, omega_BN_B: np.ndarray, k: int) -> np.ndarray:
        """The reading (P, 3) rad/s at step ``k``: the mean rate over the last interval, from the true attitudes
        (P, 4) at its ends (the rate (P, 3) at k = 0); then the biases move to step k + 1."""
        if k != self.k:
            raise ScenarioError(f"gyro sampled at step {k}, expected step {self.k}")
        e = self.errors
        w = self.true_rate(q_BN, omega_BN_B, k) @ self.C.T + self.drift
        if e.arw > 0.0:
            w = w + e.white_std(self.dt) * normals(self.seeds, k, "gyro_white")
        w = quantise_and_clip(w, e.resolution, e.range)
        if self.faults:
            w = self._faulted(w, k)
        self.last = w
        if e.bias_instability > 0.0:
            self.b_gm = self.phi * self.b_gm + e.bias_instability * np.sqrt(1.0 - self.phi**2) * normals(
                self.seeds, k, "gyro_markov")
        if e.rrw > 0.0:
            self.b_rw = self.b_rw + e.rrw * np.sqrt(self.dt) * normals(self.seeds, k, "gyro_walk")
        self.k = k + 1
        return w


@dataclass(frozen=True)
class StarTrackerErrors:
    """A star tracker's noise and timing.

    Attributes
    ----------
    cross_boresight : float
        1-sigma noise about each axis across the boresight, rad.
    about_boresight : float
        1-sigma noise about the boresight, rad.
    boresight_axis : int
        Body axis of the boresight: 0, 1 or 2.
    rate_hz : float
        Exposures per second.
    latency : float
        Delay from exposure to report, s.
    outages : tuple of (start, end)
        Exposure times (s) in [start, end) report no attitude.
    """

    cross_boresight: float = 0.0
    about_boresight: float = 0.0
    boresight_axis: int = 2
    rate_hz: float = 4.0
    latency: float = 0.0
    outages: tuple = ()

    @classmethod
    def from_values(cls, v: dict) -> StarTrackerErrors:
        """From the ``sensors`` node's parameters (``star_tracker.*``); ScenarioError for outages that are not
        (start, end) pairs with end > start."""
        flat = list(v["star_tracker.outages_s"])
        if len(flat) % 2 or any(b <= a for a, b in zip(flat[0::2], flat[1::2], strict=False)):
            raise ScenarioError("sensors.star_tracker.outages_s must hold (start, end) pairs with end > start, s")
        return cls(cross_boresight=v["star_tracker.cross_boresight_arcsec"] * ARCSEC,
                   about_boresight=v["star_tracker.about_boresight_arcsec"] * ARCSEC,
                   boresight_axis=int(v["star_tracker.boresight_axis"]),
                   rate_hz=v["star_tracker.rate_hz"], latency=v["star_tracker.latency_s"],
                   outages=tuple(zip(flat[0::2], flat[1::2], strict=True)) + tuple(outage_windows(v)))

    @property
    def sigma_B(self) -> np.ndarray:
        """1-sigma noise per body axis (3,), rad."""
        s = np.full(3, self.cross_boresight)
        s[self.boresight_axis] = self.about_boresight
        return s


def _steps(value: float, dt: float, what: str) -> int:
    """``value`` s as a whole number of control steps, or ScenarioError."""
    n = round(value / dt)
    if abs(n * dt - value) > 1e-9 * max(1.0, value):
        raise ScenarioError(f"{what} = {value:g} s is not a whole number of control steps (dt = {dt:g} s)")
    return int(n)


class TrackerSchedule:
    """When a star tracker reports: an exposure every ``1 / rate_hz`` s, reported ``latency`` s later, both whole
    numbers of control steps (ScenarioError otherwise), so the graph and the batch engine keep one schedule.
    The tracker and the filter that waits for its reports (the ``estimator`` node) share it."""

    def __init__(self, rate_hz: float, latency: float, dt: float) -> None:
        self.period_steps = _steps(1.0 / rate_hz, dt, "star_tracker: 1 / rate_hz")
        self.latency_steps = _steps(latency, dt, "star_tracker.latency_s")
        if self.period_steps < 1:
            raise ScenarioError(f"star_tracker.rate_hz = {rate_hz:g} is above the control rate")

    def exposes_at(self, k: int) -> bool:
        """Whether step ``k`` is an exposure."""
        return k % self.period_steps == 0

    def reports_at(self, k: int) -> bool:
        """Whether step ``k`` carries a report (of exposure k - latency_steps)."""
        j = k - self.latency_steps
        return j >= 0 and self.exposes_at(j)


@dataclass
class StarTrackerReport:
    """What the star tracker reports at one step: the exposure step, its attitude, whether it is valid.

    Attributes
    ----------
    exposure_step : int
        j: the attitude was true at t_j (the message's stamp).
    q_BN : (P, 4)
        Measured attitude (the truth's where not ``valid``).
    valid : bool
        False inside an outage (no attitude: REP 145 covariance[0] = -1).
    """

    exposure_step: int
    q_BN: np.ndarray
    valid: bool


class StarTracker:
    """A star tracker on P episodes (module docstring: the model).

    The period and the latency must be whole numbers of control steps, so the
    schedule is the same in the graph and the batch engine.
    """

    def __init__(self, errors: StarTrackerErrors, dt: float, seeds: np.ndarray) -> None:
        self.errors = errors
        self.dt = float(dt)
        self.seeds = np.asarray(seeds, dtype=np.int64)
        self.schedule = TrackerSchedule(errors.rate_hz, errors.latency, dt)
        self._history: dict[int, np.ndarray] = {}  # exposure step -> true attitude, until reported

        self.stuck: list[tuple[float, float]] = []  # a frozen tracker's windows [start, end) of exposure time, s
        #: a slow tracker's windows [start, end) of report time, s, each with its extra latency in steps
        self.delays: list[tuple[float, float, int]] = []
        self._last = None  # the last attitude reported (P, 4), for a frozen tracker
        self._reported = -1  # the newest exposure step reported

    def add_delay(self, t0: float, t1: float, extra_s: float) -> None:
        """Reports from ``t0`` to ``t1`` s come ``extra_s`` s later (a whole number of control steps, else
        ScenarioError): the ``latency`` fault."""
        self.delays.append((t0, t1, _steps(extra_s, self.dt, "star_tracker latency")))

    def exposure_reported_at(self, k: int) -> int:
        """The exposure step a report at step ``k`` carries: the newest exposure at least the latency (and the
        extra latency of a ``latency`` fault then active) before it."""
        extra = sum(e for a, b, e in self.delays if a - 1e-9 <= k * self.dt < b - 1e-9)
        j = k - self.schedule.latency_steps
        return j if extra == 0 else (j - extra) // self.schedule.period_steps * self.schedule.period_steps

    def in_outage(self, j: int) -> bool:
        """Whether exposure step ``j`` falls in a scheduled outage."""
        return self._in(j, self.errors.outages)

    def _in(self, j: int, windows) -> bool:
        t = j * self.dt
        return any(a - 1e-9 <= t < b - 1e-9 for a, b in windows)

    def sample(self, q_BN: np.ndarray, k: int) -> StarTrackerReport | None:
        """Step ``k``: remember the true attitude (P, 4); return the report due at this step, or None."""
        if self.schedule.exposes_at(k):  # kept until it is reported
            self._history[k] = np.array(q_BN, dtype=float)
        if not self.schedule.reports_at(k):
            return None
        j = self.exposure_reported_at(k)
        if j <= self._reported:  # a slow tracker whose next solution is not out yet: nothing new to report
            return StarTrackerReport(k - self.schedule.latency_steps, q_BN, False)
        q_true = self._history[j]
        for old in [i for i in self._history if i <= j]:  # reported, or passed over (the newest goes out)
            del self._history[old]
        self._reported = j
        if self.in_outage(j):
            return StarTrackerReport(j, q_true, False)
        if self._last is not None and self._in(j, self.stuck):  # frozen: the last attitude again, as valid
            return StarTrackerReport(j, self._last, True)
        d = normals(self.seeds, j, "star_tracker") * self.errors.sigma_B
        self._last = quat_normalize(quat_multiply(q_true, small_rotation(d)))
        return StarTrackerReport(j, self._last, True)


class Tachometer:
    """The wheels' Hall-sensor speed readings (module docstring): count change over the last step."""

    def __init__(self, counts_per_rev: int, dt: float) -> None:
        if counts_per_rev < 1:
            raise ScenarioError(f"wheel_speed.counts_per_rev must be >= 1, got {counts_per_rev}")
        self.counts_per_rev = int(counts_per_rev)
        self.dt = float(dt)
        self.reset()

    def reset(self) -> None:
        self._last_counts: np.ndarray | None = None

    def counts(self, angle: np.ndarray) -> np.ndarray:
        """Hall-sensor edge counts of wheel angles (rad): floor(angle counts_per_rev / 2 pi)."""
        return np.floor(np.asarray(angle, dtype=float) * self.counts_per_rev / (2.0 * np.pi))

    def sample(self, angle: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Speed readings (..., n) rad/s from the wheel angles at t_k; the first step rounds the true speed."""
        lsb = 2.0 * np.pi / (self.counts_per_rev * self.dt)
        c = self.counts(angle)
        if self._last_counts is None:
            out = np.round(np.asarray(velocity, dtype=float) / lsb) * lsb
        else:
            out = (c - self._last_counts) * lsb
        self._last_counts = c
        return out


@dataclass(frozen=True)
class MagnetometerErrors:
    """A three-axis magnetometer's errors in SI units.

    Attributes
    ----------
    noise : float
        1-sigma white noise per axis, tesla.
    bias : (3,) tesla
        Constant bias (hard iron and offset).
    scale_factor : (3,)
        Scale-factor errors (dimensionless; 1e-6 per ppm).
    misalignment : (3,) rad
        Small rotation of the sensor axes from the body axes.
    resolution : float
        Quantisation step, tesla (0: none).
    range : float
        Saturation, tesla.
    """

    noise: float = 0.0
    bias: tuple = (0.0, 0.0, 0.0)
    scale_factor: tuple = (0.0, 0.0, 0.0)
    misalignment: tuple = (0.0, 0.0, 0.0)
    resolution: float = 0.0
    range: float = np.inf

    @classmethod
    def from_values(cls, v: dict) -> MagnetometerErrors:
        """From the ``sensors`` node's parameters (``magnetometer.*``, datasheet units)."""
        return cls(noise=v["magnetometer.noise_nt"] * 1e-9,
                   bias=tuple(np.asarray(v["magnetometer.bias_nt"], dtype=float) * 1e-9),
                   scale_factor=tuple(np.asarray(v["magnetometer.scale_factor_ppm"], dtype=float) * 1e-6),
                   misalignment=tuple(np.asarray(v["magnetometer.misalignment_urad"], dtype=float) * 1e-6),
                   resolution=v["magnetometer.resolution_nt"] * 1e-9, range=v["magnetometer.range_nt"] * 1e-9)


class Magnetometer:
    """A three-axis magnetometer on P episodes: ``b_meas = (I + diag(s)) (I - [m x]) b_true + b_0 + sigma n_k``,
    quantised to the resolution and clipped at the range, the field's model of errors as the gyro's
    (module docstring); its noise on a stream of its own (``magnetometer``), so a draw depends only on
    (seed, step, axis)."""

    def __init__(self, errors: MagnetometerErrors, seeds: np.ndarray) -> None:
        self.errors = errors
        self.seeds = np.asarray(seeds, dtype=np.int64)
        #: b_sensor = C b_true
        self.C = sensor_axes(errors.scale_factor, errors.misalignment)
        self.faults = HeldFaults()  # off and stuck

    def sample(self, b_true_B: np.ndarray, k: int) -> np.ndarray:
        """The reading (P, 3) tesla at step ``k`` of the true field in B (P, 3) tesla; while a fault is active,
        0 (``off``) or the reading of the step before it (``stuck``)."""
        e = self.errors
        b = np.asarray(b_true_B, dtype=float) @ self.C.T + np.asarray(e.bias)
        if e.noise > 0.0:
            b = b + e.noise * normals(self.seeds, k, "magnetometer")
        return self.faults.apply(quantise_and_clip(b, e.resolution, e.range), k)

    @property
    def variance(self) -> np.ndarray:
        """The declared per-axis variance (3,) tesla^2: the white noise's (REP 145's covariance diagonal)."""
        return np.full(3, self.errors.noise**2)


@dataclass
class SensorSample:
    """What the sensors report at step k: the gyro reading (P, 3) and the star tracker's report, or None."""

    k: int
    omega_meas_B: np.ndarray
    star_tracker: StarTrackerReport | None


class SensorSuite:
    """The gyro and the star tracker of P episodes, advanced together from the ``sensors`` parameters.

    Parameters
    ----------
    values : dict
        The ``sensors`` node's parameter values.
    dt : float
        Control step, s.
    seeds : (P,) int, optional
        One seed per episode (default: ``seed`` for every episode).
    n_episodes : int
    """

    def __init__(self, values: dict, dt: float, n_episodes: int = 1, seeds=None) -> None:
        seeds = np.full(n_episodes, int(values["seed"])) if seeds is None else np.asarray(seeds, dtype=np.int64)
        if seeds.shape != (n_episodes,):
            raise ScenarioError(f"sensors: {seeds.size} seeds for {n_episodes} episodes")
        self.dt_ns = int(round(dt * 1e9))
        self.gyro = Gyro(GyroErrors.from_values(values), dt, seeds)
        self.star_tracker = StarTracker(StarTrackerErrors.from_values(values), dt, seeds)  # its outages in
        self.tachometer = Tachometer(int(values["wheel_speed.counts_per_rev"]), dt)
        self.magnetometer = Magnetometer(MagnetometerErrors.from_values(values), seeds)
        for f in faults_of(values, "sensors"):
            if (f.kind, f.mode) != ("star_tracker", "off"):  # (an outage of StarTrackerErrors already)
                self.add_fault(f)

    def add_fault(self, fault: Fault, step: int | None = None) -> None:
        """A fault of a sensor (:data:`attitude_sil.core.faults.OWNER`'s ``sensors``), from ``step`` (default: its
        time's) for its duration."""
        start = first_step(fault.time_s, self.dt_ns) if step is None else int(step)
        if fault.kind == "gyro":
            self.gyro.add_fault(fault, start)
            return
        if fault.kind == "magnetometer":
            self.magnetometer.faults.add(fault, self.dt_ns, start)
            return
        t0 = start * self.dt_ns * 1e-9  # the tracker's windows are of exposure time
        t1 = math.inf if fault.duration_s is None else t0 + fault.duration_s
        if fault.mode == "stuck":
            self.star_tracker.stuck.append((t0, t1))
        elif fault.mode == "latency":
            self.star_tracker.add_delay(t0, t1, fault.value)
        elif fault.mode == "off":
            st = self.star_tracker
            st.errors = replace(st.errors, outages=st.errors.outages + ((t0, t1),))
        else:
            raise ScenarioError(f"fault '{fault}': the sensors fly no {fault.kind} {fault.mode}")

    def sample(self, q_BN: np.ndarray, omega_BN_B: np.ndarray, k: int) -> SensorSample:
        """The readings at step ``k`` of the truth (P, 4), (P, 3)."""
        return SensorSample(k, self.gyro.sample(q_BN, omega_BN_B, k), self.star_tracker.sample(q_BN, k))
