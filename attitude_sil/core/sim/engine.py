"""The drivers: P episodes of a scenario run to the end, in compiled code or step by step from Python.

:func:`simulate` keeps the trajectory, :func:`simulate_summary` only each
episode's metrics; both take their run's settings as one
:class:`RunOptions`. A run goes to the compiled batch engine
(:mod:`attitude_sil.core.sim.batch`) where its models fit it
(:func:`compiled_plan`), else to the stepwise driver, which calls the step
objects of :mod:`attitude_sil.core.sim.models` from Python in the graph's
lockstep order; both give the same numbers. The models are built by
:mod:`attitude_sil.core.sim.build`.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from attitude_sil.core.analysis.metrics import step_summary, summarize
from attitude_sil.core.control.bank import ControllerBank
from attitude_sil.core.control.momentum import BDOT
from attitude_sil.core.plant.disturbance import DisturbanceModel
from attitude_sil.core.plant.quaternion import euler_from_quat
from attitude_sil.core.sim.batch import COMPILED_DISTURBANCES, TRAJECTORY_FIELDS, run_compiled
from attitude_sil.core.sim.build import (
    build_controller,
    build_disturbance,
    build_environment,
    build_guidance,
    build_magnetic_loop,
    build_plant,
    build_sensing,
    build_wheels,
    episode_laws,
    schedule_from_scenario,
    split_episode_values,
)
from attitude_sil.core.sim.models import SENSING_FIELDS, Guidance, MagneticLoop, Plant, Sensing, Wheels
from attitude_sil.core.sim.scenario import Scenario
from attitude_sil.core.trajectory import EpisodeSummary, Trajectory, all_finite
from attitude_sil.errors import NonFiniteWarning, ScenarioError

__all__ = ["RunOptions", "simulate", "simulate_summary", "compiled_plan", "DRIVERS", "KEEPABLE"]


def compiled_plan(plant, wheels, dist: DisturbanceModel, guide: Guidance, ctrl: ControllerBank) -> str:
    """'' if built models fit the compiled driver (:mod:`attitude_sil.core.sim.batch`), else why not."""
    if type(plant) is not Plant:
        return f"plant model {type(plant).__name__}"
    if type(wheels) is not Wheels:
        return f"actuator {type(wheels).__name__}"
    if wheels.fdir is not None:
        return "the wheels' FDIR runs in the stepwise driver"
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


@dataclass(frozen=True)
class RunOptions:
    """What a run varies besides its scenario and episode count: the settings :func:`simulate` and
    :func:`simulate_summary` share.

    Attributes
    ----------
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
    threads : int, optional
        Threads of the compiled driver (default one per core); any count gives
        the same numbers.
    warn_nonfinite : bool
        Warn (:class:`~attitude_sil.errors.NonFiniteWarning`) when episodes go
        non-finite, naming them and their laws (default); a caller that
        reports them itself (the tuner's failures, a campaign's table) sets
        it False.
    episode_values : dict, optional
        Scenario values per episode, ``{"node.param": (P, ...) array}``: any
        ``controller`` parameter and those of
        :data:`~attitude_sil.core.sim.build.EPISODE_VALUES` (inertia,
        initial attitude and rate, setpoint, noise seed and power, motor
        constants, wheel failure). Episode p then runs what the graph runs
        with those values set in the scenario (the Monte Carlo's dispersions).
        For example ``{"plant.inertia": (P, 3), "disturbance.inertia": (P, 3)}``
        (principal values, or (P, 9) row-major), ``{"guidance.setpoint_rpy_deg":
        (P, 3)}`` (deg), ``{"disturbance.noise.seed": (P,)}``.
    """

    duration: float | None = None
    controller_params: dict | None = None
    controller: str | Sequence[str] | None = None
    schedule: list[tuple[int, str]] | None = None
    driver: str = "auto"
    threads: int | None = None
    episode_values: dict | None = None
    warn_nonfinite: bool = True

    def updated(self, changes: dict[str, Any]) -> RunOptions:
        """These options with ``changes`` (field names) set; an unknown name is a TypeError, as for a call."""
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise TypeError(f"unexpected run option {unknown[0]!r} (RunOptions: "
                            f"{', '.join(f.name for f in dataclasses.fields(self))})")
        return dataclasses.replace(self, **changes) if changes else self


def simulate(scn: Scenario, n_episodes: int = 1, options: RunOptions | None = None, *, stride: int = 1,
             keep=KEEPABLE, **changes: Any) -> Trajectory:
    """Run P episodes of the scenario in lockstep, vectorised over episodes.

    Parameters
    ----------
    scn : Scenario
    n_episodes : int
        P.
    options : RunOptions, optional
        The run's settings (duration, controller, schedule, driver, threads,
        per-episode values); default all defaults.
    stride : int
        Keep every ``stride``-th step of the trajectory (k = 0, stride, ...).
    keep : collection of str
        The trajectory arrays to keep (default all of :data:`KEEPABLE`); the
        others are None. The compiled driver does not compute what is not kept
        into memory; the stepwise driver drops it at the end.
    **changes
        Fields of :class:`RunOptions` set on top of ``options``
        (``simulate(scn, 4, duration=2.0, driver="stepwise")``).

    Returns
    -------
    Trajectory

    See Also
    --------
    simulate_summary : the metrics and checks of each episode in O(P) memory.
    """
    opts = (options or RunOptions()).updated(changes)
    keep = tuple(keep)
    unknown = sorted(set(keep) - set(KEEPABLE))
    if unknown:
        raise ScenarioError(f"keep: unknown trajectory arrays {', '.join(unknown)} (known: {', '.join(KEEPABLE)})")
    if not keep:
        raise ScenarioError("keep: name at least one trajectory array (simulate_summary keeps none)")
    if int(stride) < 1:
        raise ScenarioError(f"stride must be >= 1, got {stride!r}")
    run = _Run(scn, n_episodes, opts)
    tr = run.trajectory(opts.threads, int(stride), keep)
    finite = all_finite(tr.q_BN, tr.omega_BN_B, tr.u_cmd)
    if finite is not None and opts.warn_nonfinite:
        run.warn_nonfinite(finite)
    return tr


def simulate_summary(scn: Scenario, n_episodes: int = 1, options: RunOptions | None = None,
                     **changes: Any) -> EpisodeSummary:
    """The metrics and checks of P episodes, as :func:`attitude_sil.core.analysis.metrics.summarize` gives them.

    Where the compiled driver runs the scenario and its metrics are a step's
    (``scenario.metrics.mode: step``), the episodes keep running sums only:
    memory O(P), whatever the duration, and no trajectory is written. Other
    runs keep their trajectories until they are summarised. ``options`` and
    ``changes`` are those of :func:`simulate`.
    """
    opts = (options or RunOptions()).updated(changes)
    run = _Run(scn, n_episodes, opts)
    values = scn.values["scenario"]
    # (the magnetorquers' figures come from the trajectory)
    if run.compiled and values["metrics.mode"] == "step" and run.magnetic is None:
        plant, _, _, guide, _ = run.models
        axis = values["metrics.axis"]
        # metrics_from_trajectory's start and end of the step: the setpoint before it (or the initial
        # attitude if the step is at t = 0) and the setpoint at the last step, by the guidance's own rule
        y0 = euler_from_quat(guide.q_initial if guide.step_time > 1e-12 else plant.q0)[..., axis]
        y0 = np.broadcast_to(y0, (n_episodes,))
        end, _ = guide.setpoint(run.K * int(round(run.dt * 1e9)) * 1e-9)
        r = np.broadcast_to(euler_from_quat(end)[..., axis], (n_episodes,))
        _, sums = run_compiled(run.models, run.K, run.dt, threads=opts.threads, keep=(), swaps=run.swaps,
                               laws=run.laws, sums=(axis, y0, r, values["metrics.settling_band"]))
        summary = step_summary(sums, values, r - y0)
    else:
        summary = summarize(run.trajectory(opts.threads), values, step_time=scn.param("guidance", "step_time"))
    if opts.warn_nonfinite:
        run.warn_nonfinite(summary.finite)
    return summary


class _Run:
    """The models of one :func:`simulate` call and the driver that will run them."""

    def __init__(self, scn: Scenario, P: int, opts: RunOptions) -> None:
        driver, controller = opts.driver, opts.controller
        if driver not in DRIVERS:
            raise ScenarioError(f"driver must be one of {', '.join(DRIVERS)}, got {driver!r}")
        if isinstance(controller, str):  # the law flown first is the scenario's: what it starts follows (bdot)
            scn = scn.with_values("controller", controller_type=controller)
        self.K = scn.steps(opts.duration)
        self.dt = scn.dt
        ev = split_episode_values(opts.episode_values)
        pv, dv, gv = ev["plant"], ev["disturbance"], ev["guidance"]
        plant = build_plant(scn, P, inertia=pv.get("inertia"), rpy0_deg=pv.get("initial_attitude_rpy_deg"),
                            omega0=pv.get("initial_body_rate"), flex_case=pv.get("flex.case"))
        wheels = build_wheels(scn, P, ev["wheels"])
        epochs = pv.get("orbit.epoch")  # the field's, per episode (the orbit is the same)
        dist = build_disturbance(scn, P, seeds=dv.get("noise.seed"), inertia=dv.get("inertia"),
                                 noise_power=dv.get("noise.power"), residual_dipole=dv.get("residual_dipole.moment"),
                                 epochs=epochs)
        guide = build_guidance(scn, P, gv.get("setpoint_rpy_deg"))
        ctrl_params = {**(opts.controller_params or {}), **ev["controller"]} or None  # the law's and the dipole's
        ctrl = build_controller(scn, P, params=ctrl_params)
        self.laws = None  # per-episode controller types (compiled driver), or None: ctrl.active for all
        if controller is not None and not isinstance(controller, str):
            self.laws = episode_laws(controller, P, ctrl)
            if BDOT in self.laws:
                raise ScenarioError("bdot cannot be one of a per-episode list of laws: it flies the magnetorquers, "
                                    "which run in the stepwise driver (give it as the one controller_type)")
            controller = self.laws[0]
            if len(set(self.laws)) == 1:
                self.laws = None
        if controller is not None:
            ctrl.active = controller
        self.models = (plant, wheels, dist, guide, ctrl)
        field = build_environment(scn, epochs)[1]
        self.field = field if field.model != "none" else None  # the field at the spacecraft, for the record
        self.sensing = build_sensing(scn, P, ev["sensors"].get("seed"), ev["sensors"].get("gyro.bias_deg_h"),
                                     ev["estimator"].get("initial_attitude_rpy_deg"),
                                     ev["sensors"].get("magnetometer.bias_nt"))
        self.magnetic = build_magnetic_loop(scn, ctrl_params, epochs)
        self.swaps = dict(schedule_from_scenario(scn) if opts.schedule is None else opts.schedule)
        if BDOT in self.swaps.values() and self.magnetic is None:
            raise ScenarioError("a swap to bdot needs the magnetorquers flying from the start: list it in the "
                                "scenario's schedule.controller_types, or set controller momentum.mode")
        self.compiled = False
        if driver != "stepwise":
            why = compiled_plan(*self.models)
            if self.sensing:
                why = "the sensors and estimator run in the stepwise driver"
            if self.magnetic and self.magnetic.field.epochs is not None:
                why = "a field epoch per episode runs in the stepwise driver"
            if self.magnetic and self.magnetic.rods.faults:
                why = "a magnetorquers fault runs in the stepwise driver"
            if driver == "compiled" and why:
                raise ScenarioError(f"the compiled driver does not run this scenario ({why}); use driver='auto'")
            self.compiled = not why
        if self.laws is not None and not self.compiled:
            why = "driver='stepwise'" if driver == "stepwise" else why
            raise ScenarioError(f"a controller_type per episode runs in the compiled driver only, and this run "
                                f"does not fit it ({why})")

    def laws_of(self, p: int) -> str:
        """The law(s) episode ``p`` ran: its first, then each swap (``pid, fuzzy_pid from step 500``)."""
        first = self.laws[p] if self.laws is not None else self.models[4].active
        return ", ".join([first, *(f"{law} from step {k}" for k, law in sorted(self.swaps.items()))])

    def warn_nonfinite(self, finite: np.ndarray) -> None:
        """A :class:`~attitude_sil.errors.NonFiniteWarning` naming the episodes that went non-finite and their
        laws (nothing when every episode stayed finite)."""
        bad = np.flatnonzero(~np.asarray(finite, dtype=bool))
        if bad.size == 0:
            return
        by_laws: dict[str, list[int]] = {}
        for p in bad:
            by_laws.setdefault(self.laws_of(int(p)), []).append(int(p))
        parts = [f"episodes {_first(ps)} under {laws}" for laws, ps in by_laws.items()]
        warnings.warn(f"{bad.size} of {len(finite)} episodes went non-finite (a law commanded NaN or inf, or the "
                      f"state diverged): {'; '.join(parts)}", NonFiniteWarning, stacklevel=3)

    def trajectory(self, threads: int | None, stride: int = 1, keep=KEEPABLE) -> Trajectory:
        """Run the models in the chosen driver; the arrays not in ``keep`` are None."""
        if self.compiled:
            tr, _ = run_compiled(self.models, self.K, self.dt, stride=stride, threads=threads, keep=keep,
                                 swaps=self.swaps, laws=self.laws, magnetic=self.magnetic)
        else:
            tr = _simulate_stepwise(*self.models, self.swaps, self.K, self.dt, self.sensing, self.magnetic)
            tr = tr if stride == 1 else tr.every(stride)
            for name in set(KEEPABLE) - set(keep):
                setattr(tr, name, None)
        if self.field is not None and tr.q_BN is not None and self.magnetic is None:  # the record's, afterwards
            t_ns = np.rint(tr.t * 1e9).astype(np.int64)
            tr.magnetic_field_B = self.field.field_B(t_ns, tr.q_BN)
            if self.sensing is not None:  # and the magnetometer's reading of it, a step's draws by its number
                mag = self.sensing.suite.magnetometer
                steps = t_ns // int(round(self.dt * 1e9))
                tr.magnetometer_B = np.stack([mag.sample(tr.magnetic_field_B[:, i], int(k))
                                              for i, k in enumerate(steps)], axis=1)
        return tr


def _first(items: list[int], n: int = 10) -> str:
    """The first ``n`` of a list of episode numbers, and how many more."""
    head = ", ".join(str(x) for x in items[:n])
    return head + (f" and {len(items) - n} more" if len(items) > n else "")


def _simulate_stepwise(plant, wheels, dist, guide, ctrl, swaps: dict, K: int, dt: float,
                       sensing: Sensing | None = None, magnetic: MagneticLoop | None = None) -> Trajectory:
    """The stepwise driver: the step objects called from Python, step by step, as the nodes call them.

    With ``sensing`` the sensors sample the truth and the estimator runs on them each step; the controller
    reads the estimate when ``sensing.feedback`` is ``estimate`` (the graph's remap), else the truth. With
    ``magnetic`` the controller's dipole and the rods' torque follow the wheels' step (:class:`MagneticLoop`).
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
    if magnetic is not None:
        for name in ("magnetic_field_B", "dipole_cmd_B", "magnetic_torque_B") + (("magnetometer_B",) if sensing
                                                                                 else ()):
            setattr(tr, name, np.empty((P, K + 1, 3)))
    fdir = wheels.fdir if isinstance(wheels, Wheels) else None
    if fdir is not None:
        tr.fdir_residual, tr.fdir_isolated = np.empty((P, K + 1, nw)), np.empty((P, K + 1), dtype=np.int64)
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
        if fdir is not None:
            tr.fdir_residual[:, k] = fdir.residual
            tr.fdir_isolated[:, k] = fdir.isolated + 1
        if magnetic is not None:
            tau_ext = tau_ext + _magnetic_step(tr, k, k * dt_ns, s.q_BN, ws.h_wheels_B, u, magnetic, sensing,
                                               ctrl.active)
        if k < K:
            plant.advance(ws.tau_c_B, ws.h_wheels_B, tau_ext)
    return tr


def _magnetic_step(tr: Trajectory, k: int, t_ns: int, q_BN: np.ndarray, h_wheels_B: np.ndarray, u: np.ndarray,
                   magnetic: MagneticLoop, sensing: Sensing | None, active: str) -> np.ndarray:
    """Step ``k`` of the magnetorquers' loop, kept in ``tr``; returns the rods' torque (P, 3) N m: the field at
    t_k, its magnetometer reading (the controller's with ``feedback: estimate``), the dipole (from the law's
    command ``u`` where the rods make it) and the torque."""
    b_B = magnetic.field_B(t_ns, q_BN)
    b_read = b_B
    if sensing is not None:
        tr.magnetometer_B[:, k] = sensing.suite.magnetometer.sample(b_B, k)
        if sensing.feedback == "estimate":
            b_read = tr.magnetometer_B[:, k]
    m_cmd, tau_mag = magnetic.step(active, h_wheels_B, b_B, b_read, u, k)
    tr.magnetic_field_B[:, k], tr.dipole_cmd_B[:, k], tr.magnetic_torque_B[:, k] = b_B, m_cmd, tau_mag
    return tau_mag
