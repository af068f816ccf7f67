"""``attitude-sil fidelity``: every published number the model fixes, paper against project.

One :class:`Row` per number a paper prints about a result the project's model
and presets determine: the paper, where it is printed (equation, table,
figure or section), the quantity, the paper's value, a tolerance (absolute,
relative, or a bound the paper states as a requirement) with a one-line reason,
and a function that computes the project's value from the presets in
``config/``. A row's status is

* ``PASS``: the project's value is within the tolerance around the paper's number;
* ``EXPLAINED``: it is not, and the row carries the band of what the model
  gives (``band``, with ``why``, one line) and names the section of
  ``docs/fidelity.md`` that shows why no reading of the paper reproduces the
  printed number (the readings tried and what each gives); the value lies in
  that band;
* ``FAIL``: neither, and always when the value is NaN (a run that went wrong
  is no evidence of anything; a response that never settles is ``inf``, said
  so where it is computed).

So every row can fail: a PASS row when its value leaves the tolerance, an
EXPLAINED row when its value leaves its band (a change of the model that moves
it fails until the explanation is updated on purpose). A band is the row's
value at the preset's step, widened on each side by :data:`BAND_STEP_BOUNDS`
times :func:`step_bound`, how far the value may move when the step is divided
by 10 (``test_fidelity.py`` holds every row to it), and rounded outward to 4
significant digits: a first-order error that moves by at most one bound over a
tenfold refinement lies within 1.1 bounds of its limit, so refining the step
cannot leave the band, and anything that moves the value by more than about
two bounds (2 %, or 1 s of a settling time) does.

Each row also says what kind of evidence it is (:data:`EVIDENCE`):

* ``identification``: a constant the paper does not publish was fitted so the
  model reproduces this number (:data:`IDENTIFIED` names each constant, its
  preset keys and the rows it was fitted on); a PASS shows the fit, not the model;
* ``prediction``: nothing of the model was fitted on this number;
* ``construction``: the number holds by the way the project builds its value
  (a design placed to meet it).

Rows that share a simulation share it (each group is computed once per
:class:`Presets`). ROS-free; the batch engine does every run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from attitude_sil.core.analysis.metrics import scenario_metrics, step_metrics, tracking_metrics
from attitude_sil.core.papers import PAPERS
from attitude_sil.core.plant.actuators import SpeedLoopWheels
from attitude_sil.core.plant.plants import FLEXIBLE_CASES
from attitude_sil.core.plant.quaternion import euler_from_quat
from attitude_sil.core.sim.build import flexible_settling
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import PRESETS, Scenario, default_config_dir, load_scenario
from attitude_sil.core.trajectory import all_finite
from attitude_sil.errors import AttitudeSilError
from attitude_sil.tuning.linearize import PAPER_000_TABLE_1, PAPER_000_TABLE_1_DURATION, rmse_table

from .rootlocus import closed_loop, place_poles, reduced_roll_loop

__all__ = ["PAPERS", "EVIDENCE", "IDENTIFIED", "Identified", "Row", "RowResult", "Presets", "ROWS",
           "PAPER_000_GAINS", "PAPER_001_DESIGNS", "PAPER_002_GAINS", "check", "counts", "format_report",
           "report_dict", "default_config_dir"]

STATUSES = ("PASS", "EXPLAINED", "FAIL")
EVIDENCE = ("prediction", "identification", "construction")
#: an explained row's band: its value at the preset's step +- this many :func:`step_bound`
BAND_STEP_BOUNDS = 2.0


@dataclass(frozen=True)
class Identified:
    """A constant no paper publishes, fitted to some of its published numbers and frozen in a preset.

    ``keys``: the ``node.parameter`` names (or module constants) it sets;
    ``how``: the fit in one line (docs/fidelity.md has the readings).
    The rows it was fitted on are those whose ``fitted`` names it.
    """

    name: str
    preset: str
    keys: tuple[str, ...]
    how: str

#: paper 000 PID gains (Kp, Ki, Kd, N): "Genetic algorithm based tuning" and "Root locus-based tuning"
PAPER_000_GAINS = {"ga": (48.894, 0.071, 106.046, 1.427), "root_locus": (113.554, 0.006, 260.942, 14.626)}

#: paper 001 designs: label -> (K diagonal, L diagonal, Ts s, Ce N m s) (Tables 1-4; the hand-tuned design of
#: "Results"; Table 3 prints beta Ce with beta = 1000, divided here)
PAPER_001_DESIGNS = {
    "hand-tuned": ((0.0175, 0.02, 0.025), (0.1, 0.1, 0.1), 186.9, 0.0626),
    "Tables 1-2 row 1": ((0.0445, 0.0397, 0.0207), (0.0715, 0.0905, 0.0905), 205.4, 0.12),
    "Tables 1-2 row 2": ((0.0619, 0.0255, 0.0175), (0.0937, 0.0921, 0.0715), 187.1, 0.12),
    "Tables 1-2 row 3": ((0.0651, 0.0112, 0.0207), (0.0905, 0.0984, 0.0937), 179.4, 0.1),
    "Tables 1-2 row 4": ((0.0604, 0.0017, 0.0302), (0.0968, 0.0968, 0.0984), 176.1, 0.1),
    "Tables 3-4 row 1": ((0.0049, 0.0112, 0.0096), (0.0952, 0.0937, 0.0826), 237.5, 0.03288),
    "Tables 3-4 row 2": ((0.0017, 0.035, 0.0604), (0.0794, 0.0715, 0.0889), 268.87, 0.1351),
    "Tables 3-4 row 3": ((0.0001, 0.0033, 0.0223), (0.0952, 0.081, 0.0921), 245.9, 0.04381),
    "Tables 3-4 row 4": ((0.0096, 0.0175, 0.0064), (0.0984, 0.0889, 0.0905), 230.8, 0.03956),
}

#: paper 002 (P, I, D): "pso" is Table II's MSE column (signs for e = setpoint - y, as the preset); "manual",
#: the manually tuned PID of Fig. 3-7 (a), is not printed: identified from its four finite *flexible*
#: settling times of section V by least squares over a 9 x 8 x 9 grid (Kp 2-200, Ki 0-20, Kd 5-500); its
#: rigid times and case 4 are held out (docs/fidelity.md, "The manual PID"; Table II's "Nominal case"
#: column, 41.0468 / 3.7302 / 112.464, behaves as the PSO gains)
PAPER_002_GAINS = {"pso": (41.2234, 3.9324, 112.4628), "manual": (112.468, 0.2, 158.114)}
#: paper 002 section V: settling times (flexible, rigid), s, per case; inf = "continuous vibration"
PAPER_002_SETTLING = {
    "pso": {"nominal": (20.0, 20.0), "case1": (30.0, 30.0), "case2": (45.0, 45.0), "case3": (30.0, 30.0),
            "case4": (50.0, 50.0)},
    "manual": {"nominal": (20.0, 40.0), "case1": (32.0, 60.0), "case2": (70.0, 80.0), "case3": (35.0, 60.0),
               "case4": (math.inf, math.inf)},
}


#: every constant of the presets that was fitted to published results (the rows name them in ``fitted``)
IDENTIFIED = {i.name: i for i in (
    Identified("000 motor", "hst_roll_step_unlimited",
               ("wheels.motor.torque_constant", "wheels.motor.back_emf_constant", "wheels.motor.resistance",
                "wheels.motor.v_max", "controller.output_limit"),
               "least squares of the printed J of both gain sets on the paper's unlimited motor, with the "
               "root-locus requirements on the linear model as penalties; K and R also in hst_roll_step.yaml "
               "(rated drive)"),
    Identified("000 Table 1 run length", "hst_roll_step_unlimited", ("tuning.linearize.PAPER_000_TABLE_1_DURATION",),
               "the run length whose RMSE table is nearest Table 1 (RMS log ratio)"),
    Identified("002 manual gains", "flexible_axis", ("tuning.fidelity.PAPER_002_GAINS['manual']",),
               "grid least squares of the manual PID's four finite flexible settling times"),
    Identified("003 attitude gains and step", "cubesat_1u",
               ("controller.pid.kp", "controller.pid.kd", "controller.fuzzy_pid.kp", "controller.fuzzy_pid.kd",
                "guidance.setpoint_rpy_deg"),
               "Nelder-Mead on the two attitude settling times (2.5 s PID, 2.0 s hybrid)"),
)}


class Presets:
    """The preset scenarios of a config folder, with each shared computation done once."""

    NAMES = PRESETS + ("hst_roll_step_unlimited",)

    def __init__(self, config_dir: str | Path | None = None, refine: int = 1) -> None:
        """``refine``: divide every preset's control period (and so its integration step) by this."""
        self.refine = int(refine)
        self.dir = Path(config_dir) if config_dir is not None else default_config_dir()
        if not self.dir.is_dir():
            raise AttitudeSilError(f"--config {self.dir}: not a folder of presets")
        missing = [n for n in self.NAMES if not (self.dir / f"{n}.yaml").is_file()]
        if missing:
            raise AttitudeSilError(f"--config {self.dir}: missing preset(s) {', '.join(m + '.yaml' for m in missing)}")
        self._memo: dict[str, object] = {}

    def scenario(self, name: str) -> Scenario:
        """A preset, loaded and validated once."""
        def load() -> Scenario:
            scn = load_scenario(self.dir / f"{name}.yaml")
            return scn if self.refine == 1 else scn.with_values("/**", control_period=scn.dt / self.refine)
        return self.memo(f"scn:{name}", load)

    def memo(self, key: str, fn: Callable[[], object]):
        """``fn()`` computed once per key."""
        if key not in self._memo:
            self._memo[key] = fn()
        return self._memo[key]


@dataclass(frozen=True)
class Row:
    """One published number.

    ``kind``: ``abs`` or ``rel`` (|project - paper| within ``tolerance``, absolute or
    relative to the paper's value), ``max`` (the paper states an upper bound:
    the project's value must not exceed ``paper``), ``min`` (the paper states a lower
    bound: the project's value must exceed it), ``never`` (the paper says it
    never happens: the project's value must be infinite, e.g. a response that
    never settles). ``explained``: the docs/fidelity.md section that shows why
    the printed number is out of reach of every reading of the paper; such a
    row states ``band``, (low, high), the values the model gives (see the
    module's docstring for its width), and ``why``, one line: what in the
    model puts it there. A row has an explanation and a band, or neither.
    """

    paper: str
    where: str
    quantity: str
    paper_value: float
    unit: str
    kind: str
    tolerance: float
    reason: str
    compute: Callable[[Presets], float]
    evidence: str
    explained: str = ""
    fitted: tuple[str, ...] = ()
    converged_within: float = 0.0  # an absolute bound for the step-convergence test where 1 % does not fit
    band: tuple[float, float] | None = None
    why: str = ""

    def __post_init__(self) -> None:
        if self.evidence not in EVIDENCE:
            raise ValueError(f"row {self.id}: evidence must be one of {EVIDENCE}, got {self.evidence!r}")
        if (self.evidence == "identification") != bool(self.fitted):
            raise ValueError(f"row {self.id}: an identification row names the constants fitted on it, "
                             "and only such a row does")
        if bool(self.explained) != (self.band is not None) or bool(self.explained) != bool(self.why):
            raise ValueError(f"row {self.id}: an explained row states the band the model gives and why, "
                             "and only such a row does")
        if self.band is not None and not (math.isfinite(self.band[0]) and math.isfinite(self.band[1])
                                          and self.band[0] <= self.band[1]):
            raise ValueError(f"row {self.id}: band {self.band} is not a finite interval (low, high)")

    @property
    def id(self) -> str:
        """A stable name for the row (test ids, JSON)."""
        text = f"{self.paper} {self.where} {self.quantity}".lower()
        return "-".join("".join(c if c.isalnum() or c == "." else " " for c in text).split())


@dataclass(frozen=True)
class RowResult:
    """A row with the project's value and its status."""

    row: Row
    value: float
    status: str

    def as_dict(self) -> dict:
        """JSON-ready (infinite and NaN values as null: a never-settling row says ``never``, a NaN FAILs)."""
        r = self.row
        v = None if not math.isfinite(self.value) else self.value
        p = None if not math.isfinite(r.paper_value) else r.paper_value
        return {"id": r.id, "paper": r.paper, "where": r.where, "quantity": r.quantity, "unit": r.unit,
                "paper_value": p, "project_value": v, "kind": r.kind, "tolerance": r.tolerance,
                "reason": r.reason, "status": self.status, "evidence": r.evidence, "fitted": list(r.fitted),
                "explained": r.explained or None, "band": list(r.band) if r.band is not None else None,
                "why": r.why or None}


def within(row: Row, value: float) -> bool:
    """Whether ``value`` meets the row's tolerance (never a NaN, whatever the kind)."""
    if math.isnan(value):
        return False
    if row.kind == "never":
        return value == math.inf
    if not math.isfinite(value):
        return False
    if row.kind == "max":
        return value <= row.paper_value + row.tolerance
    if row.kind == "min":
        return value > row.paper_value - row.tolerance
    if row.kind == "rel":
        return abs(value - row.paper_value) <= row.tolerance * abs(row.paper_value)
    return abs(value - row.paper_value) <= row.tolerance


def in_band(row: Row, value: float) -> bool:
    """Whether ``value`` lies in the band the row states for the model (False for a row without one, and NaN)."""
    return row.band is not None and row.band[0] <= value <= row.band[1]


def status_of(row: Row, value: float) -> str:
    """PASS within the tolerance, EXPLAINED within the row's stated band, else FAIL (NaN: FAIL, every kind)."""
    if within(row, value):
        return "PASS"
    return "EXPLAINED" if in_band(row, value) else "FAIL"


def step_bound(row: Row, value: float) -> float:
    """How far the row's value may move when the control period and the integration step are divided by 10.

    1 % of the value; a settling time in seconds 0.5 s or 1 %, whichever is more (it is read on the
    output's time grid); a row's own ``converged_within`` where neither fits.
    """
    if row.converged_within:
        return row.converged_within
    if "settling time" in row.quantity and row.unit == "s":
        return max(0.5, 0.01 * abs(value))
    return 0.01 * abs(value)


def evaluate_row(row: Row, presets: Presets) -> RowResult:
    """The row's project value and status."""
    value = float(row.compute(presets))
    return RowResult(row, value, status_of(row, value))


def check(papers=PAPERS, config_dir: str | Path | None = None, progress=None, refine: int = 1) -> list[RowResult]:
    """Every row of the given papers, evaluated on the presets of ``config_dir``.

    ``progress(paper, i, n)``, if given, is called as each paper starts (the
    whole check takes a while), once the input is known to be good.
    ``refine``: control period and integration step divided by this (the convergence check).
    """
    bad = [p for p in papers if p not in PAPERS]
    if bad:
        raise AttitudeSilError(f"--paper must be one of {', '.join(PAPERS)}, got {', '.join(bad)}")
    presets = Presets(config_dir, refine)
    chosen = [p for p in PAPERS if p in papers]
    out = []
    for i, paper in enumerate(chosen, start=1):
        if progress is not None:
            progress(paper, i, len(chosen))
        out += [evaluate_row(r, presets) for r in ROWS if r.paper == paper]
    return out


def _finite(tr) -> np.ndarray:
    """Per episode, whether the run stayed finite (attitude, rate, torque), (P,) bool.

    The metrics read a NaN sample as inside every band, so a run that went wrong could look settled: a
    group of rows gives NaN for such an episode instead, and a NaN row FAILs whatever its kind.
    """
    return all_finite(tr.q_BN, tr.omega_BN_B, tr.tau_c_B)


def _where_finite(ok: np.ndarray, values) -> np.ndarray:
    """``values`` (P,), with NaN where the episode's run did not stay finite."""
    return np.where(ok, np.asarray(values, float), np.nan)


# ------------------------------------------------------------------ paper 000
_FIT_MOTOR = {"evidence": "identification", "fitted": ("000 motor",)}

def _pid(gains, n_rows: int = 1) -> dict:
    kp, ki, kd, n = gains
    return {"pid.kp": [[kp] * 3] * n_rows, "pid.ki": [[ki] * 3] * n_rows, "pid.kd": [[kd] * 3] * n_rows,
            "pid.n": [[n] * 3] * n_rows}


def _hst_design(ps: Presets) -> dict:
    """The project's root-locus design on the linearised roll loop (tune_hst_pid_rootlocus.yaml's settings)."""
    def run():
        scn = ps.scenario("hst_roll_step")
        return place_poles(reduced_roll_loop(scn, 0), scn.param("scenario", "metrics.tau_d"))
    return ps.memo("000:design", run)


def _hst_step(ps: Presets, preset: str = "hst_roll_step") -> dict:
    """Nonlinear 1 deg roll step with the paper's GA gains, its root-locus gains and the project's design."""
    def run():
        scn = ps.scenario(preset)
        sets = [PAPER_000_GAINS["ga"], PAPER_000_GAINS["root_locus"], _hst_design(ps)["gains"]]
        params = {k: [_pid(g)[k][0] for g in sets] for k in ("pid.kp", "pid.ki", "pid.kd", "pid.n")}
        tr = simulate(scn, 3, controller_params=params, controller="pid", schedule=[], threads=1)
        m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B, scn.values["scenario"])
        m = {k: _where_finite(_finite(tr), v) for k, v in m.items()}
        return {name: {k: float(v[i]) for k, v in m.items()} for i, name in enumerate(("ga", "root_locus", "design"))}
    return ps.memo(f"000:step:{preset}", run)


#: Fig. 8's disturbance: band-limited white noise of power 5e-6 N^2 m^2 s sampled at 1 ms (sec. 2.D), on roll
FIG8_SEEDS = 8


def _hst_disturbed(ps: Presets) -> dict:
    """RMS roll error (rad) over 10-20 s of the 1 deg step under Fig. 8's disturbance, per gain set.

    The rated preset with the noise on roll, FIG8_SEEDS seeds, each flown by both gain sets (same noise).
    """
    def run():
        scn = ps.scenario("hst_roll_step").with_values(
            "disturbance", models=["noise"], **{"noise.power": [5e-6, 0.0, 0.0], "noise.sample_time": 0.001})
        sets = [PAPER_000_GAINS["ga"]] * FIG8_SEEDS + [PAPER_000_GAINS["root_locus"]] * FIG8_SEEDS
        params = {k: [_pid(g)[k][0] for g in sets] for k in ("pid.kp", "pid.ki", "pid.kd", "pid.n")}
        seeds = np.tile(np.arange(FIG8_SEEDS), 2)
        tr = simulate(scn, len(sets), controller_params=params, controller="pid", schedule=[], threads=1,
                      episode_values={"disturbance.noise.seed": seeds})
        roll = euler_from_quat(tr.q_BN)[:, :, 0] - np.radians(1.0)
        late = tr.t >= 10.0
        rms = _where_finite(_finite(tr), np.sqrt(np.mean(roll[:, late] ** 2, axis=1)))
        return {"ga": float(np.mean(rms[:FIG8_SEEDS])), "root_locus": float(np.mean(rms[FIG8_SEEDS:]))}
    return ps.memo("000:fig8", run)


def _hst_linear(ps: Presets, which: str) -> dict:
    """Linear closed-loop step figures (63.2 % time, overshoot, 2 % settling) of a gain set, python-control."""
    def run():
        import control  # where it is used: seconds of a process's start (tuning/rootlocus.py)

        scn = ps.scenario("hst_roll_step")
        cl = closed_loop(reduced_roll_loop(scn, 0), *PAPER_000_GAINS[which])
        info = control.step_info(cl, T=np.linspace(0.0, 60.0, 6001))
        return {"overshoot_pct": float(info["Overshoot"]), "settling_time_s": float(info["SettlingTime"])}
    return ps.memo(f"000:linear:{which}", run)


def _hst_table1(ps: Presets) -> np.ndarray:
    return ps.memo("000:table1", lambda: rmse_table(ps.scenario("hst_roll_step_unlimited"),
                                                     duration=PAPER_000_TABLE_1_DURATION))


def _rows_000() -> list[Row]:
    unl = "hst_roll_step_unlimited"
    rows = [
        Row("000", "Results", "cost J of the GA gains, wheels as rated", 0.5129, "", "rel", 0.05,
            "J = |tau - 1.5| + OS printed to 4 digits; 5 % covers the time-constant read-off",
            lambda ps: _hst_step(ps)["ga"]["cost_J"], **_FIT_MOTOR, explained="paper-000-cost-j",
            band=(0.3565, 0.3712), why="the rated 0.8 N m wheels: the GA gains come out faster, tau 1.21 s"),
        Row("000", "Results", "cost J of the root-locus gains, wheels as rated", 0.7215, "", "rel", 0.05,
            "as the GA row", lambda ps: _hst_step(ps)["root_locus"]["cost_J"],
            **_FIT_MOTOR, explained="paper-000-cost-j", band=(1.276, 1.329),
            why="the root-locus gains' derivative kick saturates the rated 0.8 N m wheels: tau 2.8 s"),
        Row("000", "Results", "cost J of the GA gains, UNLIMITED wheels variant", 0.5129, "", "rel", 0.05,
            "as above, on hst_roll_step_unlimited.yaml (no 0.8 N m limit, as eq. 15-16)",
            lambda ps: _hst_step(ps, unl)["ga"]["cost_J"], **_FIT_MOTOR),
        Row("000", "Results", "cost J of the root-locus gains, UNLIMITED wheels variant", 0.7215, "", "rel", 0.05,
            "as above", lambda ps: _hst_step(ps, unl)["root_locus"]["cost_J"], **_FIT_MOTOR),
        Row("000", "Fig. 8", "disturbance rejection: RMS roll error GA gains / root-locus gains", 1.0, "",
            "min", 0.0, "the paper: the root-locus gains reject the disturbance better (a ratio above 1); "
            f"{FIG8_SEEDS} seeds of its noise, 10-20 s, wheels as rated",
            lambda ps: _hst_disturbed(ps)["ga"] / _hst_disturbed(ps)["root_locus"], evidence="prediction"),
        Row("000", "Root locus-based tuning", "overshoot of the root-locus gains (linear model)", 2.0, "%", "max", 0.0,
            "the paper's requirement, met on the linearised model",
            lambda ps: _hst_linear(ps, "root_locus")["overshoot_pct"], **_FIT_MOTOR),
        Row("000", "Root locus-based tuning", "settling time of the root-locus gains (linear model)", 6.0, "s",
            "max", 0.0, "the paper's requirement, met on the linearised model",
            lambda ps: _hst_linear(ps, "root_locus")["settling_time_s"], **_FIT_MOTOR),
        Row("000", "Root locus-based tuning", "project root-locus design: settling time (linear model)", 6.0, "s",
            "max", 0.0, "the paper's requirement for its design, applied to the project's",
            lambda ps: _hst_design(ps)["settling_time_s"], evidence="construction"),
        Row("000", "Root locus-based tuning", "project root-locus design: overshoot (linear model)", 2.0, "%",
            "max", 0.0, "the paper's requirement for its design, applied to the project's",
            lambda ps: _hst_design(ps)["overshoot_pct"], evidence="construction"),
        Row("000", "Root locus-based tuning", "project root-locus design: time constant (linear model)", 1.5, "s",
            "abs", 0.1, "the design target tau_d; 0.1 s is the placement grid's resolution",
            lambda ps: _hst_design(ps)["time_constant_s"], evidence="construction"),
    ]
    for i, ang in enumerate(PAPER_000_TABLE_1):
        for a, axis in enumerate(("roll", "pitch", "yaw")):
            band, why = _TABLE_1_BANDS.get((ang, axis), (None, ""))
            rows.append(Row("000", "Table 1", f"RMSE nonlinear vs linear, {ang} deg {axis}",
                            PAPER_000_TABLE_1[ang][a], "deg", "rel", 0.5,
                            "the run length is identified from the table itself; 50 %",
                            lambda ps, i=i, a=a: float(_hst_table1(ps)[i, a]), evidence="identification",
                            fitted=("000 Table 1 run length", "000 motor"),
                            explained="paper-000-table-1" if band else "", band=band, why=why))
    return rows


_ROLL = "the roll column is 1.8-2.5 times the paper's at every run length tried while pitch and yaw fit"
#: paper 000 Table 1: the cells out of reach (angle deg, axis) -> (the model's band, why)
_TABLE_1_BANDS = {
    (3, "roll"): ((0.001561, 0.001626), _ROLL), (8, "roll"): ((0.02618, 0.02725), _ROLL),
    (15, "roll"): ((0.162, 0.1687), _ROLL), (25, "roll"): ((0.7108, 0.74), _ROLL),
    (35, "roll"): ((1.848, 1.925), _ROLL),
    (35, "pitch"): ((1.236, 1.287), "0.47 times the paper's: the run length the other cells identify is too "
                                     "short for it"),
}


# ------------------------------------------------------------------ paper 001
#: paper 001 Fig. 6: inertia perturbations (%) flown with one GA design, and the design (assumed: the best of
#: Tables 1-2, beta = 1, by its printed fitness; the paper says "the GA-derived 'optimal' controller")
FIG6_PCT = (-12.5, -5.0, 0.0, 5.0, 10.0, 12.5)
FIG6_DESIGN = "Tables 1-2 row 4"


def _hawaiisat_runs(ps: Presets) -> dict:
    """Ts (s) and Ce (N m s) of every design at the nominal inertia, then of FIG6_DESIGN per perturbation.

    One batch: the designs first (in PAPER_001_DESIGNS order), then FIG6_PCT (the controller keeps the
    nominal J). The preset's torque rods run in the stepwise driver, whose cost is per step, not per episode.
    """
    def run():
        scn = ps.scenario("hawaiisat_lvlh")
        inertia = np.asarray(scn.param("plant", "inertia"), float)
        designs = list(PAPER_001_DESIGNS.values()) + [PAPER_001_DESIGNS[FIG6_DESIGN]] * len(FIG6_PCT)
        scale = [0.0] * len(PAPER_001_DESIGNS) + list(FIG6_PCT)
        tr = simulate(scn, len(designs), controller_params={"geometric.k": [list(d[0]) for d in designs],
                                                            "geometric.l": [list(d[1]) for d in designs]},
                      schedule=[], threads=1,
                      episode_values={"plant.inertia": np.array([inertia * (1 + p / 100) for p in scale])})
        m = tracking_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B)
        ok = _finite(tr)
        return {"ts": _where_finite(ok, m["settling_time_s"]), "ce": _where_finite(ok, m["control_effort_Nms"])}
    return ps.memo("001", run)


def _hawaiisat(ps: Presets) -> dict:
    """Design label -> (Ts s, Ce N m s) at the nominal inertia."""
    r = _hawaiisat_runs(ps)
    return {k: (float(r["ts"][i]), float(r["ce"][i])) for i, k in enumerate(PAPER_001_DESIGNS)}


def _fig6(ps: Presets) -> dict:
    """Ts (s) and Ce (N m s) per inertia perturbation of FIG6_PCT."""
    r = _hawaiisat_runs(ps)
    n = len(PAPER_001_DESIGNS)
    return {"ts": r["ts"][n:], "ce": r["ce"][n:]}


def _fig6_jump(ps: Presets) -> float:
    """Ts(+12.5 %) - Ts(+10 %) over the mean change per 2.5 % of inertia from -12.5 % to +10 %."""
    ts = _fig6(ps)["ts"]
    per_step = (ts[-2] - ts[0]) / ((FIG6_PCT[-2] - FIG6_PCT[0]) / 2.5)
    return float((ts[-1] - ts[-2]) / per_step)


#: when the real-rods row reads the error: the paper's Ts of the hand-tuned design (186.9 s) to the step
REAL_RODS_AT_S = 187.0


def _real_rods_error(ps: Presets) -> float:
    """The principal error angle (rad) at :data:`REAL_RODS_AT_S` of the hand-tuned design flown on three
    25 A m^2 rods in the IGRF field (``config/hawaiisat_lvlh_magnetic.yaml``), where the paper's design on
    ideal 1.2 mN m rods has settled below 0.003 rad."""
    def run():
        scn = ps.scenario("hawaiisat_lvlh_magnetic")
        tr = simulate(scn, 1, duration=REAL_RODS_AT_S, schedule=[])
        m = tracking_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B)
        return float(_where_finite(_finite(tr), m["final_error_rad"])[0])
    return ps.memo("001-rods", run)


_TABLE_3_ROW_2 = {"explained": "paper-001-table-3-row-2", "band": (0.1231, 0.1282),
                  "why": "-7 % at every converged control period; the row's own f = -(Ts + beta Ce) does not add up"}


def _rows_001() -> list[Row]:
    rows = []
    for label, (_, _, ts, ce) in PAPER_001_DESIGNS.items():
        where = "Results" if label == "hand-tuned" else label
        digits = len(f"{ce}".split(".")[1])
        rows.append(Row("001", where, "settling time Ts" + (" (hand-tuned gains)" if label == "hand-tuned" else ""),
                        ts, "s", "rel", 0.03, "the issue's 3 % (the paper gives no control period: 50 Hz, converged)",
                        lambda ps, k=label: _hawaiisat(ps)[k][0], evidence="prediction"))
        tol = 0.05 if digits >= 3 else 0.15
        rows.append(Row("001", where, "control effort Ce" + (" (hand-tuned gains)" if label == "hand-tuned" else ""),
                        ce, "N m s", "rel", tol,
                        "printed to 3-4 digits: 5 %" if digits >= 3 else "printed to 1-2 digits: 15 %",
                        lambda ps, k=label: _hawaiisat(ps)[k][1], evidence="prediction",
                        **(_TABLE_3_ROW_2 if label == "Tables 3-4 row 2" else {})))
    for key, name in (("ts", "settling time Ts"), ("ce", "control effort Ce")):
        rows.append(Row("001", "Fig. 6", f"{name} rises with the inertia: steps where it does not", 0.0,
                        "", "abs", 0.0, f"'both Ts and Ce ... get worse for increasing values of J'; {FIG6_DESIGN}, "
                        "inertia -12.5 ... +12.5 %", lambda ps, key=key: float(np.sum(np.diff(_fig6(ps)[key]) <= 0)),
                        evidence="prediction"))
    rows.append(Row("001", "Fig. 6", "jump in Ts from +10 % to +12.5 % inertia, in mean steps per 2.5 %", 3.0, "",
                    "min", 0.0, "'the large jump in the value of Ts when the inertia perturbation is increased "
                    "from 10% to 12.5%'; read as at least 3 times the mean step (assumed)", _fig6_jump,
                    evidence="prediction", explained="paper-001-fig-6", band=(0.7201, 1.121),
                    why="with this design Ts rises evenly with J; other designs jump, at other perturbations",
                    converged_within=0.1))  # a ratio of settling-time differences: 0.1 of a 2.5 s step is 0.25 s
    rows.append(Row("001", "Sec. 3", f"error at Ts ({REAL_RODS_AT_S:g} s) on 25 A m^2 rods, IGRF field",
                    0.003, "rad", "max", 0.0,
                    "settled: below ||zeta_ref|| = 0.003 from Ts on (sec. 3)", _real_rods_error,
                    evidence="prediction", explained="paper-001-real-rods", band=(0.1864, 0.1941),
                    why="the field lies within 20 deg of the orbit normal: the rods cannot turn the body at the "
                        "orbit rate"))
    return rows


# ------------------------------------------------------------------ paper 002
def _flexible(ps: Presets) -> dict:
    """Rigid and flexible settling of both PIDs on the five plants, in one batch (the plant per episode)."""
    def run():
        scn = ps.scenario("flexible_axis")
        names = list(PAPER_002_GAINS)
        pairs = [(which, case) for case in FLEXIBLE_CASES for which in names]  # one episode each
        params = {k: [[PAPER_002_GAINS[w][i]] * 3 for w, _ in pairs] for i, k in enumerate(("pid.kp", "pid.ki",
                                                                                                "pid.kd"))}
        cases = [case for _, case in pairs]
        tr = simulate(scn, len(pairs), controller_params=params, schedule=[], threads=1,
                      episode_values={"plant.flex.case": cases})
        split = flexible_settling(scn, tr, flex_case=cases)
        ok = _finite(tr)
        # not settled by the end of a finite run: never (the manual PID's case 4 "vibrates"); a run that went
        # wrong stays NaN
        never = {k: np.where(np.isnan(v) & ok, math.inf, _where_finite(ok, v)) for k, v in split.items()}
        return {pair: (float(never["flexible_settling_time_s"][i]), float(never["rigid_settling_time_s"][i]))
                for i, pair in enumerate(pairs)}
    return ps.memo("002", run)


def _pso_case_settling(ps: Presets) -> dict[str, float]:
    """Per plant, when both responses of the PSO gains are settled ("both stabilized at"), s."""
    return {case: float(np.max(_flexible(ps)["pso", case])) for case in FLEXIBLE_CASES}  # NaN stays NaN


_PSO = "every mismatch case settles 10-17 s before the paper's figure, in every reading of eq. 1-4 tried"
_RIGID = "with any PID of the identification grid the rigid body settles before its appendage"
#: paper 002: the settling rows out of reach (gains, case, response) -> (the model's band, why)
_002_BANDS = {
    ("pso", "case1", "flexible"): ((17.9, 19.91), _PSO), ("pso", "case1", "rigid"): ((16.92, 18.93), _PSO),
    ("pso", "case2", "flexible"): ((30.38, 32.38), _PSO), ("pso", "case2", "rigid"): ((26.94, 28.94), _PSO),
    ("pso", "case3", "flexible"): ((17.2, 19.2), _PSO), ("pso", "case3", "rigid"): ((14.79, 16.79), _PSO),
    ("pso", "case4", "flexible"): ((32.36, 34.36), _PSO), ("pso", "case4", "rigid"): ((27.26, 29.26), _PSO),
    ("manual", "nominal", "rigid"): ((15.62, 17.62), _RIGID), ("manual", "case1", "rigid"): ((22.52, 24.52), _RIGID),
    ("manual", "case2", "rigid"): ((51.31, 53.41), _RIGID), ("manual", "case3", "rigid"): ((28.2, 30.2), _RIGID),
    ("manual", "case3", "flexible"): ((41.22, 43.22), "the least squares of the four flexible times leaves "
                                                       "case 3 7 s late"),
    ("manual", "case4", "flexible"): ((81.71, 85.05), "the identified gains settle case 4; gains that keep it "
                                                       "vibrating miss every other time"),
    ("manual", "case4", "rigid"): ((64.18, 66.8), "the identified gains settle case 4; gains that keep it "
                                                   "vibrating miss every other time"),
}


def _rows_002() -> list[Row]:
    rows = []
    for which, cases in PAPER_002_SETTLING.items():
        label = "PSO-tuned PID" if which == "pso" else "manual PID"
        fig = "(b)" if which == "pso" else "(a)"
        for j, case in enumerate(cases):
            for part, name in enumerate(("flexible", "rigid")):
                paper = cases[case][part]
                kind = "never" if math.isinf(paper) else "abs"
                # the manual PID's gains are fitted on its finite flexible times; all else is held out
                fit = which == "manual" and part == 0 and kind == "abs"
                band, why = _002_BANDS.get((which, case, name), (None, ""))
                rows.append(Row("002", f"Fig. {3 + j} {fig}, sec. V", f"{label}, {case}: {name} settling time", paper,
                                "s", kind, 5.0, "read off a figure by the authors to 5-10 s" if kind == "abs"
                                else "the paper: continuous vibration",
                                lambda ps, w=which, c=case, p=part: _flexible(ps)[w, c][p],
                                evidence="identification" if fit else "prediction",
                                fitted=("002 manual gains",) if fit else (),
                                explained="paper-002-settling" if band else "", band=band, why=why))
    rows += [
        Row("002", "sec. V", "PSO-tuned PID: largest flexible-rigid gap over the five plants", 0.0, "s", "abs", 5.0,
            "'both stabilize(d) at' the same time in every case; 5 s: the figures' reading",
            lambda ps: float(np.max([abs(_flexible(ps)["pso", c][0] - _flexible(ps)["pso", c][1])
                                     for c in FLEXIBLE_CASES])),
            evidence="prediction", explained="paper-002-settling", band=(4.997, 5.202),
            why="case 4's appendage settles 5.1 s after its body"),
        Row("002", "sec. V", "PSO-tuned PID: nominal settles first (nominal minus the fastest other case)", 0.0,
            "s", "max", 0.0, "nominal 20 s, the mismatch cases 30-50 s",
            lambda ps: _pso_case_settling(ps)["nominal"] - float(np.min([v for c, v in _pso_case_settling(ps).items()
                                                                         if c != "nominal"])),
            evidence="prediction", explained="paper-002-settling", band=(2.479, 2.581),
            why="case 3's rigid body settles 2.5 s before the nominal plant's"),
    ]
    return rows


# ------------------------------------------------------------------ paper 003
def _cubesat(ps: Presets) -> dict:
    def run():
        scn = ps.scenario("cubesat_1u")
        out = {}
        for law in ("pid", "fuzzy_pid"):
            tr = simulate(scn, 1, controller=law, schedule=[], threads=1)
            m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B, scn.values["scenario"])
            out[law] = float(_where_finite(_finite(tr), m["settling_time_s"])[0])
        return out
    return ps.memo("003", run)


def _speed_loop(ps: Presets) -> dict:
    """Paper 003's wheel-speed step (7330 rpm reference) with the preset's identified motor and GA PID."""
    def run():
        w = ps.scenario("cubesat_1u").values["wheels"]
        dt = 0.001 / ps.refine
        wheels = SpeedLoopWheels(w["speed_loop.motor_gain"], w["speed_loop.motor_a2"], w["speed_loop.motor_a1"],
                                 w["speed_loop.kp"], w["speed_loop.ki"], w["speed_loop.kd"], w["speed_loop.n"],
                                 w["motor.rotor_inertia"], w["motor.speed_max_rpm"], w["speed_loop.rpm_per_volt"],
                                 dt, 1)
        ref = -7330.0 / w["speed_loop.rpm_per_volt"]
        speeds = [wheels.advance(np.array([[ref, 0.0, 0.0]])).velocity[0, 0] for _ in range(10000 * ps.refine)]
        t = np.arange(len(speeds)) * dt
        y = np.array(speeds)[None] / (2 * np.pi / 60)
        m = step_metrics(t, y, np.array([y[0, -1]]), np.array([0.0]))
        ok = np.all(np.isfinite(y), axis=1)
        return {k: float(_where_finite(ok, m[k])[0]) for k in ("rise_time_s", "settling_time_s", "overshoot_pct")}
    return ps.memo("003:speed", run)


_FIT_003 = {"evidence": "identification", "fitted": ("003 attitude gains and step",)}


def _rows_003() -> list[Row]:
    return [
        Row("003", "sec. 6, speed loop", "wheel-speed rise time", 0.55, "s", "abs", 0.02,
            "printed to 2 digits", lambda ps: _speed_loop(ps)["rise_time_s"],
            evidence="prediction"),
        Row("003", "sec. 6, speed loop", "wheel-speed settling time", 2.00, "s", "abs", 0.05,
            "printed to 3 digits", lambda ps: _speed_loop(ps)["settling_time_s"],
            evidence="prediction"),
        Row("003", "sec. 6, speed loop", "wheel-speed overshoot", 3.99, "%", "abs", 0.1,
            "printed to 3 digits", lambda ps: _speed_loop(ps)["overshoot_pct"],
            evidence="prediction"),
        Row("003", "Fig. 8", "attitude settling time, PID", 2.5, "s", "abs", 0.1,
            "printed as 2.5 s", lambda ps: _cubesat(ps)["pid"], **_FIT_003),
        Row("003", "Fig. 9", "attitude settling time, hybrid fuzzy PID", 2.0, "s", "abs", 0.1,
            "printed as 2 s", lambda ps: _cubesat(ps)["fuzzy_pid"], **_FIT_003),
        Row("003", "Conclusion", "hybrid faster than PID by", 20.0, "%", "abs", 3.0,
            "'up to 20 %' from 2.5 s and 2.0 s",
            lambda ps: 100.0 * (1.0 - _cubesat(ps)["fuzzy_pid"] / _cubesat(ps)["pid"]),
            **_FIT_003,
            converged_within=1.0),  # points: a ratio of two settling times, each read on the step's grid
    ]


# ------------------------------------------------------------------ paper 004
def _pitch(ps: Presets) -> dict:
    def run():
        scn = ps.scenario("pitch_axis")
        out = {}
        for label, theta0 in (("impulse", 0.0), ("impulse+angle", 30.0)):
            variant = scn.with_values("plant", initial_attitude_rpy_deg=[0.0, theta0, 0.0])
            tr = simulate(variant, 1, schedule=[], threads=1)
            m = scenario_metrics(tr.t, tr.q_BN, tr.q_RN, tr.tau_actuators_B, scn.values["scenario"])
            out[label] = float(_where_finite(_finite(tr), m["settling_time_s"])[0])
        return out
    return ps.memo("004", run)


def _rows_004() -> list[Row]:
    return [
        Row("004", "Fig. 8 (a)", "impulse response: settling time", 10.0, "normalised",
            "max", 0.0, "the figure ends at t = 10 with the states at rest", lambda ps: _pitch(ps)["impulse"],
            evidence="prediction"),
        Row("004", "Fig. 8 (b)", "impulse and 30 deg initial pitch: settling time", 10.0,
            "normalised", "max", 0.0, "the figure ends at t = 10 with the states at rest (initial angle: "
            "theta_max, assumed)", lambda ps: _pitch(ps)["impulse+angle"], evidence="prediction"),
    ]


ROWS: list[Row] = _rows_000() + _rows_001() + _rows_002() + _rows_003() + _rows_004()


def _fmt(v: float) -> str:
    if math.isnan(v):
        return "NaN"
    if not math.isfinite(v):
        return "never"
    return f"{v:.4g}"


def counts(results: list[RowResult]) -> dict[str, dict[str, int]]:
    """Rows per evidence kind and status: ``{evidence: {status: n}}`` (every kind and status present)."""
    return {e: {st: sum(r.row.evidence == e and r.status == st for r in results) for st in STATUSES}
            for e in EVIDENCE}


def identified_rows(results: list[RowResult]) -> list[dict]:
    """Each identified constant with the ids of the rows (of ``results``) it was fitted on."""
    return [{"name": i.name, "preset": i.preset, "keys": list(i.keys), "how": i.how,
             "fitted_on": [r.row.id for r in results if i.name in r.row.fitted]}
            for i in IDENTIFIED.values()]


def report_dict(results: list[RowResult]) -> dict:
    """``fidelity --json``: the rows, the counts by evidence and status, and the identified constants."""
    by_evidence = counts(results)
    status_counts = {st: sum(by_evidence[e][st] for e in EVIDENCE) for st in STATUSES}
    return {"rows": [r.as_dict() for r in results], "status_counts": status_counts,
            "evidence_counts": by_evidence, "identified": identified_rows(results)}


def _headline(results: list[RowResult]) -> str:
    c = counts(results)
    parts = [f"{e}s {sum(c[e].values())} ({', '.join(f'{st} {n}' for st, n in c[e].items())})" for e in EVIDENCE]
    return "; ".join(parts)


def format_report(results: list[RowResult]) -> str:
    """The paper-vs-project table, then the counts per paper and per kind of evidence.

    An explained row shows, after its status, the band of what the model gives (``model band``).
    """
    lines = [f"{'paper':<5} {'where':<26} {'quantity':<60} {'paper':>9} {'project':>9} {'tolerance':>11} "
             f"{'evidence':<8} {'status':<9} model band"]
    short = {"prediction": "pred", "identification": "fit", "construction": "constr"}
    for r in results:
        row = r.row
        tol = {"abs": f"±{row.tolerance:g}", "rel": f"±{row.tolerance * 100:g} %", "max": "<= paper",
               "min": "> paper", "never": "never"}[row.kind]
        unit = f" [{row.unit}]" if row.unit else ""
        band = f"{_fmt(row.band[0])} .. {_fmt(row.band[1])}" if row.band is not None else ""
        lines.append(f"{row.paper:<5} {row.where[:26]:<26} {(row.quantity + unit)[:60]:<60} {_fmt(row.paper_value):>9} "
                     f"{_fmt(r.value):>9} {tol:>11} {short[row.evidence]:<8} {r.status:<9} {band}".rstrip())
    lines.append("")
    for paper in PAPERS:
        sub = [r for r in results if r.row.paper == paper]
        if sub:
            lines.append(f"paper {paper}: {len(sub)} rows: {_headline(sub)}")
    passing = counts(results)["prediction"]["PASS"]
    lines.append(f"all: {len(results)} rows: {_headline(results)}")
    lines.append(f"predictions that pass: {passing} (fits reproduce what they were fitted on: not evidence)")
    return "\n".join(lines)
