"""Building the models of a scenario: its parameters, and the values that vary per episode, into step objects.

Each ``build_*`` function turns the parameters of one node of a
:class:`~attitude_sil.core.sim.scenario.Scenario` into the object that node
holds (:mod:`attitude_sil.core.sim.models`, the controller bank, the
disturbance model), for P episodes; the nodes build theirs with P = 1, the
drivers of :mod:`attitude_sil.core.sim.engine` with the batch's P and the
per-episode values of :data:`EPISODE_VALUES` (the Monte Carlo's
dispersions). :func:`check_episode` builds them all once to refuse what the
schema alone cannot see; :func:`flexible_states` reads a flexible run back
through a plant built the same way.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.analysis.metrics import flexible_split
from attitude_sil.core.control import registry
from attitude_sil.core.control.bank import ControllerBank
from attitude_sil.core.control.laws.bdot import BDot
from attitude_sil.core.control.momentum import CrossProductDumping, DipoleCommand
from attitude_sil.core.environment.ephemeris import Ephemeris, FieldAlongOrbit
from attitude_sil.core.faults import faults_of, first_step, wheel_failure_values
from attitude_sil.core.plant.actuators import RPM, NoActuator, SpeedLoopWheels, TorqueActuator
from attitude_sil.core.plant.command_faults import delay_steps
from attitude_sil.core.plant.disturbance import DisturbanceModel, orbit_rate
from attitude_sil.core.plant.fdir import WheelFdir
from attitude_sil.core.plant.lanes import FAIL_SPEED_LIMIT, WHEEL_FAILURE_MODES
from attitude_sil.core.plant.linear import LinearizedPlant
from attitude_sil.core.plant.magnetorquers import Magnetorquers, rod_axes
from attitude_sil.core.plant.plants import FLEXIBLE_CASES, FlexibleAxisPlant, PitchNormalizedPlant
from attitude_sil.core.plant.quaternion import quat_from_euler, quat_multiply
from attitude_sil.core.plant.rigid_body import inertia_matrix
from attitude_sil.core.plant.scene import BodyScene, body_scene
from attitude_sil.core.plant.wheels import GEOMETRIES, MotorParams, WheelAssembly
from attitude_sil.core.sensing.models import SensorSuite
from attitude_sil.core.sensing.registry import build_filter
from attitude_sil.core.sim.models import Guidance, MagneticLoop, Plant, Sensing, Wheels, per_episode
from attitude_sil.core.sim.params import NODE_PARAMS, spec_for
from attitude_sil.core.sim.scenario import Scenario, effective_values
from attitude_sil.errors import ScenarioError

__all__ = ["build_plant", "build_wheels", "build_disturbance", "build_guidance", "build_controller", "build_sensing",
           "build_environment", "build_scene", "build_dipole_command", "build_magnetorquers", "build_magnetic_loop",
           "law_bank", "check_episode", "schedule_from_scenario", "flexible_states", "flexible_settling",
           "initial_attitude", "motor_params", "available_wheels", "command_faults_of",
           "EPISODE_VALUES", "EPISODE_MOTOR", "EPISODE_FAILURE",
           "split_episode_values", "episode_laws", "check_episode_parameters",
           "episode_parameter_faults"]


def initial_attitude(values: dict, rpy0_deg=None) -> np.ndarray:
    """q_BN(0) from ``initial_attitude_rpy_deg`` then the extra ``initial_error_*`` rotation (in B)."""
    rpy = np.asarray(values["initial_attitude_rpy_deg"] if rpy0_deg is None else rpy0_deg, dtype=float)
    q = quat_from_euler(np.radians(rpy))
    angle = np.radians(values["initial_error_deg"])
    if angle != 0.0:
        axis = np.asarray(values["initial_error_axis"], dtype=float)
        norm = np.linalg.norm(axis)
        if norm == 0.0:
            raise ScenarioError("plant.initial_error_axis must not be zero")
        turn = np.append(np.sin(angle / 2) * axis / norm, np.cos(angle / 2))
        q = quat_multiply(q, turn)
    return q


def _flex_constants(p: dict, n_episodes: int, flex_case=None) -> tuple:
    """(k1, k2, omega^2) of the flexible mode, (P,) each, from ``flex.case``: the scenario's, or one per episode."""
    if flex_case is None:
        cases = [p["flex.case"]] * n_episodes
    else:
        cases = [str(c) for c in np.atleast_1d(np.asarray(flex_case, dtype=object))]
        if len(cases) != n_episodes:
            raise ScenarioError(f"plant.flex.case: {len(cases)} cases for {n_episodes} episodes")
        known = (*FLEXIBLE_CASES, "custom")
        bad = [c for c in cases if c not in known]
        if bad:
            raise ScenarioError(f"plant.flex.case: unknown case {bad[0]!r} (known: {', '.join(known)})")
    custom = (p["flex.k1"], p["flex.k2"], p["flex.omega_sq"])
    rows = [custom if c == "custom" else FLEXIBLE_CASES[c] for c in cases]
    return tuple(np.array(column, dtype=float) for column in zip(*rows, strict=True))


def build_plant(scn: Scenario, n_episodes: int = 1, inertia=None, rpy0_deg=None, omega0=None, flex_case=None):
    """The body model of the scenario's ``plant`` parameters (per-episode overrides optional).

    ``rigid_body`` gives a :class:`Plant`, ``linearized`` the model of
    :mod:`attitude_sil.core.plant.linear`; ``flexible_axis`` and
    ``pitch_normalized`` the single-axis models of :mod:`attitude_sil.core.plant.plants`.
    ``flex_case``: the ``flexible_axis`` plant's ``flex.case`` per episode (P names: paper 002's five
    plants in one batch); other models take none.
    """
    p = scn.values["plant"]
    dt = p["control_period"]
    rpy = per_episode(p["initial_attitude_rpy_deg"] if rpy0_deg is None else rpy0_deg, n_episodes, 3)
    w0 = per_episode(p["initial_body_rate"] if omega0 is None else omega0, n_episodes, 3)
    if p["model"] == "flexible_axis":
        a = p["flex.axis"]
        k1, k2, w2 = _flex_constants(p, n_episodes, flex_case)
        return FlexibleAxisPlant(p["flex.b"], k1, k2, w2, a, dt, np.radians(rpy[:, a]), w0[:, a], p["flex.alpha0"])
    if flex_case is not None:
        raise ScenarioError(f"plant.flex.case varies per episode for the flexible_axis model only, not {p['model']}")
    if p["model"] == "pitch_normalized":
        return PitchNormalizedPlant(p["pitch.epsilon"], dt, np.radians(rpy[:, 1]), w0[:, 1], p["pitch.h0"])
    m = inertia_matrix(p["inertia"] if inertia is None else inertia)
    m = np.array(np.broadcast_to(m, (n_episodes, 3, 3)))
    q0 = initial_attitude(p, rpy)
    if p["model"] == "linearized":
        return LinearizedPlant(m, dt, q0, w0)
    return Plant(m, dt, p["substeps"], q0, w0)


def flexible_states(scn: Scenario, tr, flex_case=None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid angle theta and deflection alpha (rad, (P, K+1) each) of a ``flexible_axis`` run.

    The plant is linear and the run's torques are known, so the trajectory's
    torques replayed through a fresh plant of the same scenario give its
    internal states exactly (the published attitude is only ``y = theta + k2 alpha``).
    ``flex_case``: the run's ``plant.flex.case`` per episode, if it had one.
    """
    plant = build_plant(scn, tr.tau_c_B.shape[0], flex_case=flex_case)
    x = plant.x
    u = tr.tau_c_B[:, :, plant.axis] + (0.0 if tr.tau_ext_B is None else tr.tau_ext_B[:, :, plant.axis])
    states = np.empty(tr.tau_c_B.shape[:2] + (4,))
    for k in range(states.shape[1]):  # FlexibleAxisPlant.advance's arithmetic, without its published state
        states[:, k] = x
        x = np.einsum("pi,pij->pj", x, plant.phi_T) + u[:, k, None] * plant.gamma
    return states[:, :, 0], states[:, :, 2]


def flexible_settling(scn: Scenario, tr, flex_case=None) -> dict[str, np.ndarray]:
    """:func:`~attitude_sil.core.analysis.metrics.flexible_split` of a ``flexible_axis`` run: its rigid and
    flexible settling toward the scenario's setpoint on the plant's axis, in the scenario's settling band.

    ``flex_case``: the run's ``plant.flex.case`` per episode, if it had one (:func:`flexible_states`).
    """
    theta, alpha = flexible_states(scn, tr, flex_case=flex_case)
    target = float(np.radians(scn.param("guidance", "setpoint_rpy_deg")[scn.param("plant", "flex.axis")]))
    return flexible_split(tr.t, theta, alpha, target, scn.param("scenario", "metrics.settling_band"))


def motor_params(values: dict) -> MotorParams:
    """MotorParams from the ``wheels`` node's ``motor.*`` parameters."""
    return MotorParams(
        resistance=values["motor.resistance"],
        inductance=values["motor.inductance"],
        torque_constant=values["motor.torque_constant"],
        back_emf_constant=values["motor.back_emf_constant"],
        rotor_inertia=values["motor.rotor_inertia"],
        viscous_friction=values["motor.viscous_friction"],
        v_max=values["motor.v_max"],
        torque_max=values["motor.torque_max"],
        speed_max=values["motor.speed_max_rpm"] * RPM,
    )


#: per-episode motor constants :func:`build_wheels` takes (``wheels`` parameters)
EPISODE_MOTOR = ("motor.resistance", "motor.inductance", "motor.torque_constant", "motor.back_emf_constant",
                 "motor.torque_max")
#: per-episode wheel failure parameters
EPISODE_FAILURE = ("failure.wheel", "failure.time", "failure.mode", "failure.value")


def available_wheels(w: dict, n: int) -> list[int] | None:
    """The 0-based wheels the allocation shares a command among (``wheels.allocation: available``), or None:
    all, by the pseudo-inverse over every wheel."""
    if w["allocation"] != "available":
        return None
    chosen = list(w["available"]) or list(range(1, n + 1))
    if any(not 1 <= i <= n for i in chosen):
        raise ScenarioError(f"wheels.available {chosen}: the {w['geometry']} geometry has wheels 1..{n}")
    return [i - 1 for i in chosen]


def build_wheels(scn: Scenario, n_episodes: int = 1, per_episode: dict | None = None):
    """The actuator of the scenario's ``wheels`` parameters (``actuator``).

    ``per_episode`` maps :data:`EPISODE_MOTOR` and :data:`EPISODE_FAILURE` names
    to (P,) arrays (reaction wheels only).
    """
    w = scn.values["wheels"]
    per_episode = dict(per_episode or {})
    unknown = sorted(set(per_episode) - set(EPISODE_MOTOR) - set(EPISODE_FAILURE))
    if unknown:
        raise ScenarioError(f"wheels.{unknown[0]} cannot vary per episode (known: "
                            f"{', '.join(EPISODE_MOTOR + EPISODE_FAILURE)})")
    w = {**w, **wheel_failure_values(w)}  # a wheel fault of the faults list, as the failure.* keys say it
    fails = w["failure.wheel"] != 0 or np.any(np.asarray(per_episode.get("failure.wheel", 0)) != 0)
    if w["actuator"] != "reaction_wheels" and (fails or per_episode):
        raise ScenarioError(f"wheels.failure and per-episode motors need actuator reaction_wheels, not {w['actuator']}")
    output_faults = command_faults_of(w)
    if w["actuator"] == "torque":
        return TorqueActuator(w["torque_limit"], n_episodes)
    if w["actuator"] == "none":
        return NoActuator(n_episodes)
    if w["actuator"] == "speed_loop":
        return SpeedLoopWheels(w["speed_loop.motor_gain"], w["speed_loop.motor_a2"], w["speed_loop.motor_a1"],
                               w["speed_loop.kp"], w["speed_loop.ki"], w["speed_loop.kd"], w["speed_loop.n"],
                               w["motor.rotor_inertia"], w["motor.speed_max_rpm"], w["speed_loop.rpm_per_volt"],
                               w["control_period"], n_episodes)
    axes = GEOMETRIES[w["geometry"]]()
    motors = None
    if any(k in per_episode for k in EPISODE_MOTOR):
        cols = {k: np.broadcast_to(np.asarray(per_episode.get(k, w[k]), dtype=float), (n_episodes,))
                for k in EPISODE_MOTOR}
        motors = [motor_params({**w, **{k: float(cols[k][p]) for k in EPISODE_MOTOR}}) for p in range(n_episodes)]
    available = available_wheels(w, axes.shape[1])
    assembly = WheelAssembly(axes, motor_params(w), w["control_period"], motors, available)
    assembly.set_null_space(w["null_space.time_constant_s"], w["null_space.speed_rpm"] * RPM)
    assembly.set_reallocation(w["reallocate_on_fault"], available)
    speed0 = None
    if w["initial_speed_rpm"]:
        if len(w["initial_speed_rpm"]) != assembly.n_wheels:
            raise ScenarioError(
                f"wheels.initial_speed_rpm has {len(w['initial_speed_rpm'])} values for {assembly.n_wheels} wheels"
            )
        speed0 = np.asarray(w["initial_speed_rpm"]) * RPM
    failure = None
    if fails:
        wheel = np.atleast_1d(np.asarray(per_episode.get("failure.wheel", w["failure.wheel"]))).astype(np.int64)
        if np.any(wheel < 0) or np.any(wheel > assembly.n_wheels):
            raise ScenarioError(f"wheels.failure.wheel must be 0 (none) or 1..{assembly.n_wheels} for "
                                f"{w['geometry']}, got {wheel[(wheel < 0) | (wheel > assembly.n_wheels)][0]}")
        t = np.atleast_1d(np.asarray(per_episode.get("failure.time", w["failure.time"]), dtype=float))
        dt_ns = int(round(w["control_period"] * 1e9))
        step = np.array([first_step(float(x), dt_ns) for x in t], dtype=np.int64)  # the first step at or after
        mode = np.atleast_1d(np.asarray(per_episode.get("failure.mode", w["failure.mode"])))
        value = np.atleast_1d(np.asarray(per_episode.get("failure.value", w["failure.value"]), dtype=float))
        code = np.array([WHEEL_FAILURE_MODES.index(str(x)) for x in mode], dtype=np.int64)
        failure = (wheel - 1, step, code, np.where(code == FAIL_SPEED_LIMIT, value * RPM, value))
    fdir = None
    if w["fdir.enabled"]:
        fdir = WheelFdir(assembly, n_episodes, w["fdir.counts_per_rev"], w["fdir.threshold_rad"],
                         w["fdir.persistence"], w["fdir.bandwidth_rad_s"])
    return Wheels(assembly, n_episodes, speed0, failure, output_faults, fdir)


def command_faults_of(w: dict) -> list:
    """The ``controller`` faults (gain, delay) of the ``wheels`` parameters ``w``, checked: they act on the
    reaction wheels' command, and a delay is a whole number of control steps.

    Raises
    ------
    ScenarioError
        One line naming the fault that cannot fly.
    """
    out = [f for f in faults_of(w, "wheels") if f.kind == "controller"]
    dt_ns = int(round(w["control_period"] * 1e9))
    for f in out:
        if w["actuator"] != "reaction_wheels":
            raise ScenarioError(f"fault '{f}': a controller output fault acts on the reaction wheels' command "
                                f"(wheels.actuator reaction_wheels), not {w['actuator']}")
        if f.mode == "delay":
            try:
                delay_steps(f.value, dt_ns)
            except ValueError as exc:
                raise ScenarioError(f"fault '{f}': {exc}") from None
    return out


def build_disturbance(scn: Scenario, n_episodes: int = 1, seeds=None, inertia=None,
                      noise_power=None, residual_dipole=None, epochs=None) -> DisturbanceModel:
    """Disturbance model from the ``disturbance`` parameters; seeds default to seed + p.

    ``noise_power`` (P, 3) N^2 m^2 s sets each episode's ``noise.power``, ``residual_dipole`` (P, 3) A m^2 its
    ``residual_dipole.moment``, ``epochs`` (P,) its field's epoch (:func:`build_environment`).
    """
    d = effective_values(scn, "disturbance")  # the plant's field model
    if noise_power is not None:
        d = {**d, "noise.power": np.broadcast_to(np.asarray(noise_power, dtype=float), (n_episodes, 3))}
    if residual_dipole is not None:
        d = {**d, "residual_dipole.moment": np.broadcast_to(np.asarray(residual_dipole, dtype=float), (n_episodes, 3))}
    m = inertia_matrix(d["inertia"] if inertia is None else inertia)
    if seeds is None:
        seeds = [d["noise.seed"] + p for p in range(n_episodes)]
    ephemeris = Ephemeris(d, scn.dt)  # its readers get the same numbers in any order: one serves both
    field_model = d["environment.magnetic_field.model"]
    field = FieldAlongOrbit(ephemeris, field_model, epochs) \
        if "residual_dipole" in d["models"] and field_model != "none" else None
    return DisturbanceModel(d, np.broadcast_to(m, (n_episodes, 3, 3)), seeds,
                            ephemeris if d["orbit.model"] != "circular" else None, field)


def build_environment(scn: Scenario, epochs=None) -> tuple[Ephemeris, FieldAlongOrbit]:
    """The plant's orbit (what it publishes on ``orbit``) and the geomagnetic field along it; ``epochs`` (P,)
    ISO 8601 texts give each episode's field its own epoch (``plant.orbit.epoch`` per episode)."""
    p = scn.values["plant"]
    orbit = Ephemeris(p, scn.dt)
    return orbit, FieldAlongOrbit(orbit, p["environment.magnetic_field.model"], epochs)


def build_dipole_command(scn: Scenario, params: dict | None = None) -> DipoleCommand:
    """The controller's magnetic channel: the momentum law of ``momentum.*`` (none with ``momentum.mode:
    none``) and B-dot at ``bdot.gain`` (its k* where 0, as the runner fills it in); ``params`` per-episode
    controller values (``momentum.gain`` (P,), ``momentum.target`` (P, 3), ``bdot.gain`` (P,)) override them,
    as they do the laws' (:func:`build_controller`)."""
    c = {**effective_values(scn, "controller"), **(params or {})}
    dumping = None if c["momentum.mode"] == "none" else CrossProductDumping(c["momentum.gain"], c["momentum.target"])
    return DipoleCommand(dumping, BDot(c["bdot.gain"], c["control_period"]),
                         torque_rods=c["torque_actuator"] == "magnetorquers")


def build_magnetorquers(scn: Scenario) -> Magnetorquers:
    """The ``magnetorquers`` node's rods."""
    m = scn.values["magnetorquers"]
    rods = Magnetorquers(rod_axes(m["rods.axes"]), m["rods.max_dipole"])
    for f in faults_of(m, "magnetorquers"):
        rods.faults.add(f, int(round(m["control_period"] * 1e9)))
    return rods


def build_magnetic_loop(scn: Scenario, params: dict | None = None, epochs=None) -> MagneticLoop | None:
    """The magnetorquers' loop of the stepwise driver (:class:`~attitude_sil.core.sim.models.MagneticLoop`),
    or None where the scenario flies no magnetorquers; ``params`` as :func:`build_dipole_command`'s, ``epochs``
    as :func:`build_environment`'s."""
    if not scn.has_magnetorquers:
        return None
    return MagneticLoop(build_environment(scn, epochs)[1], build_dipole_command(scn, params),
                        build_magnetorquers(scn))


def build_scene(values: dict) -> BodyScene:
    """The 3D view's frames and body model of a scenario's values (``node -> name -> value``), LVLH from the
    propagated orbit where the scenario has one (:func:`attitude_sil.core.plant.scene.body_scene`)."""
    return body_scene(values, lambda v: Ephemeris(v, float(v["control_period"])))


def build_guidance(scn: Scenario, n_episodes: int = 1, setpoints_rpy_deg=None) -> Guidance:
    """Guidance of the scenario; ``setpoints_rpy_deg`` (P, 3) overrides the step target per episode."""
    g = scn.values["guidance"]
    final = g["setpoint_rpy_deg"] if setpoints_rpy_deg is None else setpoints_rpy_deg
    return Guidance(g["initial_setpoint_rpy_deg"], final, g["step_time"], n_episodes,
                    mode=g["mode"], lvlh_rpy_deg=g["orbit.lvlh_initial_rpy_deg"],
                    orbit_rate_rad_s=orbit_rate(g["orbit.mu"], g["orbit.radius"]),
                    orbit=Ephemeris(g, scn.dt) if g["orbit.model"] != "circular" else None)


def build_sensing(scn: Scenario, n_episodes: int = 1, seeds=None, gyro_bias_deg_h=None,
                  initial_rpy_deg=None, magnetometer_bias_nt=None) -> Sensing | None:
    """The scenario's sensors and estimator for P episodes (None if it runs without them).

    ``seeds`` (P,) gives each episode its sensor seed (default: ``sensors.seed`` for all), ``gyro_bias_deg_h``
    (P, 3) its gyro's constant bias (default: ``sensors.gyro.bias_deg_h``), ``initial_rpy_deg`` (P, 3) its
    filter's initial attitude (default: the estimator's, else the plant's initial attitude),
    ``magnetometer_bias_nt`` (P, 3) its magnetometer's bias (default: ``sensors.magnetometer.bias_nt``).
    """
    if not scn.has_sensors:
        return None
    values = dict(scn.values["sensors"])
    if gyro_bias_deg_h is not None:
        values["gyro.bias_deg_h"] = np.asarray(gyro_bias_deg_h, dtype=float).reshape(n_episodes, 3)
    if magnetometer_bias_nt is not None:
        values["magnetometer.bias_nt"] = np.asarray(magnetometer_bias_nt, dtype=float).reshape(n_episodes, 3)
    suite = SensorSuite(values, scn.dt, n_episodes, seeds)
    estimator = effective_values(scn, "estimator")
    if initial_rpy_deg is not None:
        estimator["initial_attitude_rpy_deg"] = np.asarray(initial_rpy_deg, dtype=float).reshape(n_episodes, 3)
    mekf = build_filter(estimator, suite.gyro.errors.arw, suite.star_tracker.errors.sigma_B, scn.dt, n_episodes,
                        suite.star_tracker.schedule.latency_steps)
    return Sensing(suite, mekf, scn.feedback)


def law_bank(name: str, n_episodes: int = 1, dt: float = 0.01, values: dict | None = None) -> ControllerBank:
    """A controller bank running law ``name`` with the controller's defaults and ``values`` on top.

    ``values`` keys are the law's short parameter names (``kp``) or any
    controller parameter (``output_limit``, ``orbit.mu``, ``pid.kp``); for a
    law in isolation (tests, notebooks) without a scenario.
    """
    law = registry.get(name)
    v = {s.name: s.default for s in NODE_PARAMS["controller"]}
    short = {s.name for s in law.params}
    v.update({(f"{name}.{k}" if k in short else k): val for k, val in (values or {}).items()})
    v["controller_type"] = name
    return ControllerBank(v, dt, n_episodes)


def build_controller(scn: Scenario, n_episodes: int = 1, params: dict | None = None) -> ControllerBank:
    """The controller bank of the scenario's ``controller`` parameters.

    ``params`` maps controller parameter names (``"pid.kp"``, ``"ga_flc.rules"``,
    ...) to per-episode arrays with a leading P axis.
    """
    c = scn.values["controller"]
    if params:
        check_episode_parameters(params, n_episodes)
    return ControllerBank(c, c["control_period"], n_episodes, per_episode=params)


def check_episode_parameters(params: dict, n_episodes: int) -> None:
    """Refuse per-episode controller values as the controller node refuses a parameter set: the same rule and
    the same words (the parameter, its range or shape, the value), with the episode it came from.

    Parameters
    ----------
    params : dict
        Controller parameter name (``pid.kp``) -> one value for every episode, or a value per episode with a
        leading axis of ``n_episodes``.
    n_episodes : int

    Raises
    ------
    ScenarioError
        An unknown parameter, a value of another shape, or one that breaks the parameter's rule (the first
        episode that does).
    """
    faults = episode_parameter_faults(params, n_episodes)
    if faults:
        p = min(faults)
        raise ScenarioError(faults[p] + (f" (episode {p})" if n_episodes > 1 else ""))


def episode_parameter_faults(params: dict, n_episodes: int) -> dict[int, str]:
    """Each episode whose controller values break a parameter's rule, and the node's words for the first one
    it breaks (a tuner fails those candidates and runs the rest).

    Raises
    ------
    ScenarioError
        An unknown parameter or a value of another shape (not one episode's fault).
    """
    faults: dict[int, str] = {}
    for name, value in params.items():
        try:
            spec = spec_for("controller", name)
        except KeyError:
            raise ScenarioError(f"controller has no parameter {name!r}") from None
        a = np.asarray(value)
        if spec.kind.endswith("_array"):
            rows = [a] if a.ndim == 1 else (list(a) if a.ndim == 2 and a.shape[0] == n_episodes else None)
        else:
            rows = [a] if a.ndim == 0 else (list(a) if a.shape == (n_episodes,) else None)
        if rows is None:
            one = "a list" if spec.kind.endswith("_array") else "one value"
            raise ScenarioError(f"controller.{name}: a value of shape {a.shape} is neither {one} for every "
                                f"episode nor one per episode ({n_episodes}, ...)")
        for p in _suspects(spec, rows):
            try:
                spec.validate(rows[p].tolist(), "controller")
            except ValueError as exc:
                for e in (range(n_episodes) if len(rows) == 1 else (p,)):  # a value for all: every episode's
                    faults.setdefault(e, str(exc))
    return faults


def _suspects(spec, rows: list) -> list[int]:
    """The rows a spec's check must see: all of them where it has a rule of its own, else those outside its range
    (found at once over the episodes: a Monte Carlo's rows are many)."""
    if spec.rule is not None or spec.kind in ("bool", "string", "string_array") or len(rows) == 1:
        return list(range(len(rows)))
    a = np.asarray(rows, dtype=float).reshape(len(rows), -1)
    bad = ~np.isfinite(a).all(axis=1)
    if spec.min is not None:
        bad |= ((a <= spec.min) if spec.min_exclusive else (a < spec.min)).any(axis=1)
    if spec.max is not None:
        bad |= (a > spec.max).any(axis=1)
    if spec.kind.startswith("integer"):
        bad |= (a != np.round(a)).any(axis=1)
    if spec.lengths is not None and spec.kind.endswith("_array") and a.shape[1] not in spec.lengths:
        bad[:] = True
    return [int(p) for p in np.flatnonzero(bad)]


def check_episode(scn: Scenario, controller: str | None = None) -> None:
    """Build every model of ``scn`` once, so what the schema alone cannot see is refused before a graph starts.

    Catches what the nodes would only find at ``plant/reset``: a wheel-speed list
    that does not match the geometry, a noise sample time that does not divide
    the step, and a law (the first, ``controller``, or a scheduled one) whose
    command the actuator does not take.

    Raises
    ------
    ScenarioError
        Naming the scenario file and the rule.
    """
    try:
        build_plant(scn)
        actuator = build_wheels(scn)
        build_disturbance(scn)
        build_guidance(scn)
        build_environment(scn)
        build_controller(scn)
    except ScenarioError as exc:
        raise ScenarioError(f"{scn.source}: {exc}") from None
    c = scn.values["controller"]
    for _, law in [(0, controller or c["controller_type"]), *schedule_from_scenario(scn)]:
        torque = registry.output_of(law) == "torque" or c["command"] == "torque"
        topic = "torque_cmd" if torque else "voltage_cmd"
        if isinstance(actuator, TorqueActuator) and not torque:
            raise ScenarioError(f"{scn.source}: wheels.actuator torque takes torque_cmd, but {law} (controller.command "
                                f"{c['command']}) publishes {topic}; set controller.command: torque")
        if isinstance(actuator, SpeedLoopWheels) and torque:
            raise ScenarioError(f"{scn.source}: wheels.actuator speed_loop takes voltage_cmd, but {law} publishes "
                                f"{topic}; use a voltage law with controller.command: voltage")


def schedule_from_scenario(scn: Scenario) -> list[tuple[int, str]]:
    """The scenario's controller swaps as (step index, controller_type), sorted."""
    s = scn.values["scenario"]
    dt_ns = int(round(scn.dt * 1e9))
    return sorted((int(round(t * 1e9)) // dt_ns + (int(round(t * 1e9)) % dt_ns > 0), kind)
                  for t, kind in zip(s["schedule.times"], s["schedule.controller_types"], strict=True))


#: scenario values :func:`simulate` takes per episode (``episode_values``), by node; every ``controller``
#: parameter may vary per episode too
EPISODE_VALUES = {
    # orbit.epoch: the field's (the Earth turned under the same orbit); the disturbances' field follows it
    "plant": ("inertia", "initial_attitude_rpy_deg", "initial_body_rate", "flex.case", "orbit.epoch"),
    "guidance": ("setpoint_rpy_deg",),
    "disturbance": ("inertia", "noise.seed", "noise.power", "residual_dipole.moment"),
    "wheels": EPISODE_MOTOR + EPISODE_FAILURE,
    "sensors": ("seed", "gyro.bias_deg_h", "magnetometer.bias_nt"),
    "estimator": ("initial_attitude_rpy_deg",),
}


def split_episode_values(episode_values: dict | None) -> dict[str, dict]:
    """``{"node.param": (P, ...)}`` -> ``{node: {param: (P, ...)}}``, refusing what cannot vary per episode."""
    out: dict[str, dict] = {node: {} for node in (*EPISODE_VALUES, "controller")}
    for key, value in (episode_values or {}).items():
        node, _, name = key.partition(".")
        if node != "controller" and name not in EPISODE_VALUES.get(node, ()):
            known = [f"{n}.{v}" for n, vs in EPISODE_VALUES.items() for v in vs] + ["controller.*"]
            raise ScenarioError(f"{key} cannot vary per episode in the batch engine (known: {', '.join(known)})")
        out[node][name] = value
    return out


def episode_laws(controller, n_episodes: int, ctrl: ControllerBank) -> list[str]:
    """Validate a controller_type per episode: P known names of one command kind."""
    laws = [str(c) for c in controller]
    if len(laws) != n_episodes:
        raise ScenarioError(f"controller: {len(laws)} controller types for {n_episodes} episodes")
    unknown = sorted(set(laws) - set(registry.names()))
    if unknown:
        known = ", ".join(registry.names())
        raise ScenarioError(f"controller: unknown controller_type {unknown[0]!r} (known: {known})")
    kinds = {ctrl.kind_of(law) for law in laws}
    if len(kinds) > 1:
        raise ScenarioError(f"controller: the episodes' controller types command both volts and torque "
                            f"({', '.join(sorted(set(laws)))}); one batch takes one command kind")
    return laws
