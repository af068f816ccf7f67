"""Benchmark: graph real-time factor and batch-engine throughput against its ceiling (not a test).

Prints, for the HST roll step at 100 Hz control:
* the ROS graph's real-time factor in one process and in one process per node,
  recording on;
* the batch engine's simulated seconds per wall second at P = 1, 50, 500 and
  5,000 on one core and on both, each as a ratio of the ceiling measured in
  the same run: a hand-fused compiled loop of the same episode
  (``fused_reference.py``, checked to give the engine's numbers first), with
  the engine keeping the same arrays (equal work), its whole trajectory, and
  only the running sums of the metrics; and the stepwise driver (the first
  engine) where it is not too slow;
* the cost of each control law per step and episode;
* issue 25's table, ``simd``: the engine's summaries (the plant with the
  episodes as the vector axis) at P = 1, 64, 1,024 and 16,384 on one core and
  on both, against the fused loop, a hand-written lanes reference
  (``soa_reference.py``, checked equal to the fused loop) and the physical
  limit (``limits.py``); then the tuning example's evaluations and a
  10,000-run Monte Carlo campaign, locally and on a Dask cluster.
  ``python bench/bench_engine.py simd`` runs it alone, after ``laws``;
* ``laws``: each registered law's step in the controller bank's row loop
  against its loop on the episode axis (``vector_<code>``), and how much of it
  LLVM packed;
* ``jax``: the same episode in JAX on the CPU (``jax_reference.py``, run by
  ``$JAX_PYTHON``; not a dependency), the measurement behind the choice of tool.

Figures from one run are comparable with each other (the machine is shared);
quote ratios. Run with ``make bench``.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))

from bench_cluster import _spec as mc_spec  # noqa: E402
from fused_reference import fused_parallel, fused_serial, fused_setup  # noqa: E402
from limits import count_step_ops, peak_fma_flops  # noqa: E402
from numba import config, njit, set_num_threads  # noqa: E402
from soa_reference import LANES, lanes_args, lanes_run  # noqa: E402

from attitude_sil.core.control.registry import names as law_names  # noqa: E402
from attitude_sil.core.plant.quaternion import quat_from_euler  # noqa: E402
from attitude_sil.core.sim.build import build_controller  # noqa: E402
from attitude_sil.core.sim.engine import simulate, simulate_summary  # noqa: E402
from attitude_sil.core.sim.scenario import load_scenario  # noqa: E402
from attitude_sil.graph.session import run_graph  # noqa: E402
from attitude_sil.tuning.evaluate import evaluate  # noqa: E402
from attitude_sil.tuning.executor import LocalProcesses  # noqa: E402
from attitude_sil.tuning.montecarlo import run_campaign  # noqa: E402
from attitude_sil.tuning.spec import load_spec  # noqa: E402


def main() -> None:
    scn = load_scenario(ROOT / "config" / "hst_roll_step.yaml")
    if sys.argv[1:] == ["laws"]:
        law_lanes(scn)
        return
    if sys.argv[1:] == ["jax"]:
        jax_table(scn)
        return
    if sys.argv[1:] == ["simd"]:
        law_lanes(scn)
        simd(scn)
        targets(scn)
        return
    duration = scn.duration
    simulate(scn, 2, duration=0.1)  # compile / load the kernels once
    print(f"HST roll step, {duration:g} s episodes, control period {scn.dt * 1e3:g} ms")
    with tempfile.TemporaryDirectory() as tmp:
        for label, processes in (("graph, one process", False), ("graph, one process per node", True)):
            result = run_graph(scn, record_dir=Path(tmp) / label.replace(" ", "_").replace(",", ""),
                               processes=processes, progress=False)
            m = result.metrics
            print(f"{label:<32} real-time factor {m['real_time_factor']:7.1f}x  (wall {m['wall_time_s']:.2f} s, "
                  f"recording on)")
    ceiling(scn)
    newly_compiled(scn)
    costs = {p: controller_cost(scn, p) for p in (1, 50)}
    law_lanes(scn)
    simd(scn)
    targets(scn)
    print("controller cost, us per step per episode (ratio to pid at the same P):")
    for kind in law_names():
        cells = "   ".join(f"P={p:<3} {costs[p][kind]:7.2f} ({costs[p][kind] / costs[p]['pid']:4.1f}x)" for p in costs)
        print(f"  {kind:<10} {cells}")


def _best(fn, reps: int) -> float:
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


#: what the fused loop keeps per step: the engine is asked for the same arrays for the equal-work column
FUSED_KEEPS = ("q_BN", "omega_BN_B", "u_cmd", "tau_c_B")


def newly_compiled(scn, n_episodes: int = 50) -> None:
    """Runs that took the stepwise driver until the compiled loop ran them: both drivers, same run."""
    noisy = scn.with_values("disturbance", models=["noise"])
    cases = (("geometric law", scn, dict(controller="geometric")),
             ("swaps pid -> ga_flc -> fuzzy_pid", scn, dict(schedule=[(500, "ga_flc"), (1000, "fuzzy_pid")])),
             ("a law per episode", scn, dict(controller=["pid", "fuzzy_pid", "ga_flc"] * (n_episodes // 3) + ["pid"]
                                             * (n_episodes % 3))),
             ("disturbance noise", noisy, dict()))
    print(f"runs the compiled loop took over (P = {n_episodes}, both cores), simulated s per wall s:")
    for label, s, kw in cases:
        compiled = _best(lambda s=s, kw=kw: simulate(s, n_episodes, **kw), 3)
        if isinstance(kw.get("controller"), list):  # the stepwise driver runs one law per batch: one per type
            stepwise = sum(_best(lambda s=s, law=law: simulate(s, n_episodes, controller=law, driver="stepwise"), 1)
                           for law in set(kw["controller"]))
        else:
            stepwise = _best(lambda s=s, kw=kw: simulate(s, n_episodes, driver="stepwise", **kw), 1)
        work = n_episodes * scn.duration
        print(f"  {label:<34} compiled {work / compiled:9,.0f}   stepwise {work / stepwise:7,.0f}   "
              f"({stepwise / compiled:5.1f}x)")


def ceiling(scn) -> None:
    """Engine throughput as a ratio of the hand-fused loop, on one core and on two.

    Columns: the fused ceiling; the engine keeping the same four arrays the
    fused loop keeps (equal work); the engine keeping its whole trajectory (all
    ten arrays, the default); the engine keeping only the running sums of the
    metrics (``simulate_summary``, what tuning and Monte Carlo evaluations use).
    The fused loop writes into arrays allocated once outside the timing; the
    engine allocates its results on every call, as a caller gets them.
    """
    duration = scn.duration
    kp = np.linspace(30.0, 60.0, 3 * 50).reshape(50, 3)
    ref = fused_setup(scn, 50, kp)
    fused_serial(*ref[0])
    tr = simulate(scn, 50, controller_params={"pid.kp": kp})
    diff = max(np.max(np.abs(a - b)) for a, b in zip(ref[1], (tr.q_BN, tr.omega_BN_B, tr.u_cmd, tr.tau_c_B),
                                                      strict=True))
    print(f"hand-fused reference == engine: max |difference| {diff:.1e} over 50 designs (equal work)")
    print("simulated s per wall s, and as a ratio of the fused ceiling:")
    print(f"{'P':>6} {'cores':>5} {'fused ceiling':>14} {'engine, same 4':>20} {'engine, all 10':>20} "
          f"{'engine, sums only':>20} {'stepwise (v1)':>14}")
    for p in (1, 50, 500, 5000):
        stride = 10 if p == 5000 else 1  # 5,000 whole trajectories would not fit: both keep every 10th step
        reps = 7 if p <= 50 else 2
        args, _ = fused_setup(scn, p, stride=stride)
        for cores, fused, threads in ((1, fused_serial, 1), (2, fused_parallel, 2)):
            fused(*args)  # compile / load
            f = _best(lambda fused=fused, args=args: fused(*args), reps)
            same = _best(lambda p=p, stride=stride, threads=threads: simulate(
                scn, p, stride=stride, threads=threads, keep=FUSED_KEEPS), reps)
            whole = _best(lambda p=p, stride=stride, threads=threads: simulate(scn, p, stride=stride, threads=threads),
                          reps)
            sums = _best(lambda p=p, threads=threads: simulate_summary(scn, p, threads=threads), reps)
            step = ""
            if cores == 1 and p <= 50:
                w = _best(lambda p=p: simulate(scn, p, driver="stepwise"), 2)
                step = f"{p * duration / w:14,.0f}"
            cells = "".join(f"{p * duration / e:13,.0f} ({f / e:4.2f})" for e in (same, whole, sums))
            print(f"{p:>6} {cores:>5} {p * duration / f:14,.0f}{cells} {step:>14}")


def simd(scn) -> None:
    """Issue 25's table: the engine with the episodes as the vector axis against the fused scalar loop, the
    lanes reference and the machine's physical limit, at P = 1 ... 16,384 on one core and on both.

    The fused loop and the lanes reference keep only the final state (the fused loop: its first and last
    step), so what is timed is the step; the engine column is ``simulate_summary`` (running sums of every
    metric, what tuning and Monte Carlo use), which does more than either.
    """
    duration = scn.duration
    args, out = fused_setup(scn, 256, np.linspace(30.0, 60.0, 3 * 256).reshape(256, 3))
    fused_serial(*args)
    la = lanes_args(args)
    lanes_run(*la)
    diff = max(np.max(np.abs(out[0][:, -1] - la[-2])), np.max(np.abs(out[1][:, -1] - la[-1])))
    print(f"lanes reference ({LANES} lanes a block) == fused loop: max |final state difference| {diff:.1e} "
          "over 256 designs")
    ops = count_step_ops(scn)
    steps_per_s = 1.0 / scn.dt
    print(f"one episode step (PID, 4 wheels, RK4 body), counted from the kernels: {ops['flops']} flops "
          f"(add {ops['add']}, mul {ops['mul']}, div {ops['div']}, sqrt {ops['sqrt']}) and {ops['other']} "
          "other operations (negation, abs, comparisons)")
    peak = {cores: peak_fma_flops(cores) for cores in (1, 2)}
    limit = {c: peak[c] / (ops["flops"] * steps_per_s) for c in peak}
    for c in peak:
        print(f"measured peak FMA rate, {c} core(s): {peak[c] / 1e9:.1f} Gflop/s -> physical limit "
              f"{limit[c]:,.0f} simulated s per wall s")
    print("simulated s per wall s (ratio to the fused loop on the same cores; share of the physical limit):")
    print(f"{'P':>6} {'cores':>5} {'fused loop':>12} {'lanes reference':>22} {'engine, sums':>26}")
    for p in (1, 64, 1024, 16384):
        reps = 5 if p <= 64 else 2
        args, _ = fused_setup(scn, p, stride=scn.steps())  # keeps step 0 and the last: the step is what is timed
        la = lanes_args(args)
        for cores, fused in ((1, fused_serial), (2, fused_parallel)):
            set_num_threads(cores)
            fused(*args)
            f = _best(lambda fused=fused, args=args: fused(*args), reps)
            lanes = _best(lambda la=la: lanes_run(*la), reps)
            eng = _best(lambda p=p, cores=cores: simulate_summary(scn, p, threads=cores), reps)
            cells = "".join(f"{p * duration / t:11,.0f} ({f / t:4.2f}; {p * duration / t / limit[cores]:5.1%})"
                            for t in (lanes, eng))
            print(f"{p:>6} {cores:>5} {p * duration / f:12,.0f}{cells}")
    set_num_threads(config.NUMBA_NUM_THREADS)  # numba's default again for what follows


#: the shared arrays of the fused loop's arguments, by name, for jax_reference.py
_FUSED_NAMES = ("n_steps", "dt", "q0", "q_r", "inertia", "inertia_inv", "kp", "ki", "kd", "nf", "af", "u_max",
                "alloc", "axes", "phi_T", "gamma", "j_m", "k_b", "headroom", "speed_max", "v_max")


def jax_table(scn) -> None:
    """The tool question of issue 25, measured: the same episode in JAX on the CPU (``jax_reference.py``, run
    by ``$JAX_PYTHON``, an interpreter with ``jax[cpu]``; JAX is not a dependency) against the fused scalar
    loop and the engine, on one core (``taskset -c 0``) and on both, after checking its final states."""
    import shutil
    import subprocess

    python = os.environ.get("JAX_PYTHON", sys.executable)
    probe = subprocess.run([python, "-c", "import jax"], capture_output=True, text=True)
    if probe.returncode != 0:
        print(f"jax: not importable by {python}; install it beside the package (pip install 'jax[cpu]') or set "
              "JAX_PYTHON to an interpreter that has it")
        return
    duration = scn.duration
    print("simulated s per wall s, the HST roll step with the PID (ratio to the fused loop on the same cores):")
    print(f"{'P':>6} {'cores':>5} {'fused loop':>12} {'engine, sums':>20} {'JAX (XLA CPU)':>20} {'JAX compile':>12}")
    with tempfile.TemporaryDirectory() as tmp:
        for p in (64, 1024, 16384):
            args, out = fused_setup(scn, p, stride=scn.steps())
            reps = 3 if p <= 1024 else 2
            arrays = dict(zip(_FUSED_NAMES, args[:len(_FUSED_NAMES)], strict=True))
            np.savez(Path(tmp) / "in.npz", reps=reps, **arrays)
            for cores, fused in ((1, fused_serial), (2, fused_parallel)):
                set_num_threads(cores)
                fused(*args)
                f = _best(lambda fused=fused, args=args: fused(*args), reps)
                eng = _best(lambda p=p, cores=cores: simulate_summary(scn, p, threads=cores), reps)
                pin = ["taskset", "-c", "0"] if cores == 1 and shutil.which("taskset") else []
                run = subprocess.run([*pin, python, str(ROOT / "bench" / "jax_reference.py"), str(Path(tmp) / "in.npz"),
                                      str(Path(tmp) / "out.npz")], capture_output=True, text=True)
                if run.returncode != 0:
                    print("jax_reference.py failed: " + (run.stderr.strip().splitlines() or ["no message"])[-1])
                    set_num_threads(config.NUMBA_NUM_THREADS)
                    return
                res = np.load(Path(tmp) / "out.npz")
                diff = max(np.max(np.abs(res["q"] - out[0][:, -1])), np.max(np.abs(res["w"] - out[1][:, -1])))
                t_jax = float(res["run_s"])
                cells = "".join(f"{p * duration / t:11,.0f} ({f / t:5.2f})" for t in (eng, t_jax))
                print(f"{p:>6} {cores:>5} {p * duration / f:12,.0f}   {cells}   {float(res['compile_s']):9.1f} s"
                      f"   |final state - fused| {diff:.1e}")
    set_num_threads(config.NUMBA_NUM_THREADS)


def law_lanes(scn, n_episodes: int = 64, steps: int = 2000) -> dict[str, tuple[float, float, float]]:
    """Each law on the episode axis: ns per episode and step of its ``vector_<code>`` loop (the batch
    engine's one-law case, column-major arrays, on a block of the engine's 64 episodes) against the same step
    in the controller bank's row loop
    (row-major, a law test per row), on the same inputs; and how much of the vector loop's arithmetic LLVM
    packed (ymm or zmm instructions among the double-precision ones). A law whose branches LLVM cannot turn into
    selects stays scalar: its speed-up near 1 and its packed share near 0 are what it loses to them.

    Returns each law's (row loop ns, vector loop ns, packed share), as printed."""
    import re

    from attitude_sil.core.control.registry import dispatch_module
    rng = np.random.default_rng(0)
    q = quat_from_euler(np.radians(rng.uniform(-20, 20, (n_episodes, 3))))
    w = rng.normal(0, 0.01, (n_episodes, 3))
    q_r = np.tile([0.0, 0.0, 0.0, 1.0], (n_episodes, 1))
    w_r = np.zeros((n_episodes, 3))
    d = dispatch_module()
    fortran = [np.asfortranarray(a) for a in (q, w, q_r, w_r)]
    print(f"each law on {n_episodes} episodes, ns per episode step (vector loop: the engine's one-law case):")
    print(f"{'law':<12} {'row loop':>9} {'vector loop':>12} {'speed-up':>9} {'packed share':>13}")
    table = {}
    for kind in law_names():
        bank = build_controller(scn, n_episodes)
        code = bank.codes[kind]
        rec = bank.record(kind)
        par = type(rec)(*(np.asfortranarray(f) if isinstance(f, np.ndarray) else f for f in rec))
        st = bank.new_states(n_episodes, order="F")[code]
        u = np.zeros((n_episodes, 3), order="F")
        vec = getattr(d, f"vector_{code}")
        vec(*fortran, par, st, scn.dt, u)
        law = np.full(n_episodes, code, dtype=np.int64)
        u_row, offset, has_off = np.zeros((n_episodes, 3)), np.zeros((n_episodes, 3)), np.zeros(n_episodes, bool)
        row_args = (law, q, w, q_r, w_r, rec, bank.new_states(n_episodes)[code], scn.dt, u_row, offset, has_off, 0.0)
        vec_args = (*fortran, par, st, scn.dt, u)
        rows = getattr(d, f"rows_{code}")
        t_row = _best(lambda r=rows, a=row_args: _repeat_stage(r, steps, *a), 3) / steps / n_episodes * 1e9
        t_vec = _best(lambda f=vec, a=vec_args: _repeat_vector(f, steps, *a), 3) / steps / n_episodes * 1e9
        asm = _vector_asm(d, code, (*fortran, par, st, scn.dt, u))
        packed = len(re.findall(r"\bv\w+pd\s+%[yz]mm", asm))
        scalar = len(re.findall(r"\bv\w+sd\s", asm))
        table[kind] = (t_row, t_vec, packed / max(1, packed + scalar))
        print(f"{kind:<12} {t_row:9.1f} {t_vec:12.1f} {t_row / t_vec:9.2f} {table[kind][2]:13.0%}")
    return table


@njit
def _repeat_stage(rows, reps, law, q, w, q_r, w_r, par, st, dt, u, offset, has_off, decay):
    # the bank's row loop (``rows_<code>``) called reps times from compiled code (a call from Python costs
    # more than the loop)
    for _ in range(reps):
        rows(law, q, w, q_r, w_r, par, st, dt, u, offset, has_off, decay)


@njit
def _repeat_vector(vector, reps, q, w, q_r, w_r, par, st, dt, u):
    for _ in range(reps):
        vector(q, w, q_r, w_r, par, st, dt, u)


def _vector_asm(d, code: int, args: tuple) -> str:
    """The assembly of law ``code``'s vector loop, compiled afresh (numba shows none for what it loaded
    from its cache)."""
    from numba import njit

    from attitude_sil.core.control.compiled import LanesCompiler
    fresh = njit(error_model="numpy", pipeline_class=LanesCompiler)(getattr(d, f"vector_{code}").py_func)
    fresh(*args)
    return fresh.inspect_asm(fresh.signatures[0])


def targets(scn) -> None:
    """Issue 25's wall times: the README's tuning example's evaluations and a 10,000-run Monte Carlo
    campaign of the HST roll step (summaries only), locally and on a Dask cluster, with the same numbers."""
    spec = load_spec(ROOT / "config" / "tune_hst_pid_ga.yaml")
    rng = np.random.default_rng(0)
    lo = np.array([g.low for g in spec.genome for _ in range(g.count)])
    hi = np.array([g.high for g in spec.genome for _ in range(g.count)])
    evaluate(spec, rng.uniform(lo, hi, (2, lo.size)))  # load the kernels
    t0 = time.perf_counter()
    for _ in range(40):  # 40 generations of 50: the GA's evaluations (pymoo's own work not counted)
        evaluate(spec, rng.uniform(lo, hi, (50, lo.size)))
    print(f"tuning example (config/tune_hst_pid_ga.yaml), 40 x 50 evaluations: {time.perf_counter() - t0:.2f} s")
    with tempfile.TemporaryDirectory() as tmp:
        tables = {}
        with LocalProcesses(1) as ex:
            run_campaign(mc_spec(Path(tmp), "warm", 4, 4), ex)
        for label, make in (("2 local worker processes", lambda: LocalProcesses(2)),
                            ("Dask LocalCluster, 2 workers", _dask_executor)):
            with make() as ex:
                spec = mc_spec(Path(tmp), label.split()[0], 10_000, 2_500)
                t0 = time.perf_counter()
                tables[label] = run_campaign(spec, ex).table
                print(f"Monte Carlo, 10,000 runs of config/mc_hst_roll_step.yaml (summaries), {label}: "
                      f"{time.perf_counter() - t0:.1f} s")
        a, b = tables.values()
        same = all(np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f") for k in a)
        print(f"  the two campaigns' tables are {'identical' if same else 'DIFFERENT'} ({len(a)} columns)")


@contextlib.contextmanager
def _dask_executor():
    from distributed import Client, LocalCluster

    from attitude_sil.tuning.executor import DaskCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None,
                      processes=True) as cluster, Client(cluster) as client, DaskCluster(client=client) as ex:
        yield ex


def controller_cost(scn, n_episodes: int, steps: int = 2000) -> dict[str, float]:
    """Microseconds per step per episode of each law's compute, on the same inputs."""
    rng = np.random.default_rng(0)
    q_BN = quat_from_euler(np.radians(rng.uniform(-2, 2, (n_episodes, 3))))
    w = rng.normal(0, 0.01, (n_episodes, 3))
    q_RN = np.tile([0.0, 0.0, 0.0, 1.0], (n_episodes, 1))
    w_d = np.zeros((n_episodes, 3))
    out = {}
    for kind in law_names():
        bank = build_controller(scn, n_episodes)
        bank.active = kind
        bank.compute(q_BN, w, q_RN, w_d)  # compile / warm
        t0 = time.perf_counter()
        for _ in range(steps):
            bank.compute(q_BN, w, q_RN, w_d)
        out[kind] = (time.perf_counter() - t0) / steps / n_episodes * 1e6
    return out


if __name__ == "__main__":
    main()
