"""Whole episodes in compiled code: the batch engine's second driver of the step kernels.

The nodes call the compiled step kernels of :mod:`attitude_sil.core.plant.kernels`
once per message, through the objects of :mod:`attitude_sil.core.sim.models`; the
stepwise :func:`~attitude_sil.core.sim.engine.simulate` loop calls the same objects
once per step from Python. This module is the third caller: one compiled loop
over every step of a chunk of episodes, calling the *same* kernels with the
*same* arrays, so its numbers are the stepwise driver's to the last bit (and
the graph's, which the graph == batch tests check at 1e-9). Chunks of episodes
run on every core (a thread each: the compiled loop runs without the GIL); an
episode's arithmetic does not depend on which chunk or thread ran it, so the
result is identical for any number of threads.

What the compiled driver covers (the tuning and Monte Carlo workhorse: the HST
and CubeSat presets and their kind): the ``rigid_body`` plant, the
``reaction_wheels`` actuator, ``step`` guidance, the ``constant``, ``step``,
``noise``, ``gravity_gradient`` and ``aerodynamic`` disturbance models (or
none; the orbit's frames and gains computed per step beforehand), the
magnetorquers' loop (the field along the orbit computed beforehand; B-dot,
the dumping law and the rods in the loop), and every law of the registry,
built in or plugin: one per episode if asked, with
scheduled swaps and the controller bank's bumpless transfer, per-episode gains,
motor constants, wheel failures and sensor noise (the Monte Carlo's
dispersions; the same kernels as the nodes'). Noise torques are drawn from the
stepwise driver's streams by each chunk in its own thread
(:meth:`~attitude_sil.core.plant.disturbance.DisturbanceModel.noise_torque`).
:func:`attitude_sil.core.sim.engine.compiled_plan` says whether a run fits and, if
not, why; everything else (the flexible and pitch plants, the torque actuator,
LVLH guidance, the residual dipole, the sensing loop, a field epoch per
episode) runs in the stepwise driver, which handles every model.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np
from numba import njit

from attitude_sil.core.analysis.metric_rows import Sums
from attitude_sil.core.cache import numba_cache_in
from attitude_sil.core.control import registry
from attitude_sil.core.control.compiled import law_addresses
from attitude_sil.core.control.momentum import BDOT
from attitude_sil.core.plant.command_faults import CommandFault, no_command_fault
from attitude_sil.core.plant.kernels import WheelFailure, WheelParams
from attitude_sil.core.plant.wheels import no_failure
from attitude_sil.core.sim import batch_loop
from attitude_sil.core.trajectory import Trajectory

__all__ = ["COMPILED_DISTURBANCES", "SUMMARY_COLUMNS", "TRAJECTORY_FIELDS", "run_compiled", "loop_of"]

#: disturbance models the compiled driver evaluates in the loop
COMPILED_DISTURBANCES = frozenset({"constant", "step", "noise", "gravity_gradient", "aerodynamic"})


#: columns of the running sums the compiled driver keeps per episode (``sums``), in column order
SUMMARY_COLUMNS = tuple(c.name for c in Sums)


class SimArrays(NamedTuple):
    """The models' arrays and settings the compiled loop reads (:func:`attitude_sil.core.sim.batch_loop.chunk`)."""

    n_steps: int
    stride: int
    dt: float
    dt_ns: int
    substeps: int
    step_time: float
    q0: np.ndarray
    w0: np.ndarray
    x0: np.ndarray
    q_initial: np.ndarray
    q_final: np.ndarray
    omega_ref: np.ndarray
    inertia: np.ndarray
    inertia_inv: np.ndarray
    law0: np.ndarray  # (P,) each episode's law code
    law_torque: np.ndarray  # (n_laws,) whether the law of each code always commands a torque
    sw_k: np.ndarray  # swap steps, sorted
    sw_law: np.ndarray  # the law code each swap goes to
    command_torque: bool
    decay: float  # bumpless offset decay per step
    wheel: WheelParams
    failure: WheelFailure
    cmd_fault: CommandFault  # the controller output's gain and delay (command_faults), the rings per episode
    noisy: bool
    s_seeds: np.ndarray
    s_att: np.ndarray
    s_rate: np.ndarray
    tau_constant: np.ndarray
    tau_step: np.ndarray
    step_ns: int
    # the orbit's disturbances (disturbance.orbit_torques): each step's LVLH frame (K+1, 4), gravity-gradient
    # and drag gains (K+1,); the episodes' inertia (P, 3, 3), the centre of pressure (3,), the models on
    orbit_q_LN: np.ndarray
    orbit_gg: np.ndarray
    orbit_aero: np.ndarray
    dist_inertia: np.ndarray
    cp_offset: np.ndarray
    gg_on: bool
    aero_on: bool
    # the magnetorquers' loop (models.MagneticLoop), where ``mag``: the field in N at each step (K+1, 3), the
    # rods (axes, allocation (n, 3), limit), the law that is B-dot (-1: none) and its gain (P,), the dumping
    # law (on, gain (P,), target (P, 3)), or the law's torque made by the rods
    mag: bool
    b_N: np.ndarray
    rod_axes: np.ndarray
    rod_alloc: np.ndarray
    rod_max: float
    bdot_code: int
    k_bdot: np.ndarray
    dumping: bool
    k_dump: np.ndarray
    h_target: np.ndarray
    torque_rods: bool


class Outputs(NamedTuple):
    """The kept trajectory arrays (episode, kept step, .); one with no rows is not kept."""

    q: np.ndarray
    w: np.ndarray
    qr: np.ndarray
    h: np.ndarray
    u: np.ndarray
    tc: np.ndarray
    te: np.ndarray
    ws: np.ndarray
    wa: np.ndarray
    we: np.ndarray
    b: np.ndarray
    mc: np.ndarray
    mt: np.ndarray


class SumsSpec(NamedTuple):
    """The running sums: Euler axis, per-episode start and final values (rad), band, output (P, 13) or no rows."""

    axis: int
    y0: np.ndarray
    r: np.ndarray
    band: float
    out: np.ndarray


#: episodes per chunk, the block the plant's lanes span (at most; fewer where the threads would idle). Each
#: step of a chunk has a cost whatever its size (the stages' loop set-up, the law's call at its address), so a
#: larger block spreads it thinner while the block stays in L2; bench/README.md has the measured choice
CHUNK = 128


#: threads of the compiled driver: one per core (numba's count, which NUMBA_NUM_THREADS sets)
_POOL_SIZE = max(1, int(numba.config.NUMBA_NUM_THREADS))
_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(_POOL_SIZE, thread_name_prefix="attitude_sil-batch")
    return _POOL


def _c(a, shape=None) -> np.ndarray:
    # float64, broadcast to shape, contiguous and writable (a per-episode array broadcast to its own shape
    # stays a read-only view, and once compiled the loop again for that type: 2 min from an empty cache)
    a = np.asarray(a, dtype=float)
    return _writable(a if shape is None else np.broadcast_to(a, shape))


def _writable(a):
    # one numba signature per argument: a read-only or strided array (a broadcast view) would compile the
    # whole loop again for its type, so such arrays go in as contiguous writable copies
    if isinstance(a, np.ndarray) and not (a.flags.writeable and a.flags.c_contiguous):
        return np.array(a, order="C")
    return a


#: the Trajectory arrays the compiled driver can keep (``keep``), in its output order
TRAJECTORY_FIELDS = ("q_BN", "omega_BN_B", "q_RN", "h_wheels_B", "u_cmd", "tau_c_B", "tau_ext_B", "wheel_speed",
                     "wheel_angle", "wheel_effort", "magnetic_field_B", "dipole_cmd_B", "magnetic_torque_B")

#: the arrays only a run with the magnetorquers fills (None in any other)
MAGNETIC_FIELDS = ("magnetic_field_B", "dipole_cmd_B", "magnetic_torque_B")


def _kinds(ctrl, laws: np.ndarray, swaps: dict, kept_steps: np.ndarray) -> list[str]:
    """The command kind (``voltage``/``torque``) at each kept step; every episode's is the same."""
    first = ctrl.kind_of(str(laws[0]))
    if not swaps:
        return [first] * len(kept_steps)
    at = sorted(swaps)
    kinds = np.array([first] + [ctrl.kind_of(swaps[k]) for k in at], dtype=object)
    return kinds[np.searchsorted(np.array(at), kept_steps, side="right")].tolist()


def run_compiled(models: tuple, n_steps: int, dt: float, stride: int = 1, threads: int | None = None,
                 chunk: int = CHUNK, keep=TRAJECTORY_FIELDS, sums: tuple | None = None, swaps: dict | None = None,
                 laws=None, magnetic=None) -> tuple[Trajectory | None, np.ndarray | None]:
    """Run built models (fresh, as the stepwise driver gets them) in the compiled loop.

    Parameters
    ----------
    models : tuple
        ``(plant, wheels, dist, guide, ctrl)``: fresh models from the
        ``build_*`` functions of :mod:`attitude_sil.core.sim.build` (``Plant``,
        ``Wheels``, ``DisturbanceModel``, ``Guidance``, ``ControllerBank``)
        that :func:`attitude_sil.core.sim.engine.compiled_plan` accepted.
    n_steps : int
        K: states at k = 0..K.
    dt : float
        Control period, s.
    stride : int
        Keep every ``stride``-th step (k = 0, stride, 2 stride, ...).
    threads : int, optional
        Threads for the chunks (default: numba's, one per core). Any count
        gives the same numbers.
    chunk : int
        Episodes per chunk.
    keep : collection of str
        The :data:`TRAJECTORY_FIELDS` (and ``omega_RN_R``) to keep; the others
        are None. Empty keeps no trajectory.
    sums : tuple, optional
        ``(axis, y0 (P,), r (P,), band)``: keep the running sums of
        :data:`SUMMARY_COLUMNS` for a step on that Euler axis from ``y0`` to
        ``r`` (rad) with a settling band of ``band`` times the step.
    swaps : dict, optional
        ``{step k: controller_type}``: swaps before the command of step k,
        with the bank's bumpless transfer.
    laws : sequence of str, optional
        Each episode's ``controller_type`` (default ``ctrl.active`` for all);
        all must command the same kind (volts or N m).
    magnetic : MagneticLoop, optional
        The magnetorquers' loop (:class:`~attitude_sil.core.sim.models.MagneticLoop`, fresh; one field for
        every episode), run after the wheels' stage as the stepwise driver runs it.

    Returns
    -------
    (Trajectory or None, ndarray (P, len(SUMMARY_COLUMNS)) or None)
        The trajectory with ``t`` the kept steps' times (None if ``keep`` is
        empty), and the running sums (None without ``sums``).
    """
    unknown = set(keep) - set(TRAJECTORY_FIELDS) - {"omega_RN_R"}
    if unknown:
        raise ValueError(f"keep: unknown trajectory fields {sorted(unknown)}")
    plant, wheels, dist, _, ctrl = models
    P = plant.n_episodes
    swaps = dict(swaps or {})
    if laws is None:  # every episode on the bank's law: np.full, no lookup per episode
        laws = np.full(P, ctrl.active, dtype=object)
        law0, used = np.full(P, ctrl.codes[ctrl.active], dtype=np.int64), {ctrl.active}
    else:
        laws = np.asarray(laws, dtype=object)
        law0 = np.array([ctrl.codes[str(law)] for law in laws], dtype=np.int64)
        used = {str(x) for x in laws}
    sw = sorted(swaps.items())
    kept = n_steps // stride + 1
    out = _outputs(P, kept, wheels.assembly.n_wheels, [f for f in keep if magnetic is not None
                                                       or f not in MAGNETIC_FIELDS])
    spec = _sums_spec(sums, P)
    sim = _sim_arrays(models, n_steps, stride, dt, law0,
                      (np.array([k for k, _ in sw], dtype=np.int64),
                       np.array([ctrl.codes[law] for _, law in sw], dtype=np.int64)), magnetic)
    noise = (lambda lo, hi: dist.noise_torque(lo, hi, n_steps)) if "noise" in set(dist.models) else None
    run = _chunk_runner(ctrl, used | set(swaps.values()), sim,
                        Outputs(*(out[f] for f in TRAJECTORY_FIELDS)), spec, noise)
    _run_chunks(run, P, threads, chunk)
    trajectory = None
    if keep:
        got = {f: (a if f in keep and a.shape[0] else None) for f, a in out.items()}
        steps = np.arange(0, n_steps + 1, stride)
        omega_rn = np.ascontiguousarray(np.broadcast_to(sim.omega_ref[:, None, :], (P, kept, 3)))
        trajectory = Trajectory(t=steps * dt, kind=_kinds(ctrl, laws, swaps, steps),
                                omega_RN_R=omega_rn if "omega_RN_R" in keep else None, **got)
    return trajectory, (None if sums is None else spec.out)


def _run_chunks(run, P: int, threads: int | None, chunk: int) -> None:
    """``run(lo, hi)`` over chunks of the P episodes, on the pool's threads."""
    n_threads = _POOL_SIZE if threads is None else max(1, min(int(threads), _POOL_SIZE))
    size = max(1, min(int(chunk), -(-P // n_threads)))  # every thread gets work, chunks stay cache-sized
    b = np.unique(np.append(np.arange(0, P, size), P)).tolist()
    spans = list(zip(b[:-1], b[1:], strict=True))
    if n_threads > 1 and len(spans) > 1:  # the chunks on threads: the loop runs without the GIL
        list(_pool().map(lambda span: run(*span), spans))
    else:  # one thread: the chunks one after another, no thread hand-off
        for span in spans:
            run(*span)


def _outputs(P: int, kept: int, n_wheels: int, keep) -> dict[str, np.ndarray]:
    """The trajectory arrays, episode-major (episode, step, .) as the Trajectory holds them; no rows: not kept."""
    width = dict(q_BN=4, q_RN=4, wheel_speed=n_wheels, wheel_angle=n_wheels, wheel_effort=n_wheels)
    keep = set(keep)
    return {f: np.empty((P, kept, width.get(f, 3)) if f in keep else (0, 0, width.get(f, 3)))
            for f in TRAJECTORY_FIELDS}


def _sums_spec(sums: tuple | None, P: int) -> SumsSpec:
    """The running sums' settings and output (P, columns), or no rows without ``sums``."""
    if sums is None:
        return SumsSpec(0, np.zeros(P), np.zeros(P), 0.0, np.empty((0, len(SUMMARY_COLUMNS))))
    return SumsSpec(int(sums[0]), _c(sums[1], (P,)), _c(sums[2], (P,)), float(sums[3]),
                    np.empty((P, len(SUMMARY_COLUMNS))))


#: the compiled loop's noise argument of a run without disturbance noise (no rows)
_NO_NOISE = np.zeros((0, 0, 3))

#: the laws' compiled loops' addresses by law set, laws run and the records' field kinds (what fixes their numba
#: types once _rows has laid them out): typing the records is a large share of a one-episode call
_ADDRESSES: dict[tuple, np.ndarray] = {}


def _chunk_runner(ctrl, used: set[str], sim: SimArrays, outputs: Outputs, spec: SumsSpec, noise=None):
    """``run(lo, hi)``: the compiled loop on episodes lo..hi-1 of the bank's law set.

    ``noise(lo, hi)``: the disturbance noise torque of those episodes (``DisturbanceModel.noise_torque``),
    drawn in the chunk's thread, so its memory is the chunk's; None: no noise.
    """
    P = ctrl.n
    records = ctrl.records_for(used)

    def blocks(lo, hi):
        # each chunk gets its own rows of the law records and a fresh state, column-major (the episodes
        # contiguous: compiled.vector_<code>); at least two rows (_rows says why)
        pars = tuple(type(r)(*(_rows(f, lo, hi, P) for f in r)) for r in records)
        return pars, ctrl.new_states(max(hi - lo, 2), order="F")

    # the laws' compiled loops, compiled (or loaded) here, once, before the threads start
    codes = tuple(sorted(ctrl.names.index(n) for n in used))
    key = (ctrl.names, codes, tuple((type(r), tuple((f.dtype.str, f.ndim) if isinstance(f, np.ndarray) else type(f)
                                                    for f in r)) for r in records))
    if key not in _ADDRESSES:
        _ADDRESSES[key] = law_addresses(ctrl.dispatch, codes, *blocks(0, 1))
    at = _ADDRESSES[key]

    block, one = loop_of(ctrl.dispatch)

    def run(lo, hi):
        recs = tuple(zip(*blocks(lo, hi), strict=True))
        tau_noise = _NO_NOISE if noise is None else noise(lo, hi)
        (one if hi - lo == 1 else block)(lo, hi, sim, recs, tau_noise, lo, outputs, spec, at)

    return run


_LOOPS: dict[str, tuple] = {}


def loop_of(table) -> tuple:
    """:func:`~attitude_sil.core.sim.batch_loop.chunk` and ``chunk_one`` compiled for the law set of the
    dispatch table ``table``, cached in a folder of that set's own (:func:`~attitude_sil.core.cache.numba_cache_in`)."""
    if table.__name__ not in _LOOPS:
        with numba_cache_in(table.__name__):
            _LOOPS[table.__name__] = tuple(njit(**batch_loop.CHUNK_JIT)(f) for f in (batch_loop.chunk,
                                                                                    batch_loop.chunk_one))
    return _LOOPS[table.__name__]


def _rows(field, lo: int, hi: int, P: int):
    """Rows lo..hi-1 of a record field with a leading episode axis, as a writable column-major copy with at
    least two rows; a stand-in's field (no rows: a law no episode runs) as two rows of zeros; scalars as
    they are.

    numpy calls an array of one row or none C-contiguous, and numba would type
    it so: the loop would be compiled again for every chunk of one episode and
    every set of laws a run uses, and the laws' vector loops, compiled for
    column-major records, called with another layout. The loop reads rows
    0..hi-lo-1 only.
    """
    if not (isinstance(field, np.ndarray) and field.ndim >= 1):
        return field
    rows = field[lo:hi] if field.shape[0] == P else field[:0]
    if rows.shape[0] == 0:
        rows = np.zeros((2, *rows.shape[1:]), dtype=rows.dtype)
    elif rows.shape[0] == 1:
        rows = np.repeat(rows, 2, axis=0)
    return np.array(rows, order="F")


def _sim_arrays(models: tuple, n_steps: int, stride: int, dt: float, law0: np.ndarray,
                swaps: tuple[np.ndarray, np.ndarray], magnetic=None) -> SimArrays:
    """The models' arrays for the compiled loop, each contiguous and writable (one numba signature)."""
    plant, wheels, dist, guide, ctrl = models
    P = plant.n_episodes
    asm = wheels.assembly
    v = dist.v
    models = set(dist.models)
    failure = wheels.failure_arrays() if wheels.failure is not None else no_failure()
    sim = SimArrays(
        int(n_steps), int(stride), float(dt), int(round(dt * 1e9)), int(plant.substeps), float(guide.step_time),
        _c(plant.q0), _c(plant.omega0), np.ascontiguousarray(wheels.x), _c(guide.q_initial), _c(guide.q_final),
        _c(guide.omega, (P, 3)), _c(plant.inertia), _c(plant.inertia_inv), law0,
        np.array([registry.output_of(n) == "torque" for n in ctrl.names]),
        swaps[0], swaps[1],
        ctrl.command == "torque", float(ctrl.decay), WheelParams(*(_writable(a) for a in asm.params)),
        WheelFailure(*(_writable(a) for a in failure)),
        CommandFault(*(_writable(a) for a in (wheels.command_fault or no_command_fault(P)))), ctrl.noisy,
        ctrl.sensor_seeds,
        ctrl.sensor_att_std, ctrl.sensor_rate_std,
        _c(v["constant.torque"]) if "constant" in models else np.zeros(3),
        _c(v["step.torque"]) if "step" in models else np.zeros(3),
        int(round(v["step.time"] * 1e9)) if "step" in models else int(np.iinfo(np.int64).max),
        *_orbit_arrays(dist, n_steps), *_magnetic_arrays(magnetic, ctrl, P, n_steps))
    return SimArrays(*(_writable(a) for a in sim))


def _orbit_arrays(dist, n_steps: int) -> tuple:
    """The orbit disturbances' fields of SimArrays (no rows where neither model is on)."""
    inertia, _, _, cp, gg, aero = dist._orbit
    return (*dist.orbit_frames(n_steps), _c(inertia), _c(cp), bool(gg), bool(aero))


def _magnetic_arrays(magnetic, ctrl, P: int, n_steps: int) -> tuple:
    """The magnetorquers' fields of SimArrays (``mag`` False and no rows without them)."""
    if magnetic is None:
        none = np.zeros((0, 3))
        return False, none, none, none, 0.0, -1, np.zeros(P), False, np.zeros(P), np.zeros((P, 3)), False
    law, rods = magnetic.law, magnetic.rods
    b_N = magnetic.field.field_N(np.arange(n_steps + 1, dtype=np.int64) * magnetic.field.orbit.dt_ns)
    dump = law.dumping
    return (True, _c(b_N), _c(rods.axes), _c(rods.allocation), float(rods.max_dipole),
            int(ctrl.codes.get(BDOT, -1)), _c(law.bdot.gain, (P,)), dump is not None,
            _c(dump.gain if dump is not None else 0.0, (P,)), _c(dump.target_B if dump is not None else 0.0, (P, 3)),
            bool(law.torque_rods))
