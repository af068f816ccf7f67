"""The lockstep step objects and the batch engine.

The five graph nodes each hold one of the objects below and call exactly the
methods the batch engine calls, in the same order, so a run through the ROS
graph and :func:`simulate` with P = 1 produce the same numbers (docs/architecture.md,
"Lockstep"). One control step k of the lockstep protocol:

1. ``Plant.state`` at t_k (published as ``attitude``, ``body_rate``);
2. ``Guidance.setpoint(t_k)`` and ``Disturbance.torque(q_BN)``;
3. ``Controller.compute(...)`` -> command held over ``[t_k, t_k+1]``;
4. ``Wheels.advance(command)`` -> momentum at t_k and mean torque;
5. ``Plant.advance(tau_c, h_w, tau_ext)`` -> state at t_k+1.

Every object carries a leading episode axis P.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.analysis.metrics import flexible_split, step_summary, summarize
from attitude_sil.core.control import registry
from attitude_sil.core.control.bank import ControllerBank
from attitude_sil.core.plant.actuators import RPM, SpeedLoopWheels, TorqueActuator
from attitude_sil.core.plant.disturbance import DisturbanceModel, lvlh_attitude, orbit_rate
from attitude_sil.core.plant.kernels import WheelFailure
from attitude_sil.core.plant.linear import LinearizedPlant
from attitude_sil.core.plant.plants import FLEXIBLE_CASES, FlexibleAxisPlant, PitchNormalizedPlant
from attitude_sil.core.plant.quaternion import euler_from_quat, quat_from_euler, quat_multiply
from attitude_sil.core.plant.rigid_body import BodyState, rk4_step
from attitude_sil.core.plant.wheels import GEOMETRIES, MotorParams, WheelAssembly
from attitude_sil.core.sensing.mekf import Mekf, MekfSettings
from attitude_sil.core.sensing.models import SensorSuite
from attitude_sil.core.sim.batch import COMPILED_DISTURBANCES, TRAJECTORY_FIELDS, run_compiled
from attitude_sil.core.sim.params import NODE_PARAMS
from attitude_sil.core.sim.scenario import Scenario, effective_values
from attitude_sil.core.trajectory import EpisodeSummary, Trajectory, WheelStep
from attitude_sil.errors import ScenarioError

__all__ = [
    "Plant",
    "Wheels",
    "Guidance",
    "build_plant",
    "build_wheels",
    "build_disturbance",
    "build_guidance",
    "build_controller",
    "law_bank",
    "Trajectory",
    "simulate",
    "simulate_summary",
    "EpisodeSummary",
    "check_episode",
    "flexible_states",
    "flexible_settling",
    "build_sensing",
    "Sensing",
    "SENSING_FIELDS",
]



def inertia_matrix(values) -> np.ndarray:
    """3 principal values or 9 row-major entries (or (P, 3) / (P, 9)) -> (..., 3, 3) kg m^2.

    Raises ``ValueError`` unless symmetric and positive definite.
    """
    v = np.asarray(values, dtype=float)
    m = v[..., :, None] * np.eye(3) if v.shape[-1] == 3 else v.reshape(v.shape[:-1] + (3, 3))
    mt = np.swapaxes(m, -1, -2)
    if not np.all(np.abs(m - mt) <= 1e-8 + 1e-5 * np.abs(mt)):  # np.allclose's test, without its overhead
        raise ScenarioError("inertia must be symmetric")
    if np.any(np.linalg.eigvalsh(m) <= 0.0):
        raise ScenarioError("inertia must be positive definite")
    return m


def _per_episode(value, n: int, width: int) -> np.ndarray:
    """Broadcast a (width,) or (P, width) value to (P, width)."""
    a = np.asarray(value, dtype=float)
    return np.array(np.broadcast_to(a, (n, width)))


def _inverse(m: np.ndarray) -> np.ndarray:
    """``np.linalg.inv(m)`` for a stack (..., 3, 3), the same bits, inverted once where every matrix is the
    first (the common case: one inertia for all episodes; LAPACK per 3 x 3 costs 6 ms at P = 16,384)."""
    if m.ndim == 3 and m.shape[0] > 1 and np.array_equal(m, np.broadcast_to(m[:1], m.shape)):
        return np.repeat(np.linalg.inv(m[:1]), m.shape[0], axis=0)
    return np.linalg.inv(m)


class Plant:
    """Spacecraft body: RK4 over each held-input interval (paper 000 eq. 4, 10-11)."""

    def __init__(self, inertia: np.ndarray, dt: float, substeps: int,
                 q0: np.ndarray, omega0: np.ndarray) -> None:
        self.inertia = np.asarray(inertia, dtype=float)
        self.inertia_inv = _inverse(self.inertia)
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.q0 = np.asarray(q0, dtype=float)
        self.omega0 = np.asarray(omega0, dtype=float)
        self.reset()

    @property
    def n_episodes(self) -> int:
        return self.q0.shape[0]

    def reset(self) -> None:
        """Return to the initial state (wheel momentum comes from the wheels each step)."""
        self.state = BodyState(self.q0.copy(), self.omega0.copy(), np.zeros_like(self.omega0))

    def advance(self, tau_c_B: np.ndarray, h_wheels_B: np.ndarray, tau_ext_B: np.ndarray) -> BodyState:
        """Integrate from t_k to t_k+1 with the step's inputs.

        Parameters
        ----------
        tau_c_B : (P, 3) N m, mean wheel torque on the body over the step
        h_wheels_B : (P, 3) N m s, wheel momentum at t_k
        tau_ext_B : (P, 3) N m, disturbance torque held over the step
        """
        self.state.h_wheels_B = np.asarray(h_wheels_B, dtype=float)
        self.state = rk4_step(self.state, self.inertia, self.inertia_inv, tau_c_B, tau_ext_B,
                              self.dt, self.substeps)
        return self.state


class Wheels:
    """Reaction-wheel assembly driven by a body-axis voltage command.

    ``failure`` is ``(wheel (P,) int, -1 none; step (P,) int; stuck (P,) bool)``:
    from that step on the wheel is lost (open circuit) or its drive is stuck at
    the voltage of the step before (:func:`attitude_sil.core.plant.kernels.wheel_step`).
    """

    def __init__(self, assembly: WheelAssembly, n_episodes: int, speed0: np.ndarray | None,
                 failure: tuple | None = None) -> None:
        self.assembly = assembly
        self.n_episodes = n_episodes
        self.speed0 = speed0
        if failure is None or not np.any(np.asarray(failure[0]) >= 0):
            self.failure = None
        else:
            wheel, step, stuck = (np.atleast_1d(np.asarray(a)) for a in failure)
            f = n_episodes  # the held voltage is per episode
            self.failure = (np.broadcast_to(wheel, (f,)).astype(np.int64), np.broadcast_to(step, (f,)).astype(np.int64),
                            np.broadcast_to(stuck, (f,)).astype(np.bool_))
        self.reset()

    def reset(self) -> None:
        self.x = self.assembly.initial_state(self.n_episodes, self.speed0)
        self.k = 0
        self.e_hold = None if self.failure is None else np.zeros(len(self.failure[0]))

    @property
    def names(self) -> list[str]:
        return [f"wheel_{i + 1}" for i in range(self.assembly.n_wheels)]

    def failure_arrays(self) -> WheelFailure | None:
        """The kernel's failure record (with the held voltages, state), or None."""
        return None if self.failure is None else WheelFailure(*self.failure, self.e_hold)

    def advance(self, cmd_B: np.ndarray, torque_mode: bool = False) -> WheelStep:
        """Hold a body-axis command (P, 3) over one step; return the step's outputs.

        The command is a voltage (V), or with ``torque_mode`` a body torque (N m)
        that the inverse motor model turns into voltages.
        """
        x = self.x
        self.x, tau_c, h = self.assembly.advance(x, np.ascontiguousarray(cmd_B, dtype=float), torque_mode,
                                                 self.k, self.failure_arrays())
        self.k += 1
        return WheelStep(h, tau_c, x[:, :, 0], x[:, :, 2], self.assembly.motor_torque(x))


class Guidance:
    """Setpoints of the ``guidance`` node.

    * ``step``: ``initial`` attitude until ``step_time``, then ``final``; zero rate.
    * ``lvlh``: the orbit frame, ``q_RN(t) = q_LN(0) ⊗ R_y(Omega_0 t)`` with
      ``omega_RN_R = [0, Omega_0, 0]`` (paper 001: the body tracks LVLH).
    """

    def __init__(self, initial_rpy_deg, final_rpy_deg, step_time: float, n_episodes: int, mode: str = "step",
                 lvlh_rpy_deg=(0.0, 0.0, 0.0), orbit_rate_rad_s: float = 0.0) -> None:
        self.mode = mode
        self.n = n_episodes
        self.q_initial = _per_episode(quat_from_euler(np.radians(initial_rpy_deg)), n_episodes, 4)
        self.q_final = _per_episode(quat_from_euler(np.radians(final_rpy_deg)), n_episodes, 4)
        self.step_time = float(step_time)
        self.q_LN0 = quat_from_euler(np.radians(np.asarray(lvlh_rpy_deg, dtype=float)))
        self.rate = float(orbit_rate_rad_s)
        self.omega = np.zeros((n_episodes, 3))
        if mode == "lvlh":
            self.omega[:, 1] = self.rate

    def setpoint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Reference (q_RN (P, 4), omega_RN_R (P, 3) rad/s) at sim time t."""
        if self.mode == "lvlh":
            return _per_episode(lvlh_attitude(t, self.q_LN0, self.rate), self.n, 4), self.omega
        # compare in integer-safe form: t is k*dt computed from integer ns
        q = self.q_final if t >= self.step_time - 1e-12 else self.q_initial
        return q, self.omega


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
    rpy = _per_episode(p["initial_attitude_rpy_deg"] if rpy0_deg is None else rpy0_deg, n_episodes, 3)
    w0 = _per_episode(p["initial_body_rate"] if omega0 is None else omega0, n_episodes, 3)
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
EPISODE_FAILURE = ("failure.wheel", "failure.time", "failure.mode")


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
    fails = w["failure.wheel"] != 0 or np.any(np.asarray(per_episode.get("failure.wheel", 0)) != 0)
    if w["actuator"] != "reaction_wheels" and (fails or per_episode):
        raise ScenarioError(f"wheels.failure and per-episode motors need actuator reaction_wheels, not {w['actuator']}")
    if w["actuator"] == "torque":
        return TorqueActuator(w["torque_limit"], n_episodes)
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
    assembly = WheelAssembly(axes, motor_params(w), w["control_period"], motors)
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
        t_ns = np.round(t * 1e9).astype(np.int64)
        step = t_ns // dt_ns + (t_ns % dt_ns > 0)  # the first step at or after the time
        mode = np.atleast_1d(np.asarray(per_episode.get("failure.mode", w["failure.mode"])))
        failure = (wheel - 1, step, mode == "stuck")
    return Wheels(assembly, n_episodes, speed0, failure)


def build_disturbance(scn: Scenario, n_episodes: int = 1, seeds=None, inertia=None,
                      noise_power=None) -> DisturbanceModel:
    """Disturbance model from the ``disturbance`` parameters; seeds default to seed + p.

    ``noise_power`` (P, 3) N^2 m^2 s sets each episode's ``noise.power``.
    """
    d = scn.values["disturbance"]
    if noise_power is not None:
        d = {**d, "noise.power": np.broadcast_to(np.asarray(noise_power, dtype=float), (n_episodes, 3))}
    m = inertia_matrix(d["inertia"] if inertia is None else inertia)
    if seeds is None:
        seeds = [d["noise.seed"] + p for p in range(n_episodes)]
    return DisturbanceModel(d, np.broadcast_to(m, (n_episodes, 3, 3)), seeds)


def build_guidance(scn: Scenario, n_episodes: int = 1, setpoints_rpy_deg=None) -> Guidance:
    """Guidance of the scenario; ``setpoints_rpy_deg`` (P, 3) overrides the step target per episode."""
    g = scn.values["guidance"]
    final = g["setpoint_rpy_deg"] if setpoints_rpy_deg is None else setpoints_rpy_deg
    return Guidance(g["initial_setpoint_rpy_deg"], final, g["step_time"], n_episodes,
                    mode=g["mode"], lvlh_rpy_deg=g["orbit.lvlh_initial_rpy_deg"],
                    orbit_rate_rad_s=orbit_rate(g["orbit.mu"], g["orbit.radius"]))


class Sensing:
    """The sensing loop of P episodes: the sensors and the estimator, stepped together (docs/sensors.md).

    ``step(k, q_BN, omega_BN_B)`` samples the sensors on the truth at t_k and
    runs the filter on what they report, as the ``sensors`` and ``estimator``
    nodes do for one episode; it returns the filter's estimate at t_k.
    """

    def __init__(self, suite: SensorSuite, mekf: Mekf, feedback: str) -> None:
        self.suite = suite
        self.mekf = mekf
        self.feedback = feedback

    def step(self, k: int, q_BN: np.ndarray, omega_BN_B: np.ndarray):
        """The estimate at step ``k`` (a :class:`~attitude_sil.core.sensing.mekf.Estimate`) and the gyro reading."""
        sample = self.suite.sample(q_BN, omega_BN_B, k)
        return self.mekf.step(k, sample.omega_meas_B, sample.star_tracker), sample.omega_meas_B


def build_sensing(scn: Scenario, n_episodes: int = 1, seeds=None, gyro_bias_deg_h=None,
                  initial_rpy_deg=None) -> Sensing | None:
    """The scenario's sensors and estimator for P episodes (None if it runs without them).

    ``seeds`` (P,) gives each episode its sensor seed (default: ``sensors.seed`` for all), ``gyro_bias_deg_h``
    (P, 3) its gyro's constant bias (default: ``sensors.gyro.bias_deg_h``), ``initial_rpy_deg`` (P, 3) its
    filter's initial attitude (default: the estimator's, else the plant's initial attitude).
    """
    if not scn.has_sensors:
        return None
    values = dict(scn.values["sensors"])
    if gyro_bias_deg_h is not None:
        values["gyro.bias_deg_h"] = np.asarray(gyro_bias_deg_h, dtype=float).reshape(n_episodes, 3)
    suite = SensorSuite(values, scn.dt, n_episodes, seeds)
    estimator = effective_values(scn, "estimator")
    if initial_rpy_deg is not None:
        estimator["initial_attitude_rpy_deg"] = np.asarray(initial_rpy_deg, dtype=float).reshape(n_episodes, 3)
    settings = MekfSettings.from_values(estimator, suite.gyro.errors.arw, suite.star_tracker.errors.sigma_B)
    mekf = Mekf(settings, scn.dt, n_episodes, suite.star_tracker.schedule.latency_steps)
    return Sensing(suite, mekf, scn.feedback)


#: the arrays a run with the sensing loop adds to its trajectory (:class:`~attitude_sil.core.trajectory.Trajectory`)
SENSING_FIELDS = ("q_BN_est", "omega_BN_B_est", "gyro_bias_est", "attitude_sigma", "omega_BN_B_meas",
                  "gyro_bias_true")


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
    return ControllerBank(c, c["control_period"], n_episodes, per_episode=params)


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


def compiled_plan(plant, wheels, dist: DisturbanceModel, guide: Guidance, ctrl: ControllerBank) -> str:
    """'' if built models fit the compiled driver (:mod:`attitude_sil.core.sim.batch`), else why not."""
    if type(plant) is not Plant:
        return f"plant model {type(plant).__name__}"
    if type(wheels) is not Wheels:
        return f"actuator {type(wheels).__name__}"
    if guide.mode != "step":
        return f"guidance {guide.mode}"
    extra = sorted(set(dist.models) - COMPILED_DISTURBANCES)
    if extra:
        return f"disturbance {', '.join(extra)}"
    return ""


#: ``simulate(driver=...)``: ``auto`` takes the compiled driver where the run fits it
DRIVERS = ("auto", "compiled", "stepwise")


#: what ``simulate(keep=...)`` can keep: the Trajectory's arrays
KEEPABLE = TRAJECTORY_FIELDS + ("omega_RN_R",)


def simulate(
    scn: Scenario,
    n_episodes: int = 1,
    duration: float | None = None,
    controller_params: dict | None = None,
    controller: str | None = None,
    schedule: list[tuple[int, str]] | None = None,
    driver: str = "auto",
    stride: int = 1,
    threads: int | None = None,
    keep=KEEPABLE,
    episode_values: dict | None = None,
) -> Trajectory:
    """Run P episodes of the scenario in lockstep, vectorised over episodes.

    Parameters
    ----------
    scn : Scenario
    n_episodes : int
        P.
    duration : float, optional
        Overrides ``plant.duration``, s.
    controller_params : dict, optional
        Per-episode controller parameters ``{"pid.kp": (P, 3), ...}``.
    controller : str or sequence of P str, optional
        ``controller_type`` to start with (default: the scenario's), or one
        per episode (one command kind; the compiled driver runs them, and
        episode p gives what a batch of its type alone gives).
    schedule : list of (step, controller_type), optional
        Swaps applied before the command of that step (default: the
        scenario's ``schedule.*``).
    driver : str
        ``auto`` (default): whole episodes in compiled code
        (:mod:`attitude_sil.core.sim.batch`) where the run fits it, else the
        stepwise loop; ``compiled`` insists (ScenarioError naming why a run
        does not fit); ``stepwise`` always calls the step objects from Python,
        as the nodes do. Both give the same numbers.
    stride : int
        Keep every ``stride``-th step of the trajectory (k = 0, stride, ...).
    threads : int, optional
        Threads of the compiled driver (default one per core); any count gives
        the same numbers.
    keep : collection of str
        The trajectory arrays to keep (default all of :data:`KEEPABLE`); the
        others are None. The compiled driver does not compute what is not kept
        into memory; the stepwise driver drops it at the end.
    episode_values : dict, optional
        Scenario values per episode, ``{"node.param": (P, ...) array}``: any
        ``controller`` parameter and those of :data:`EPISODE_VALUES` (inertia,
        initial attitude and rate, setpoint, noise seed and power, motor
        constants, wheel failure). Episode p then runs what the graph runs
        with those values set in the scenario (the Monte Carlo's dispersions).
        For example ``{"plant.inertia": (P, 3), "disturbance.inertia": (P, 3)}``
        (principal values, or (P, 9) row-major), ``{"guidance.setpoint_rpy_deg":
        (P, 3)}`` (deg), ``{"disturbance.noise.seed": (P,)}``.

    Returns
    -------
    Trajectory

    See Also
    --------
    simulate_summary : the metrics and checks of each episode in O(P) memory.
    """
    keep = tuple(keep)
    unknown = sorted(set(keep) - set(KEEPABLE))
    if unknown:
        raise ScenarioError(f"keep: unknown trajectory arrays {', '.join(unknown)} (known: {', '.join(KEEPABLE)})")
    if not keep:
        raise ScenarioError("keep: name at least one trajectory array (simulate_summary keeps none)")
    if int(stride) < 1:
        raise ScenarioError(f"stride must be >= 1, got {stride!r}")
    run = _Run(scn, n_episodes, duration, controller_params, controller, schedule, driver, episode_values)
    return run.trajectory(threads, int(stride), keep)


def simulate_summary(
    scn: Scenario,
    n_episodes: int = 1,
    duration: float | None = None,
    controller_params: dict | None = None,
    controller: str | None = None,
    schedule: list[tuple[int, str]] | None = None,
    driver: str = "auto",
    threads: int | None = None,
    episode_values: dict | None = None,
) -> EpisodeSummary:
    """The metrics and checks of P episodes, as :func:`attitude_sil.core.analysis.metrics.summarize` gives them.

    Where the compiled driver runs the scenario and its metrics are a step's
    (``scenario.metrics.mode: step``), the episodes keep running sums only:
    memory O(P), whatever the duration, and no trajectory is written. Other
    runs keep their trajectories until they are summarised. The parameters
    are those of :func:`simulate`.
    """
    run = _Run(scn, n_episodes, duration, controller_params, controller, schedule, driver, episode_values)
    values = scn.values["scenario"]
    if run.compiled and values["metrics.mode"] == "step":
        plant, _, _, guide, _ = run.models
        axis = values["metrics.axis"]
        # metrics_from_trajectory's start and end of the step: the setpoint before it (or the initial
        # attitude if the step is at t = 0) and the setpoint at the last step, by the guidance's own rule
        y0 = euler_from_quat(guide.q_initial if guide.step_time > 1e-12 else plant.q0)[..., axis]
        y0 = np.broadcast_to(y0, (n_episodes,))
        end, _ = guide.setpoint(run.K * int(round(run.dt * 1e9)) * 1e-9)
        r = np.broadcast_to(euler_from_quat(end)[..., axis], (n_episodes,))
        _, sums = run_compiled(run.models, run.K, run.dt, threads=threads, keep=(), swaps=run.swaps, laws=run.laws,
                               sums=(axis, y0, r, values["metrics.settling_band"]))
        return step_summary(sums, values, r - y0)
    return summarize(run.trajectory(threads), values, step_time=scn.param("guidance", "step_time"))


#: scenario values :func:`simulate` takes per episode (``episode_values``), by node; every ``controller``
#: parameter may vary per episode too
EPISODE_VALUES = {
    "plant": ("inertia", "initial_attitude_rpy_deg", "initial_body_rate", "flex.case"),
    "guidance": ("setpoint_rpy_deg",),
    "disturbance": ("inertia", "noise.seed", "noise.power"),
    "wheels": EPISODE_MOTOR + EPISODE_FAILURE,
    "sensors": ("seed", "gyro.bias_deg_h"),
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


def _episode_laws(controller, n_episodes: int, ctrl: ControllerBank) -> list[str]:
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


class _Run:
    """The models of one :func:`simulate` call and the driver that will run them."""

    def __init__(self, scn, P, duration, controller_params, controller, schedule, driver, episode_values) -> None:
        if driver not in DRIVERS:
            raise ScenarioError(f"driver must be one of {', '.join(DRIVERS)}, got {driver!r}")
        self.K = scn.steps(duration)
        self.dt = scn.dt
        ev = split_episode_values(episode_values)
        pv, dv, gv = ev["plant"], ev["disturbance"], ev["guidance"]
        plant = build_plant(scn, P, inertia=pv.get("inertia"), rpy0_deg=pv.get("initial_attitude_rpy_deg"),
                            omega0=pv.get("initial_body_rate"), flex_case=pv.get("flex.case"))
        wheels = build_wheels(scn, P, ev["wheels"])
        dist = build_disturbance(scn, P, seeds=dv.get("noise.seed"), inertia=dv.get("inertia"),
                                 noise_power=dv.get("noise.power"))
        guide = build_guidance(scn, P, gv.get("setpoint_rpy_deg"))
        ctrl = build_controller(scn, P, params={**(controller_params or {}), **ev["controller"]} or None)
        self.laws = None  # per-episode controller types (compiled driver), or None: ctrl.active for all
        if controller is not None and not isinstance(controller, str):
            self.laws = _episode_laws(controller, P, ctrl)
            controller = self.laws[0]
            if len(set(self.laws)) == 1:
                self.laws = None
        if controller is not None:
            ctrl.active = controller
        self.models = (plant, wheels, dist, guide, ctrl)
        self.sensing = build_sensing(scn, P, ev["sensors"].get("seed"), ev["sensors"].get("gyro.bias_deg_h"),
                                     ev["estimator"].get("initial_attitude_rpy_deg"))
        self.swaps = dict(schedule_from_scenario(scn) if schedule is None else schedule)
        self.compiled = False
        if driver != "stepwise":
            why = compiled_plan(*self.models)
            if self.sensing:
                why = "the sensors and estimator run in the stepwise driver"
            if driver == "compiled" and why:
                raise ScenarioError(f"the compiled driver does not run this scenario ({why}); use driver='auto'")
            self.compiled = not why
        if self.laws is not None and not self.compiled:
            why = "driver='stepwise'" if driver == "stepwise" else why
            raise ScenarioError(f"a controller_type per episode runs in the compiled driver only, and this run "
                                f"does not fit it ({why})")

    def trajectory(self, threads: int | None, stride: int = 1, keep=KEEPABLE) -> Trajectory:
        """Run the models in the chosen driver; the arrays not in ``keep`` are None."""
        if self.compiled:
            tr, _ = run_compiled(self.models, self.K, self.dt, stride=stride, threads=threads, keep=keep,
                                 swaps=self.swaps, laws=self.laws)
            return tr
        tr = _simulate_stepwise(*self.models, self.swaps, self.K, self.dt, self.sensing)
        tr = tr if stride == 1 else tr.every(stride)
        for name in set(KEEPABLE) - set(keep):
            setattr(tr, name, None)
        return tr


def _simulate_stepwise(plant, wheels, dist, guide, ctrl, swaps: dict, K: int, dt: float,
                       sensing: Sensing | None = None) -> Trajectory:
    """The stepwise driver: the step objects called from Python, step by step, as the nodes call them.

    With ``sensing`` the sensors sample the truth and the estimator runs on them each step; the controller
    reads the estimate when ``sensing.feedback`` is ``estimate`` (the graph's remap), else the truth.
    """
    P = plant.n_episodes
    nw = len(wheels.names)
    tr = Trajectory(
        t=np.arange(K + 1) * dt,
        q_BN=np.empty((P, K + 1, 4)),
        omega_BN_B=np.empty((P, K + 1, 3)),
        q_RN=np.empty((P, K + 1, 4)),
        h_wheels_B=np.empty((P, K + 1, 3)),
        u_cmd=np.empty((P, K + 1, 3)),
        tau_c_B=np.empty((P, K + 1, 3)),
        tau_ext_B=np.empty((P, K + 1, 3)),
        wheel_speed=np.empty((P, K + 1, nw)),
        kind=[],
        wheel_angle=np.empty((P, K + 1, nw)),
        wheel_effort=np.empty((P, K + 1, nw)),
        omega_RN_R=np.empty((P, K + 1, 3)),
    )
    if sensing is not None:
        for name, width in zip(SENSING_FIELDS, (4, 3, 3, 3, 3, 3), strict=True):
            setattr(tr, name, np.empty((P, K + 1, width)))
    estimate = sensing is not None and sensing.feedback == "estimate"
    dt_ns = int(round(dt * 1e9))
    for k in range(K + 1):
        t = k * dt_ns * 1e-9
        s = plant.state
        q_RN, w_RN = guide.setpoint(t)
        tau_ext = dist.torque(s.q_BN, k * dt_ns)
        if k in swaps:
            ctrl.request(swaps[k])
        q_fb, w_fb = s.q_BN, s.omega_BN_B
        if sensing is not None:
            tr.gyro_bias_true[:, k] = sensing.suite.gyro.drift
            est, w_meas = sensing.step(k, s.q_BN, s.omega_BN_B)
            tr.q_BN_est[:, k] = est.q_BN
            tr.omega_BN_B_est[:, k] = est.omega_BN_B
            tr.gyro_bias_est[:, k] = est.gyro_bias
            tr.attitude_sigma[:, k] = est.attitude_sigma
            tr.omega_BN_B_meas[:, k] = w_meas
            if estimate:
                q_fb, w_fb = est.q_BN, est.omega_BN_B
        u = ctrl.compute(q_fb, w_fb, q_RN, w_RN, k)
        tr.kind.append(ctrl.kind)
        ws = wheels.advance(u, ctrl.kind == "torque")
        tr.q_BN[:, k] = s.q_BN
        tr.omega_BN_B[:, k] = s.omega_BN_B
        tr.q_RN[:, k] = q_RN
        tr.h_wheels_B[:, k] = ws.h_wheels_B
        tr.u_cmd[:, k] = u
        tr.tau_c_B[:, k] = ws.tau_c_B
        tr.tau_ext_B[:, k] = tau_ext
        tr.wheel_speed[:, k] = ws.velocity
        tr.wheel_angle[:, k] = ws.position
        tr.wheel_effort[:, k] = ws.effort
        tr.omega_RN_R[:, k] = w_RN
        if k < K:
            plant.advance(ws.tau_c_B, ws.h_wheels_B, tau_ext)
    return tr
