"""The controller's parameters that every law's ``record`` may read besides its own table.

A law's record is built from the controller node's values: the law's own
parameters (``pid.kp``, read as ``kp``) and these shared ones (the command
kind and its limit, the error mode, the bumpless transfer, the orbit and the
aerodynamics the geometric law's feed-forward uses). They are declared here,
below the registry, so the registry can build a plugin's record with every
default when it checks the plugin (:mod:`attitude_sil.core.control.registry`);
the controller node's table (:mod:`attitude_sil.core.sim.params`) is these,
the laws' tables, and the run's own.
"""

from __future__ import annotations

from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.paramspec import double as _d
from attitude_sil.core.paramspec import double_array as _da
from attitude_sil.core.plant.wheels import HST_MOTOR

__all__ = ["CONTROLLER_SHARED", "ORBIT", "AERO", "shared_defaults"]

#: the controller's own parameters a law may read (the command, its limit, the transfer, the error mode)
CONTROLLER_SHARED = [
    ParamSpec("error_mode", "string", "quaternion",
              "what the PID-family laws act on: quaternion (vector part, paper 000) or angle (2 asin of it, "
              "the rotation angle per axis, for single-axis papers 002 and 004)", choices=("quaternion", "angle")),
    ParamSpec("command", "string", "voltage",
              "topic of the PID-family laws: voltage (voltage_cmd, wheel presets) or torque (torque_cmd, "
              "torque presets); geometric always commands torque", choices=("voltage", "torque")),
    _d("bumpless_time_constant", 1.0,
       "decay time of the transfer offset when switching to a law without a bumpless entry (ga_flc, geometric), s",
       min=0.0, runtime=True),
    _d("output_limit", HST_MOTOR["motor.v_max"], "command saturation of the voltage laws, V",
       min=0.0, min_exclusive=True, runtime=True),
    _d("sensor_noise.attitude_std_deg", 0.0, "attitude sensor noise: standard deviation of a small "
       "rotation per body axis on the attitude the law sees, deg (0: none)", min=0.0),
    _d("sensor_noise.rate_std_deg_s", 0.0, "rate sensor noise: standard deviation per body axis on the "
       "body rate the law sees, deg/s (0: none)", min=0.0),
    ParamSpec("sensor_noise.seed", "integer", 0, "sensor noise seed (a draw depends only on the seed, the "
              "step and the channel)", min=0),
]

#: the circular orbit (the guidance, the disturbances and the geometric law read it)
ORBIT = [
    _d("orbit.mu", 3.986004418e14, "Earth gravitational parameter, m^3/s^2", min=0.0, min_exclusive=True),
    _d("orbit.radius", 6.913e6, "circular orbit radius, m (default: HST, about 535 km altitude, assumed)",
       min=6.378e6),
    _da("orbit.lvlh_initial_rpy_deg", [0, 0, 0], "LVLH frame at t = 0 relative to N, roll/pitch/yaw deg",
        lengths=(3,), min=-360.0, max=360.0),
]
#: the aerodynamic torque model (the disturbances and the geometric law read it)
AERO = [
    _d("aero.density", 1.0e-13, "atmospheric density, kg/m^3 (assumed: 600 km, moderate solar activity)",
       min=0.0),
    _d("aero.drag_coefficient", 2.2, "drag coefficient C_d (assumed: 2.2, free-molecular flow)", min=0.0),
    _d("aero.area", 0.508, "area normal to the velocity, m^2 (assumed: Hawai'iSat side, 0.66 m x 0.77 m)",
       min=0.0),
    _da("aero.cp_offset", [0.0, 0.0, 0.05], "centre of pressure from the centre of mass in B, m (assumed)",
        lengths=(3,)),
]


def shared_defaults() -> dict:
    """Every shared parameter's default by name (what a law's ``record`` reads besides its own table)."""
    return {s.name: s.default for s in (*CONTROLLER_SHARED, *ORBIT, *AERO)}
