"""Dispersions of one scenario: what a Monte Carlo campaign (and a robust-design cost) varies per run.

A ``dispersions`` mapping (in a Monte Carlo spec, or a tuning spec's
``robust`` section)::

    inertia_pct:          {dist: normal, scale: [5, 5, 5]}     # per principal axis, % (1 sigma)
    initial_attitude_deg: {dist: uniform, scale: 0.5}          # added to plant.initial_attitude_rpy_deg
    initial_rate_deg_s:   {dist: normal, scale: 0.01}          # added to plant.initial_body_rate
    setpoint_deg:         {dist: normal, scale: [0.1, 0, 0]}   # added to guidance.setpoint_rpy_deg
    motor_constant_pct:   {dist: normal, scale: 3}             # K_i = K_b (and the torque at the current limit)
    noise_level_pct:      {dist: uniform, scale: 50}           # disturbance noise.power x (1 + d / 100)
    noise_seeds: true                                          # noise.seed + run (default when noise is on)
    wheel_failure: {probability: 0.1, modes: [lost, stuck], time: [0, 20]}
    faults:               # any fault of docs/faults.md, each drawn per run (at most 8 entries)
      - {fault: gyro.x bias_jump, probability: 0.3, time: [2, 10], value: [10, 100], for: 5}
    # (modes may add torque_limit with torque_limit_Nm: [low, high] and speed_limit with speed_limit_rpm: [low, high],
    #  each run's limit uniform in its range)
    sensor_noise: {attitude_std_deg: 0.001, rate_std_deg_s: 0.0005}   # seed: sensor_noise.seed + run
    gyro_bias_deg_h:      {dist: normal, scale: 1.0}           # added to sensors.gyro.bias_deg_h per axis
    sensor_seeds: true                                         # sensors.seed + run (default with the sensors on)
    residual_dipole_Am2:  {dist: normal, scale: 0.01}          # added to disturbance.residual_dipole.moment
    magnetometer_bias_nt: {dist: normal, scale: 200}           # added to sensors.magnetometer.bias_nt per axis
    epoch_s:              {dist: uniform, scale: 43200}        # added to orbit.epoch, whole seconds (the field's)

``dist: normal`` draws ``scale`` x N(0, 1), ``dist: uniform`` ``scale`` x U(-1, 1);
``scale`` is one number or one per axis. Run i draws from its own stream,
``numpy.random.default_rng([seed, i])``, always the same slots in the same
order, so a run's values depend only on the seed and its index: not on the
chunk, the worker or which other dispersions are on.

Every dispersed value is a scenario value (:func:`episode_values` gives them
per run for :func:`attitude_sil.core.sim.engine.simulate`, :func:`run_scenario`
one run's as a :class:`~attitude_sil.core.sim.scenario.Scenario`), so a run
re-runs through the node graph exactly.
"""

from __future__ import annotations

import difflib
from datetime import timedelta
from typing import Any

import numpy as np
from scipy.special import ndtri

from attitude_sil.core.environment.earth_time import epoch_from_text
from attitude_sil.core.faults import FAULT_NODES, VALUED
from attitude_sil.core.plant.wheels import GEOMETRIES
from attitude_sil.core.sim.build import command_faults_of
from attitude_sil.core.sim.scenario import Scenario, check_fault_lines, derived_values, effective_values
from attitude_sil.errors import ScenarioError, SpecError

__all__ = ["DISPERSION_KEYS", "check_dispersions", "draw", "episode_values", "run_scenario", "value_columns"]

#: numeric dispersions: key -> (width, unit)
_NUMERIC = {"inertia_pct": 3, "initial_attitude_deg": 3, "initial_rate_deg_s": 3, "setpoint_deg": 3,
            "motor_constant_pct": 1, "noise_level_pct": 1, "gyro_bias_deg_h": 3, "residual_dipole_Am2": 3,
            "magnetometer_bias_nt": 3, "epoch_s": 1}
DISPERSION_KEYS = (*_NUMERIC, "noise_seeds", "wheel_failure", "sensor_noise", "sensor_seeds", "faults")
#: the per-run uniform slots, in draw order
_SLOTS = {"inertia_pct": slice(0, 3), "initial_attitude_deg": slice(3, 6), "initial_rate_deg_s": slice(6, 9),
          "setpoint_deg": slice(9, 12), "motor_constant_pct": slice(12, 13), "noise_level_pct": slice(13, 14),
          "failure_happens": 14, "failure_wheel": 15, "failure_time": 16, "failure_mode": 17,
          "gyro_bias_deg_h": slice(18, 21), "residual_dipole_Am2": slice(21, 24),
          "magnetometer_bias_nt": slice(24, 27), "epoch_s": 27, "failure_value": 28,
          "faults": slice(29, 53)}  # per entry of ``faults``: whether, when, how large
#: (slots are drawn in order from each run's stream: a slot added at the end leaves the others' values as they were)
_N_SLOTS = 53
#: entries of the ``faults`` dispersion a campaign may have (three slots each)
MAX_FAULT_ENTRIES = 8
#: the per-run key of the drawn faults: the run's ``faults`` list, set under /** (each node flies its own)
FAULTS_KEY = "/**.faults"
#: a wheel failure's modes, and the range key of each that has a size
_FAILURE_MODES = {"lost": None, "stuck": None, "torque_limit": "torque_limit_Nm", "speed_limit": "speed_limit_rpm",
                  "friction": "friction_factor"}


def _number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and bool(np.isfinite(v))


def check_dispersions(where: str, raw: Any, scn: Scenario) -> dict:
    """A ``dispersions`` mapping, validated against the scenario it disperses.

    Raises
    ------
    SpecError
        One line naming ``where``, the key and the rule.
    """
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise SpecError(f"{where}: dispersions must be a mapping, got {type(raw).__name__}")
    out: dict = {}
    for key, value in raw.items():
        if key not in DISPERSION_KEYS:
            close = difflib.get_close_matches(str(key), DISPERSION_KEYS, n=1)
            raise SpecError(f"{where}: unknown dispersion {key!r}" + (f" (did you mean {close[0]!r}?)" if close else "")
                            + f"; known: {', '.join(DISPERSION_KEYS)}")
        at = f"{where}: dispersions.{key}"
        if key in _NUMERIC:
            if not isinstance(value, dict) or set(value) - {"dist", "scale"} or "scale" not in value:
                raise SpecError(f"{at} must be a mapping {{dist: normal|uniform, scale: ...}}, got {value!r}")
            dist = value.get("dist", "normal")
            if dist not in ("normal", "uniform"):
                raise SpecError(f"{at}.dist must be normal or uniform, got {dist!r}")
            scale = value["scale"]
            width = _NUMERIC[key]
            vals = scale if isinstance(scale, list) else [scale]
            if len(vals) not in (1, width) or not all(_number(v) and v >= 0 for v in vals):
                raise SpecError(f"{at}.scale must be a number >= 0" + (f" or {width} of them" if width > 1 else "")
                                + f", got {scale!r}")
            out[key] = {"dist": dist, "scale": np.broadcast_to(np.asarray(vals, dtype=float), (width,)).copy()}
        elif key in ("noise_seeds", "sensor_seeds"):
            if not isinstance(value, bool):
                raise SpecError(f"{at} must be true or false, got {value!r}")
            out[key] = value
        elif key == "wheel_failure":
            sizes = [v for v in _FAILURE_MODES.values() if v]
            if not isinstance(value, dict) or set(value) - {"probability", "modes", "time", *sizes}:
                raise SpecError(f"{at} must be a mapping of probability, modes, time, {', '.join(sizes)}, "
                                f"got {value!r}")
            p = value.get("probability", 1.0)
            if not (_number(p) and 0.0 <= p <= 1.0):
                raise SpecError(f"{at}.probability must be a number in 0..1, got {p!r}")
            modes = value.get("modes", ["lost", "stuck"])
            if not isinstance(modes, list) or not modes or not all(m in _FAILURE_MODES for m in modes):
                raise SpecError(f"{at}.modes must be a non-empty list of {', '.join(_FAILURE_MODES)}, got {modes!r}")
            ranges = {}
            for m in modes:
                size = _FAILURE_MODES[m]
                r = value.get(size) if size else None
                if size and not (isinstance(r, list) and len(r) == 2 and all(_number(v) and v >= 0 for v in r)
                                 and r[0] <= r[1]):
                    raise SpecError(f"{at}.{size} must be [low, high], 0 <= low <= high, for mode {m}, got {r!r}")
                if size:
                    ranges[m] = [float(v) for v in r]
            t = value.get("time", [0.0, scn.duration])
            if not (isinstance(t, list) and len(t) == 2 and all(_number(v) and v >= 0 for v in t) and t[0] <= t[1]):
                raise SpecError(f"{at}.time must be [earliest, latest] s, 0 <= earliest <= latest, got {t!r}")
            if scn.param("wheels", "actuator") != "reaction_wheels":
                raise SpecError(f"{at}: the scenario's actuator is {scn.param('wheels', 'actuator')}; wheel failures "
                                "need reaction_wheels")
            out[key] = {"probability": float(p), "modes": list(modes), "time": [float(v) for v in t], "limits": ranges}
        elif key == "faults":
            out[key] = _check_fault_entries(at, value, scn)
        elif key == "sensor_noise":
            if not isinstance(value, dict) or set(value) - {"attitude_std_deg", "rate_std_deg_s"}:
                raise SpecError(f"{at} must be a mapping of attitude_std_deg, rate_std_deg_s, got {value!r}")
            for k, v in value.items():
                if not (_number(v) and v >= 0):
                    raise SpecError(f"{at}.{k} must be a number >= 0, got {v!r}")
            out[key] = {"attitude_std_deg": float(value.get("attitude_std_deg", 0.0)),
                        "rate_std_deg_s": float(value.get("rate_std_deg_s", 0.0))}
    return _check_against(where, out, scn)


def _check_against(where: str, out: dict, scn: Scenario) -> dict:
    """The checked dispersions ``out``, refused in one line where the scenario has nothing they could vary; the
    seeds' defaults set from it."""
    if "motor_constant_pct" in out and scn.param("wheels", "actuator") != "reaction_wheels":
        raise SpecError(f"{where}: dispersions.motor_constant_pct: the scenario's actuator is "
                        f"{scn.param('wheels', 'actuator')}; motor constants need reaction_wheels")
    noise_on = "noise" in scn.param("disturbance", "models")
    if "noise_level_pct" in out and not noise_on:
        raise SpecError(f"{where}: dispersions.noise_level_pct: the scenario has no noise disturbance "
                        "(set disturbance.models: [noise])")
    out.setdefault("noise_seeds", noise_on)
    if ("gyro_bias_deg_h" in out or out.get("sensor_seeds")) and not scn.has_sensors:
        raise SpecError(f"{where}: dispersions of the sensors need a scenario that runs them (scenario.sensors: true "
                        "or feedback: estimate, e.g. config/hst_roll_step_sensors.yaml)")
    out.setdefault("sensor_seeds", scn.has_sensors)
    if "residual_dipole_Am2" in out and "residual_dipole" not in scn.param("disturbance", "models"):
        raise SpecError(f"{where}: dispersions.residual_dipole_Am2: the scenario has no residual dipole "
                        "(add residual_dipole to disturbance.models, with a field model)")
    if "magnetometer_bias_nt" in out and not (scn.has_sensors and scn.param(
            "plant", "environment.magnetic_field.model") != "none"):
        raise SpecError(f"{where}: dispersions.magnetometer_bias_nt: the scenario has no magnetometer (it needs the "
                        "sensors and a field model)")
    if "epoch_s" in out and scn.param("plant", "environment.magnetic_field.model") == "none":
        raise SpecError(f"{where}: dispersions.epoch_s: the scenario has no field model (the epoch turns the Earth "
                        "under the orbit and dates the field)")
    return out


def draw(seed: int, runs) -> np.ndarray:
    """The uniform slots of runs ``runs``: (n, _N_SLOTS) in (0, 1), run i from ``default_rng([seed, i])``."""
    out = np.empty((len(runs), _N_SLOTS))
    for r, i in enumerate(np.asarray(runs, dtype=np.int64).tolist()):
        bits = np.random.default_rng([int(seed), i]).integers(0, 2**53, _N_SLOTS)
        out[r] = (bits + 0.5) / 2.0**53
    return out


def _offsets(d: dict, u: np.ndarray) -> np.ndarray:
    z = ndtri(u) if d["dist"] == "normal" else 2.0 * u - 1.0
    return d["scale"] * z


def _check_fault_entries(at: str, raw: Any, scn: Scenario) -> list[dict]:
    """The ``faults`` dispersion: a list of {fault: "TARGET MODE", probability, time: [t0, t1], value: [low, high]
    (a mode with a size), for: D (optional)}, each checked as a fault line of the run would be."""
    if not isinstance(raw, list) or not 1 <= len(raw) <= MAX_FAULT_ENTRIES:
        raise SpecError(f"{at} must be a list of 1..{MAX_FAULT_ENTRIES} mappings, got {raw!r}")
    out = []
    for i, e in enumerate(raw):
        where = f"{at}[{i}]"
        if not isinstance(e, dict) or set(e) - {"fault", "probability", "time", "value", "for"} or "fault" not in e:
            raise SpecError(f"{where} must be a mapping of fault, probability, time, value, for, got {e!r}")
        words = str(e["fault"]).split()
        p, t = e.get("probability", 1.0), e.get("time", [0.0, scn.duration])
        if not (_number(p) and 0.0 <= p <= 1.0):
            raise SpecError(f"{where}.probability must be a number in 0..1, got {p!r}")
        if not (isinstance(t, list) and len(t) == 2 and all(_number(v) and v >= 0 for v in t) and t[0] <= t[1]):
            raise SpecError(f"{where}.time must be [earliest, latest] s, 0 <= earliest <= latest, got {t!r}")
        size = e.get("value")
        valued = len(words) == 2 and words[1] in VALUED
        if valued != (size is not None) or (valued and not (isinstance(size, list) and len(size) == 2 and all(
                _number(v) for v in size) and size[0] <= size[1])):
            raise SpecError(f"{where}.value must be [low, high] where the mode has a size, and absent where not, "
                            f"got {size!r}")
        entry = {"fault": " ".join(words), "probability": float(p), "time": [float(v) for v in t],
                 "value": None if size is None else [float(v) for v in size], "for": e.get("for")}
        try:  # the extremes as the run's fault lines, against the scenario
            for v in ([None] if size is None else size):
                line = _fault_line(entry, t[1], v)
                check_fault_lines(scn, [line])
                command_faults_of({**scn.values["wheels"], "faults": [line]})  # a delay in whole steps
        except ScenarioError as exc:
            raise SpecError(f"{where}: {exc}") from None
        out.append(entry)
    return out


def _fault_line(entry: dict, time_s: float, value: float | None) -> str:
    """One drawn fault as a line of the ``faults`` list."""
    size = "" if value is None else f" {value:g}"
    span = "" if entry["for"] is None else f" for {entry['for']:g}"
    return f"{entry['fault']}{size} at {time_s:g}{span}"


def _fault_lists(entries: list[dict], u: np.ndarray, scn: Scenario) -> np.ndarray:
    """Each run's ``faults`` list (n,) of tuples: the scenario's own lines, then the faults drawn for it (a time
    in whole milliseconds and a size in four significant digits, as a file states them)."""
    own = list(dict.fromkeys(line for node in FAULT_NODES for line in scn.values[node]["faults"]))
    slots = u[:, _SLOTS["faults"]]
    out = np.empty(u.shape[0], dtype=object)
    for r in range(u.shape[0]):
        lines = list(own)
        for i, e in enumerate(entries):
            happens, when, size = slots[r, 3 * i:3 * i + 3]
            if happens < e["probability"]:
                t0, t1 = e["time"]
                lo, hi = e["value"] or (0.0, 0.0)
                value = None if e["value"] is None else float(f"{lo + (hi - lo) * size:.4g}")
                lines.append(_fault_line(e, round(t0 + (t1 - t0) * when, 3), value))
        out[r] = tuple(lines)
    return out


def _failure_values(wf: dict, u: np.ndarray, n_wheels: int) -> dict[str, np.ndarray]:
    """The ``wheels.failure.*`` values of runs with uniform slots ``u`` (n, _N_SLOTS) under the ``wheel_failure``
    dispersion ``wf``: which wheel (0: none), when (whole milliseconds: a time a scenario file states exactly),
    how, and a limited drive's size (whole thousandths)."""
    out = {}
    happens = u[:, 14] < wf["probability"]
    out["wheels.failure.wheel"] = np.where(happens, 1 + np.minimum((u[:, 15] * n_wheels).astype(np.int64),
                                                                   n_wheels - 1), 0)
    t0, t1 = wf["time"]
    out["wheels.failure.time"] = np.where(happens, np.round(t0 + (t1 - t0) * u[:, 16], 3), 0.0)
    modes = np.asarray(wf["modes"])
    out["wheels.failure.mode"] = np.where(happens, modes[np.minimum((u[:, 17] * len(modes)).astype(np.int64),
                                                                     len(modes) - 1)], "lost")
    if wf.get("limits"):
        limit = np.zeros(u.shape[0])
        for mode, (lo, hi) in wf["limits"].items():
            chosen = out["wheels.failure.mode"] == mode
            limit[chosen] = np.round(lo + (hi - lo) * u[chosen, _SLOTS["failure_value"]], 3)
        out["wheels.failure.value"] = limit
    return out


def episode_values(scn: Scenario, dispersions: dict, seed: int, runs) -> dict[str, np.ndarray]:
    """The dispersed scenario values of runs ``runs`` (n,): ``{"node.param": (n, ...)}`` for ``simulate``.

    Only what a dispersion changes is returned (nothing for an empty mapping).
    """
    runs = np.asarray(runs, dtype=np.int64)
    n = len(runs)
    u = draw(seed, runs)
    v = scn.values
    out: dict[str, np.ndarray] = {}
    if "inertia_pct" in dispersions:
        f = 1.0 + _offsets(dispersions["inertia_pct"], u[:, _SLOTS["inertia_pct"]]) / 100.0
        for node in ("plant", "disturbance"):
            base = np.asarray(v[node]["inertia"], dtype=float)
            if base.size == 3:
                out[f"{node}.inertia"] = base * f
            else:  # J_ij sqrt(f_i f_j): symmetric, principal moments scale by f_i for a diagonal J
                s = np.sqrt(f)
                out[f"{node}.inertia"] = (base.reshape(3, 3) * s[:, :, None] * s[:, None, :]).reshape(n, 9)
    if "initial_attitude_deg" in dispersions:
        out["plant.initial_attitude_rpy_deg"] = (np.asarray(v["plant"]["initial_attitude_rpy_deg"])
                                                 + _offsets(dispersions["initial_attitude_deg"], u[:, 3:6]))
        if scn.has_sensors:  # the filter starts where it believes the plant starts, not at the dispersed truth
            belief = effective_values(scn, "estimator")["initial_attitude_rpy_deg"]
            out["estimator.initial_attitude_rpy_deg"] = np.tile(np.asarray(belief, dtype=float), (n, 1))
    if "initial_rate_deg_s" in dispersions:
        out["plant.initial_body_rate"] = (np.asarray(v["plant"]["initial_body_rate"])
                                          + np.radians(_offsets(dispersions["initial_rate_deg_s"], u[:, 6:9])))
    if "setpoint_deg" in dispersions:
        out["guidance.setpoint_rpy_deg"] = (np.asarray(v["guidance"]["setpoint_rpy_deg"])
                                            + _offsets(dispersions["setpoint_deg"], u[:, 9:12]))
    if "motor_constant_pct" in dispersions:
        f = 1.0 + _offsets(dispersions["motor_constant_pct"], u[:, 12]) / 100.0
        f = np.maximum(f, 1e-3)
        for name in ("motor.torque_constant", "motor.back_emf_constant", "motor.torque_max"):  # current limit kept
            out[f"wheels.{name}"] = v["wheels"][name] * f
    if "noise_level_pct" in dispersions:
        f = np.maximum(1.0 + _offsets(dispersions["noise_level_pct"], u[:, 13]) / 100.0, 0.0)
        out["disturbance.noise.power"] = np.asarray(v["disturbance"]["noise.power"], dtype=float) * f[:, None]
    if dispersions.get("noise_seeds"):
        out["disturbance.noise.seed"] = v["disturbance"]["noise.seed"] + runs
    if "wheel_failure" in dispersions:
        out.update(_failure_values(dispersions["wheel_failure"], u, GEOMETRIES[v["wheels"]["geometry"]]().shape[1]))
    if "faults" in dispersions:
        out[FAULTS_KEY] = _fault_lists(dispersions["faults"], u, scn)
    if "gyro_bias_deg_h" in dispersions:
        out["sensors.gyro.bias_deg_h"] = (np.asarray(v["sensors"]["gyro.bias_deg_h"], dtype=float)
                                          + _offsets(dispersions["gyro_bias_deg_h"], u[:, _SLOTS["gyro_bias_deg_h"]]))
    if dispersions.get("sensor_seeds"):
        out["sensors.seed"] = v["sensors"]["seed"] + runs
    if "residual_dipole_Am2" in dispersions:
        out["disturbance.residual_dipole.moment"] = (
            np.asarray(v["disturbance"]["residual_dipole.moment"], dtype=float)
            + _offsets(dispersions["residual_dipole_Am2"], u[:, _SLOTS["residual_dipole_Am2"]]))
    if "magnetometer_bias_nt" in dispersions:
        out["sensors.magnetometer.bias_nt"] = (
            np.asarray(v["sensors"]["magnetometer.bias_nt"], dtype=float)
            + _offsets(dispersions["magnetometer_bias_nt"], u[:, _SLOTS["magnetometer_bias_nt"]]))
    if "epoch_s" in dispersions:
        out["plant.orbit.epoch"] = _epochs(v["plant"]["orbit.epoch"],
                                           _offsets(dispersions["epoch_s"], u[:, _SLOTS["epoch_s"]]))
    if "sensor_noise" in dispersions:
        sn = dispersions["sensor_noise"]
        out["controller.sensor_noise.attitude_std_deg"] = np.full(n, sn["attitude_std_deg"])
        out["controller.sensor_noise.rate_std_deg_s"] = np.full(n, sn["rate_std_deg_s"])
        out["controller.sensor_noise.seed"] = v["controller"]["sensor_noise.seed"] + runs
    return out


def _plain(value) -> Any:
    a = np.asarray(value)
    if a.dtype.kind in "US":
        return str(a)
    if a.ndim == 0:
        return int(a) if a.dtype.kind in "iu" else float(a)
    return [int(x) if a.dtype.kind in "iu" else float(x) for x in a.tolist()]


def _epochs(epoch: str, offsets_s: np.ndarray) -> np.ndarray:
    """``epoch`` (ISO 8601 UTC) plus each of ``offsets_s`` (n,) rounded to whole seconds, as ISO 8601 texts
    (a time a scenario file states exactly)."""
    start = epoch_from_text(epoch, "orbit.epoch")
    return np.array([(start + timedelta(seconds=int(np.rint(d)))).strftime("%Y-%m-%dT%H:%M:%SZ")
                     for d in offsets_s])


def run_scenario(scn: Scenario, values: dict[str, np.ndarray], row: int) -> Scenario:
    """Row ``row`` of :func:`episode_values` as a scenario: the run's values set, validated.

    Raises
    ------
    ScenarioError
        A dispersed value the schema refuses (e.g. a negative inertia).
    """
    # the flight software's B-dot gain is the nominal plant's k*: a dispersed inertia must not move it
    k_star = derived_values(scn, "controller").get("bdot.gain")
    if k_star is not None:
        scn = scn.with_values("controller", **{"bdot.gain": k_star})
    for key, col in values.items():
        node, _, name = key.partition(".")
        node = "/**" if name.startswith("orbit.") else node  # one orbit: every node that flies it
        try:
            scn = scn.with_values(node, **{name: list(col[row]) if key == FAULTS_KEY else _plain(col[row])})
        except ScenarioError as exc:
            raise ScenarioError(f"run {row}: {exc}") from None
    return scn


def value_columns(values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Flat table columns of :func:`episode_values`: ``plant.inertia[0]``, ..., one (n,) array each."""
    cols: dict[str, np.ndarray] = {}
    for key, col in values.items():
        if key == FAULTS_KEY:  # each run's list, as one line of text
            cols["faults"] = np.array(["; ".join(lines) for lines in col])
            continue
        a = np.asarray(col)
        if a.ndim == 1:
            cols[key] = a
        else:
            for j in range(a.shape[1]):
                cols[f"{key}[{j}]"] = a[:, j]
    return cols
