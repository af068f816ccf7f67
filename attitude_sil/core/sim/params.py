"""Parameter schema of every node: names, types, defaults, units, ranges.

One table serves three users: the nodes declare their ROS parameters from it
(``ParameterDescriptor`` with description and range), the scenario loader
validates YAML files against it, and the batch engine reads its defaults. A
name here is a ROS contract (docs/architecture.md, "Parameters").

Values whose source paper gives no number are marked ``assumed`` in their
description, with the reason.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

from attitude_sil.core.control import registry
from attitude_sil.core.control.momentum import MOMENTUM_PARAMS
from attitude_sil.core.control.shared import AERO, CONTROLLER_SHARED, ORBIT
from attitude_sil.core.environment.earth_time import epoch_from_text
from attitude_sil.core.environment.ephemeris import ORBIT_MODELS
from attitude_sil.core.environment.geomagnetic import FIELD_MODELS
from attitude_sil.core.faults import faults_rule
from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.paramspec import double as _d
from attitude_sil.core.paramspec import double_array as _da
from attitude_sil.core.paramspec import inertia_rule as _inertia_rule
from attitude_sil.core.paramspec import nonzero as _nonzero
from attitude_sil.core.plant.disturbance import DISTURBANCE_MODELS
from attitude_sil.core.plant.magnetorquers import rod_axes
from attitude_sil.core.plant.wheels import HST_MOTOR
from attitude_sil.core.sensing import registry as estimator_registry
from attitude_sil.core.sim.lockstep import COMMAND_TIMINGS
from attitude_sil.errors import ScenarioError

__all__ = ["ParamSpec", "NODE_PARAMS", "GLOBAL_NODE", "SCENARIO_NODE", "spec_for", "HST_MOTOR", "parameters_markdown"]

GLOBAL_NODE = "/**"
SCENARIO_NODE = "scenario"

_HST_INERTIA = [31.046, 77.217, 78.754]

#: how the controller's command is taken (plant and wheels; docs/flight-software.md)
_COMMAND_TIMING = ParamSpec(
    "command_timing", "string", "stamped",
    "stamped: one command per step, stamped t_k; sim_timer: a controller on a sim-time timer (the plant publishes "
    "/clock once the step's setpoints are out; the wheels wait for each tick's command and apply it one period "
    "later); wall: a controller on the wall clock (the wheels apply the newest command, whatever its stamp)",
    choices=COMMAND_TIMINGS)


def _refusal(check: Callable[[Any], object]) -> Callable[[Any], str]:
    """A ParamSpec rule from a check that raises ScenarioError ``where: why``: the why, or '' when it passes."""
    def rule(value: Any) -> str:
        try:
            check(value)
        except ScenarioError as exc:
            return str(exc).partition(": ")[2]
        return ""
    return rule


#: a node's fault list (the wheels', the sensors'): the same list under /**, each node flying its targets'
_FAULTS = ParamSpec("faults", "string_array", [], "faults of the run, one a line: TARGET MODE [VALUE] [at T] "
                    "[for D], e.g. 'wheel1 stuck at 2' (docs/faults.md); set under /**; lines may be added while "
                    "the graph runs (attitude-sil fault)", rule=faults_rule, runtime=True)

#: an ISO 8601 UTC time
_epoch_rule = _refusal(epoch_from_text)


#: the orbit beyond the circular one: its model, epoch and elements (guidance, disturbance and the plant, which
#: publishes it; core/environment/ephemeris.py)
_ORBIT_MODEL = [
    ParamSpec("orbit.model", "string", "circular",
              "circular (orbit.radius; LVLH at t = 0 from orbit.lvlh_initial_rpy_deg) or keplerian_j2 (the "
              "elements below at orbit.epoch, under two-body gravity and J2)", choices=ORBIT_MODELS),
    ParamSpec("orbit.epoch", "string", "2026-01-01T00:00:00Z",
              "UTC time of t = 0, ISO 8601: the Earth's rotation and the geomagnetic field's year", rule=_epoch_rule),
    _d("orbit.semi_major_axis", 6.913e6, "keplerian_j2: semi-major axis, m (default: HST's, about 535 km)",
       min=6.378e6),
    _d("orbit.eccentricity", 0.0, "keplerian_j2: eccentricity", min=0.0, max=0.99),
    _d("orbit.inclination_deg", 28.5, "keplerian_j2: inclination, deg (default: HST's)", min=0.0, max=180.0),
    _d("orbit.raan_deg", 0.0, "keplerian_j2: right ascension of the ascending node, deg", min=-360.0, max=360.0),
    _d("orbit.arg_perigee_deg", 0.0, "keplerian_j2: argument of perigee, deg", min=-360.0, max=360.0),
    _d("orbit.true_anomaly_deg", 0.0, "keplerian_j2: true anomaly at the epoch, deg", min=-360.0, max=360.0),
    ParamSpec("orbit.j2", "bool", True, "keplerian_j2: the Earth's oblateness J2 (false: the two-body orbit)"),
]

#: whole 3-vectors, none zero, spanning the body axes
_rods_rule = _refusal(rod_axes)


#: the geomagnetic field model (the plant's; the disturbances' residual dipole follows it)
_FIELD_MODEL = ParamSpec(
    "environment.magnetic_field.model", "string", "none",
    "the geomagnetic field at the spacecraft, published on magnetic_field: none, dipole (IGRF-14's degree 1 of "
    "the epoch) or igrf (IGRF-14 to degree 13)", choices=tuple(FIELD_MODELS))

#: whether the magnetorquers fly (plant and controller): the runner sets it where the controller commands a
#: dipole (momentum.mode, bdot among the laws it flies, or the rods as its torque_actuator)
_MAGNETORQUERS = ParamSpec(
    "magnetorquers", "bool", False,
    "the magnetorquers fly (set by the runner where momentum.mode is not none, bdot is among the laws or they "
    "are the torque_actuator): the plant takes their magnetic_torque each step, the controller commands dipole_cmd")

_COMMAND_RATE = _d("command_rate", 0.0, "sim_timer: the controller's timer rate, Hz (0: the control rate); its "
                   "period must be a whole number of control periods", min=0.0)


NODE_PARAMS: dict[str, list[ParamSpec]] = {
    GLOBAL_NODE: [],  # filled below: names any node declares may be set for all
    "plant": [
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        _da("inertia", _HST_INERTIA,
            "body inertia, kg m^2: 3 principal values or 9 row-major entries (paper 000: HST)",
            lengths=(3, 9), rule=_inertia_rule),
        _da("initial_attitude_rpy_deg", [0, 0, 0], "initial roll, pitch, yaw of B in N, deg",
            lengths=(3,), min=-360.0, max=360.0),
        _da("initial_body_rate", [0, 0, 0], "initial omega_BN in B, rad/s", lengths=(3,)),
        _da("initial_error_axis", [1, 0, 0], "axis (in B) of an extra initial rotation after the rpy one",
            lengths=(3,), rule=_nonzero),
        _d("initial_error_deg", 0.0, "angle of that extra rotation, deg (paper 001: 1 deg about [-1,1,-1])",
           min=-180.0, max=180.0),
        ParamSpec("model", "string", "rigid_body",
                  "body model: rigid_body (papers 000, 001, 003), linearized (paper 000 eq. 20-28 about the "
                  "initial rate), flexible_axis (paper 002), pitch_normalized (paper 004)",
                  choices=("rigid_body", "linearized", "flexible_axis", "pitch_normalized")),
        ParamSpec("flex.axis", "integer", 0, "body axis of the flexible single-axis model", min=0, max=2),
        ParamSpec("flex.case", "string", "nominal",
                  "paper 002 parameter set: nominal, case1 (w^2 1.7), case2 (k1 0.76), case3 (w^2 1.7, k2 0.114), "
                  "case4 (w^2 1.7, k1 0.114, k2 0.2), or custom (flex.k1, flex.k2, flex.omega_sq)",
                  choices=("nominal", "case1", "case2", "case3", "case4", "custom")),
        _d("flex.b", 0.0064, "rigid-body gain of theta'' = b tau, 1/(kg m^2) (paper 002 eq. 1)", min=0.0,
           min_exclusive=True),
        _d("flex.k1", 0.076, "torque gain of the flexible mode (custom case)"),
        _d("flex.k2", 0.076, "flexible contribution to the total attitude (custom case)"),
        _d("flex.omega_sq", 4.509, "squared natural frequency of the appendage, rad^2/s^2 (custom case)",
           min=0.0, min_exclusive=True),
        _d("flex.alpha0", 0.0, "initial flexible deflection alpha, rad (paper 002: 0)"),
        _d("pitch.epsilon", 0.1, "wheel-to-satellite inertia ratio epsilon (assumed; paper 004 gives none)",
           min=0.0, min_exclusive=True),
        _d("pitch.h0", 0.0, "initial normalised total momentum H"),
        ParamSpec("substeps", "integer", 1, "RK4 steps per control period", min=1, max=1000),
        _d("duration", 20.0, "episode length, s of sim time (0: run until stopped)", min=0.0),
        _d("real_time_factor", 0.0, "pace sim time to wall time: 1.0 real time, 0 as fast as possible",
           min=0.0, max=1000.0, runtime=True),
        _d("input_timeout", 10.0, "wall time the plant waits for a step's inputs before it stops, s",
           min=0.0, min_exclusive=True, runtime=True),
        ParamSpec("autostart", "bool", False,
                  "start the episode once every input and output topic is matched (default: wait for plant/reset)"),
        _d("hold_at", -1.0, "hold the lockstep before publishing the first step at or after this sim time, s "
           "(negative: never); setting it past the current time releases the hold", runtime=True),
        _COMMAND_TIMING,
        _COMMAND_RATE,
        *ORBIT,
        *_ORBIT_MODEL,
        _MAGNETORQUERS,
        _FIELD_MODEL,
    ],
    "wheels": [
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        ParamSpec("geometry", "string", "hst_pyramid", "wheel axes: hst_pyramid (paper 000 eq. 13) or orthogonal",
                  choices=("hst_pyramid", "orthogonal")),
        ParamSpec("allocation", "string", "pseudo_inverse",
                  "how a body-axis command is shared among the wheels: pseudo_inverse (paper 000 eq. 14 over every "
                  "wheel) or available (the pseudo-inverse over the wheels of available alone)",
                  choices=("pseudo_inverse", "available"), runtime=True),
        ParamSpec("available", "integer_array", [], "allocation available: the wheels (1..n of the geometry) the "
                  "command is shared among (empty: all); they must span the three body axes", min=1, runtime=True),
        _d("motor.resistance", HST_MOTOR["motor.resistance"], "armature resistance R_a, ohm (assumed)",
           min=0.0, min_exclusive=True),
        _d("motor.inductance", HST_MOTOR["motor.inductance"], "armature inductance L_a, H (assumed)",
           min=0.0, min_exclusive=True),
        _d("motor.torque_constant", HST_MOTOR["motor.torque_constant"], "torque constant K_i, N m/A (assumed)",
           min=0.0, min_exclusive=True),
        _d("motor.back_emf_constant", HST_MOTOR["motor.back_emf_constant"],
           "back-EMF constant K_b, V s/rad (assumed)", min=0.0, min_exclusive=True),
        _d("motor.rotor_inertia", HST_MOTOR["motor.rotor_inertia"], "wheel rotor inertia J_m, kg m^2",
           min=0.0, min_exclusive=True),
        _d("motor.viscous_friction", HST_MOTOR["motor.viscous_friction"],
           "viscous friction B_m, N m s/rad (assumed)", min=0.0),
        _d("motor.v_max", HST_MOTOR["motor.v_max"], "drive bus voltage limit, V (assumed)",
           min=0.0, min_exclusive=True),
        _d("motor.torque_max", HST_MOTOR["motor.torque_max"], "motor torque limit, N m", min=0.0, min_exclusive=True),
        _d("motor.speed_max_rpm", HST_MOTOR["motor.speed_max_rpm"], "wheel speed limit, rpm",
           min=0.0, min_exclusive=True),
        _da("initial_speed_rpm", [], "initial wheel speeds, rpm (empty: all zero)"),
        _FAULTS,
        _d("null_space.time_constant_s", 0.0, "null-space speed management: the wheel speeds' component along the "
           "null vector of the wheels in use goes to null_space.speed_rpm as a first order of this time constant, "
           "s, making no body torque (0: off; needs one free direction, e.g. a four-wheel pyramid)", min=0.0,
           runtime=True),
        _d("null_space.speed_rpm", 0.0, "target of the wheel speeds' component along the unit null vector (HST's "
           "pyramid: (-1/2, 1/2, -1/2, 1/2)), rpm: biases the wheels away from zero speed", runtime=True),
        ParamSpec("reallocate_on_fault", "bool", False, "ideal isolation: at the step a wheel fault becomes "
                  "active the allocation drops that wheel and shares commands among the others (a perfect, instant "
                  "detector; the bound a real one approaches)"),
        ParamSpec("fdir.enabled", "bool", False, "the drive's FDIR (docs/faults.md): a residual of each wheel's "
                  "tachometer against the nominal motor model, a threshold and a persistence count; with "
                  "reallocate_on_fault the allocation drops the wheel it isolates, from the step it does"),
        ParamSpec("fdir.counts_per_rev", "integer", 4096, "the drive tachometer's counts per revolution, which "
                  "the FDIR reads (its angle is within half a count)", min=1),
        _d("fdir.threshold_rad", 0.01, "FDIR residual threshold on a wheel's angle, rad", min=0.0, min_exclusive=True),
        ParamSpec("fdir.persistence", "integer", 10, "FDIR: control steps in a row over the threshold that "
                  "isolate a wheel", min=1),
        _d("fdir.bandwidth_rad_s", 2.0, "FDIR observer's double pole w, rad/s: a wheel torque off the model's "
           "by J a leaves a residual a / (w^2 + 2 w / tau_m), tau_m the motor's time constant",
           min=0.0, min_exclusive=True),
        ParamSpec("failure.wheel", "integer", 0, "wheel that fails at failure.time: 0 none, 1..n that wheel of "
                  "the geometry (reaction_wheels only)", min=0),
        _d("failure.time", 0.0, "sim time the wheel fails (the first step at or after it), s", min=0.0),
        ParamSpec("failure.mode", "string", "lost", "lost: the drive opens, no current, the wheel coasts on "
                  "its friction; stuck: the drive holds the voltage of the step before the failure; torque_limit: "
                  "the drive makes at most failure.value N m; speed_limit: it drives to failure.value rpm at most; "
                  "friction: the bearing's viscous friction grows failure.value times (a large factor seizes it)",
                  choices=("lost", "stuck", "torque_limit", "speed_limit", "friction")),
        _d("failure.value", 0.0, "the failed wheel's size: N m (torque_limit), rpm (speed_limit) or a friction "
           "factor (friction)", min=0.0),
        ParamSpec("actuator", "string", "reaction_wheels",
                  "reaction_wheels (PMDC motors, paper 000), speed_loop (identified motor with a wheel-speed "
                  "PID, paper 003), torque (ideal torquer saturated at torque_limit: torque rods, paper 001), "
                  "none (no wheels: the magnetorquers make the torque, controller torque_actuator magnetorquers)",
                  choices=("reaction_wheels", "speed_loop", "torque", "none")),
        _d("torque_limit", 1.2e-3, "saturation of the torque actuator per body axis, N m (paper 001: 1.2 mN m)",
           min=0.0, min_exclusive=True),
        _d("speed_loop.motor_gain", 1.0069, "identified motor gain K (paper 003)", min=0.0, min_exclusive=True),
        _d("speed_loop.motor_a2", 3.16955,
           "s^2 coefficient of the motor denominator, s^2 (paper 003; see docs/getting-started.md)", min=0.0,
           min_exclusive=True),
        _d("speed_loop.motor_a1", 5.0289, "s coefficient of the motor denominator, s (paper 003)", min=0.0,
           min_exclusive=True),
        _d("speed_loop.kp", 20.402, "wheel-speed PID proportional gain (paper 003)", min=0.0),
        _d("speed_loop.ki", 4.58, "wheel-speed PID integral gain, 1/s (paper 003)", min=0.0),
        _d("speed_loop.kd", 9.12, "wheel-speed PID derivative gain, s (paper 003)", min=0.0),
        _d("speed_loop.n", 1000.0, "derivative filter of the speed PID, rad/s (assumed)", min=0.0,
           min_exclusive=True),
        _d("speed_loop.rpm_per_volt", 1000.0, "speed reference per volt of the drive's analog input, rpm/V "
           "(assumed)", min=0.0, min_exclusive=True),
        _COMMAND_TIMING,
        _COMMAND_RATE,
    ],
    "disturbance": [
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        _da("inertia", _HST_INERTIA, "body inertia for the gravity gradient, kg m^2 (3 or 9 values)",
            lengths=(3, 9), rule=_inertia_rule),
        ParamSpec("models", "string_array", [], "disturbance models summed (empty: none)",
                  choices=DISTURBANCE_MODELS),
        _da("residual_dipole.moment", [0, 0, 0], "the spacecraft's residual magnetic dipole, A m^2 in B (model "
            "residual_dipole: the torque m_res x B in the plant's field)", lengths=(3,)),
        _da("constant.torque", [0, 0, 0], "constant torque, N m (body axes)", lengths=(3,)),
        _da("step.torque", [0, 0, 0], "step torque from step.time on, N m", lengths=(3,)),
        _d("step.time", 0.0, "time of the torque step, s", min=0.0),
        _d("impulse.magnitude", 1.0, "impulse, N m s (normalised unit on a normalised plant)"),
        ParamSpec("impulse.axis", "integer", 1, "body axis of the impulse: 0, 1, 2", min=0, max=2),
        _d("impulse.time", 0.0, "time of the (first) impulse, s", min=0.0),
        _d("impulse.period", 0.0, "pulse-train period, s (0: a single impulse)", min=0.0),
        ParamSpec("impulse.count", "integer", 0, "pulses in the train (0: no end)", min=0),
        _da("noise.power", [5e-6, 5e-6, 5e-6], "band-limited white noise power per body axis, N^2 m^2 s",
            lengths=(3,), min=0.0),
        _d("noise.sample_time", 0.001, "noise sample time T_s, s", min=0.0, min_exclusive=True),
        ParamSpec("noise.seed", "integer", 0, "noise seed (episode p of a batch uses seed + p)", min=0),
        *ORBIT,
        *_ORBIT_MODEL,
        *AERO,
        _FIELD_MODEL,
    ],
    "guidance": [
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        _da("initial_setpoint_rpy_deg", [0, 0, 0], "reference roll, pitch, yaw before the step, deg",
            lengths=(3,), min=-360.0, max=360.0, runtime=True),
        _da("setpoint_rpy_deg", [0, 0, 0], "reference roll, pitch, yaw from step_time on, deg",
            lengths=(3,), min=-360.0, max=360.0, runtime=True),
        _d("step_time", 0.0, "sim time of the setpoint step, s", min=0.0, runtime=True),
        ParamSpec("mode", "string", "step", "step (setpoints above) or lvlh (track the orbit frame, paper 001)",
                  choices=("step", "lvlh")),
        *ORBIT,
        *_ORBIT_MODEL,
        _COMMAND_TIMING,
        _COMMAND_RATE,
    ],
    "controller": [
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        ParamSpec("controller_type", "string", "pid", "active control law (switches at the next step, bumpless)",
                  choices=registry.names(), runtime=True),
        *CONTROLLER_SHARED,
        # each registered law's own table, as <law>.<name> (attitude_sil.core.control.laws, plugins)
        *registry.parameter_table(),
        *ORBIT,
        *AERO,
        *MOMENTUM_PARAMS,
        _MAGNETORQUERS,
    ],
    "magnetorquers": [
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        _da("rods.axes", [1, 0, 0, 0, 1, 0, 0, 0, 1], "the rods' axes in B, 3 values per rod, row by row "
            "(default: three orthogonal rods, paper 001)", rule=_rods_rule),
        _d("rods.max_dipole", 25.0, "saturation of each rod, A m^2 (default: paper 001, Hawai'iSat-1's 25 A m^2 "
           "rods)", min=0.0, min_exclusive=True),
        _FAULTS,
    ],
    "sensors": [
        # The defaults are a generic navigation-grade gyro and a mid-class star tracker (assumed); the presets
        # config/*_sensors.yaml name the datasheet class they take their numbers from (docs/sensors.md).
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        ParamSpec("seed", "integer", 0, "sensor noise seed: a draw depends only on (seed, error source, step, "
                  "axis), so the graph and the batch engine draw the same numbers", min=0, max=2**40 - 1),
        _d("gyro.arw_deg_rt_h", 0.01, "gyro angle random walk N, deg/sqrt(h) (white rate noise; 0: none)",
           min=0.0),
        _d("gyro.bias_instability_deg_h", 0.05, "gyro bias instability B: steady-state 1-sigma of the "
           "Gauss-Markov bias, deg/h (0: none)", min=0.0),
        _d("gyro.bias_correlation_time_s", 300.0, "correlation time of the Gauss-Markov bias, s", min=0.0,
           min_exclusive=True),
        _d("gyro.rrw_deg_h_rt_h", 0.0, "gyro rate random walk K, deg/h/sqrt(h) (0: none)", min=0.0),
        _da("gyro.bias_deg_h", [0.0, 0.0, 0.0], "gyro constant bias per body axis, deg/h", lengths=(3,)),
        _da("gyro.scale_factor_ppm", [0.0, 0.0, 0.0], "gyro scale-factor error per axis, ppm", lengths=(3,)),
        _da("gyro.misalignment_urad", [0.0, 0.0, 0.0], "small rotation of the gyro axes from the body axes, "
            "urad", lengths=(3,)),
        _d("gyro.resolution_deg_s", 0.0, "gyro quantisation step, deg/s (0: none)", min=0.0),
        _d("gyro.range_deg_s", 400.0, "gyro saturation, deg/s", min=0.0, min_exclusive=True),
        _d("star_tracker.rate_hz", 4.0, "star tracker exposures per second (1 / rate a whole number of control "
           "steps)", min=0.0, min_exclusive=True),
        _d("star_tracker.latency_s", 0.0, "star tracker delay from exposure to report, s (a whole number of "
           "control steps); the report is stamped with the exposure time", min=0.0, max=10.0),
        _d("star_tracker.cross_boresight_arcsec", 5.0, "star tracker 1-sigma noise about each axis across the "
           "boresight, arcsec", min=0.0),
        _d("star_tracker.about_boresight_arcsec", 40.0, "star tracker 1-sigma noise about the boresight, arcsec",
           min=0.0),
        ParamSpec("star_tracker.boresight_axis", "integer", 2, "body axis of the star tracker boresight: 0, 1, 2",
                  min=0, max=2),
        _da("star_tracker.outages_s", [], "scheduled outages: (start, end) pairs of exposure times, s; an "
            "exposure inside one reports no attitude (a fault 'star_tracker off at T for D' is one too)", min=0.0),
        _FAULTS,
        _d("magnetometer.noise_nt", 50.0, "magnetometer 1-sigma white noise per axis, nT (assumed: a CubeSat-class "
           "magnetoresistive sensor)", min=0.0),
        _da("magnetometer.bias_nt", [0.0, 0.0, 0.0], "magnetometer constant bias per axis, nT", lengths=(3,)),
        _da("magnetometer.scale_factor_ppm", [0.0, 0.0, 0.0], "magnetometer scale-factor error per axis, ppm",
            lengths=(3,)),
        _da("magnetometer.misalignment_urad", [0.0, 0.0, 0.0], "small rotation of the magnetometer axes from the "
            "body axes, urad", lengths=(3,)),
        _d("magnetometer.resolution_nt", 0.0, "magnetometer quantisation step, nT (0: none)", min=0.0),
        _d("magnetometer.range_nt", 100000.0, "magnetometer saturation per axis, nT", min=0.0, min_exclusive=True),
        ParamSpec("wheel_speed.counts_per_rev", "integer", 24, "wheel tachometer Hall-sensor edges per "
                  "revolution (quantises wheel_speed)", min=1),
    ],
    "estimator": [
        _d("control_period", 0.01, "control step dt, s (shared by every node)", min=0.0, min_exclusive=True, max=1.0),
        ParamSpec("type", "string", "mekf", "the attitude filter: " + "; ".join(
            f"{n}: {estimator_registry.get(n).description}" for n in estimator_registry.builtin_names())
            + " (or a plugin's, entry-point group attitude_sil.estimators, docs/sensors.md)",
            rule=estimator_registry.unknown),
        *estimator_registry.parameter_table(),
        _d("bias_walk_deg_h_rt_h", 0.01, "the filter's gyro bias random walk sigma_u, deg/h/sqrt(h) (covers "
           "bias instability: about B sqrt(2 / tau))", min=0.0),
        _da("initial_attitude_rpy_deg", [0, 0, 0], "initial attitude estimate, roll/pitch/yaw deg (the runner "
            "copies the plant's initial attitude unless set)", lengths=(3,), min=-360.0, max=360.0),
        _d("initial_attitude_sigma_deg", 1.0, "1-sigma of the initial attitude error per axis, deg", min=0.0,
           min_exclusive=True),
        _d("initial_bias_sigma_deg_h", 1.0, "1-sigma of the initial gyro bias error per axis, deg/h", min=0.0,
           min_exclusive=True),
        _d("star_tracker.rate_hz", 4.0, "the star tracker's report rate the filter waits for, per s (the runner "
           "copies the sensors' unless set)", min=0.0, min_exclusive=True),
        _d("star_tracker.latency_s", 0.0, "the star tracker's latency the filter expects, s (the runner copies "
           "the sensors' unless set)", min=0.0, max=10.0),
        _d("star_tracker.max_age_s", 0.0, "the oldest star tracker report the filter takes, s from its exposure "
           "(0 or less than star_tracker.latency_s: that latency); an older one is dropped", min=0.0, max=60.0),
    ],
    SCENARIO_NODE: [
        ParamSpec("name", "string", "", "scenario name (read by the runner, not a node)"),
        ParamSpec("description", "string", "", "one-line description"),
        ParamSpec("metrics.axis", "integer", 0, "body axis of the step metrics: 0 roll, 1 pitch, 2 yaw",
                  min=0, max=2),
        _d("metrics.settling_band", 0.02, "settling band, fraction of the step", min=0.0, min_exclusive=True,
           max=1.0),
        _d("metrics.tau_d", 1.5, "desired time constant tau_d of the cost J (paper 000 eq. 19), s", min=0.0),
        _d("metrics.w_os", 1.0, "overshoot weight w_os of the cost J (paper 000 eq. 19), per %", min=0.0),
        ParamSpec("metrics.mode", "string", "step",
                  "step (a setpoint step on metrics.axis), tracking (principal error angle vs the reference, "
                  "paper 001) or regulation (single-axis return to zero, MSE of paper 002)",
                  choices=("step", "tracking", "regulation")),
        _d("metrics.settling_angle_deg", -1.0,
           "tracking: settled once the principal error angle stays below this, deg (negative: the angle of "
           "R1(0.1 deg) R2(0.1 deg) R3(0.1 deg), paper 001)"),
        _d("metrics.detumble_rate_deg_s", 0.0, "detumble_time_s is the time from which |omega_BN| stays below "
           "this rate, deg/s (0: not reported)", min=0.0),
        _d("metrics.beta", 1.0, "weight beta of paper 001's fitness f = -(Ts + beta Ce)", min=0.0),
        ParamSpec("feedback", "string", "truth", "what the controller reads: truth (the plant's attitude and "
                  "rate) or estimate (the estimator's, fed by the sensors node)", choices=("truth", "estimate")),
        ParamSpec("sensors", "bool", False, "run the sensors and estimator in the loop (on by itself with "
                  "feedback: estimate or a sensors / estimator section)"),
        _d("metrics.pointing_after_s", -1.0, "APE and AKE are taken from this sim time on, s (negative: from "
           "the settling time of a step, else from 0)"),
        _da("schedule.times", [], "sim times of scheduled controller swaps, s (runner applies them as "
            "parameter sets)", min=0.0),
        ParamSpec("schedule.controller_types", "string_array", [], "controller_type to swap to at each time",
                  choices=registry.names()),
    ],
}

# A name under "/**" applies to every node that declares it.
NODE_PARAMS[GLOBAL_NODE] = list(
    {s.name: s for node, specs in NODE_PARAMS.items() if node != SCENARIO_NODE for s in specs}.values()
)


def spec_for(node: str, name: str) -> ParamSpec:
    """The spec of ``node``'s parameter ``name``; ``KeyError`` if it has none."""
    for spec in NODE_PARAMS[node]:
        if spec.name == name:
            return spec
    raise KeyError(f"{node} has no parameter {name!r}")


def _range_text(spec: ParamSpec) -> str:
    parts = []
    if spec.choices:
        parts.append(", ".join(f"`{c}`" for c in spec.choices))
    if spec.min is not None:
        parts.append(f"{'>' if spec.min_exclusive else '>='} {spec.min:g}")
    if spec.max is not None:
        parts.append(f"<= {spec.max:g}")
    if spec.lengths:
        parts.append("length " + " or ".join(map(str, spec.lengths)))
    return "; ".join(parts)


def _default_text(value: Any) -> str:
    if isinstance(value, list) and len(value) > 6:
        return f"{len(value)} values"
    return f"`{value}`"


def parameters_markdown() -> str:
    """Every node's parameters as Markdown tables: the source of docs/parameters.md.

    The test suite regenerates this and compares it with the file, so the
    document cannot drift from the schema.
    """
    lines = ["<!-- generated from attitude_sil/core/sim/params.py by parameters_markdown(); "
             "test/unit/test_docs.py keeps it equal -->", ""]
    plugins = tuple(f"{n}." for n in set(registry.names()) - set(registry.builtin_names())) + tuple(
        f"{n}." for n in set(estimator_registry.names()) - set(estimator_registry.builtin_names()))
    for node, specs in NODE_PARAMS.items():
        if node == GLOBAL_NODE:
            continue
        title = "scenario (read by the runner and the metrics, not a node)" if node == SCENARIO_NODE else node
        lines += [f"## `{node}`" if node != SCENARIO_NODE else f"## `{node}`: {title}", "",
                  "| name | type | default | range / choices | set at runtime | meaning |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for spec in specs:
            if spec.name.startswith(plugins):  # an installed plugin documents its own law
                continue
            desc = spec.description.replace("|", "\\|")
            if spec.name in ("controller_type", "schedule.controller_types"):
                desc += " (and any law a plugin registers, docs/writing-a-law.md)"
                spec = replace(spec, choices=tuple(c for c in spec.choices if c in registry.builtin_names()))
            lines.append(f"| `{spec.name}` | {spec.kind} | {_default_text(spec.default)} | {_range_text(spec)} | "
                         f"{'yes' if spec.runtime else 'no'} | {desc} |")
        lines.append("")
    return "\n".join(lines)
