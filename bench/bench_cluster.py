"""Campaign throughput on each back-end: episodes per second and the overhead per chunk.

    PYTHONPATH=. .venv/bin/python bench/bench_cluster.py [--runs 10000] [--chunk 250]

Runs the HST roll step campaign (``config/mc_hst_roll_step.yaml``: 20 s episodes
with every dispersion on) with 1 and 2 local worker processes and with a
2-worker Dask ``LocalCluster`` on 127.0.0.1, and prints episodes per second.
The overhead per chunk is the wall time of a campaign of empty-ish chunks (one
0.01 s episode each) on the cluster divided by their number. The goal of issue
13: 10,000 HST roll episodes in under 2 minutes on a 2-core machine. Not a test.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from distributed import Client, LocalCluster

from attitude_sil.tuning.executor import DaskCluster, LocalProcesses
from attitude_sil.tuning.montecarlo import load_mc_spec, run_campaign

ROOT = Path(__file__).resolve().parent.parent


def _spec(tmp: Path, name: str, runs: int, chunk: int, duration: float | None = None):
    text = (ROOT / "config" / "mc_hst_roll_step.yaml").read_text()
    text = text.replace("scenario: ", f"scenario: {ROOT}/config/").replace(
        "output: results/mc_hst_roll_step", f"output: {tmp}/{name}").replace("chunk: 100", f"chunk: {chunk}")
    if duration is not None:
        text = text.replace("disturbance.models: [noise]", f"disturbance.models: [noise]\n  plant.duration: {duration}")
    path = tmp / f"{name}.yaml"
    path.write_text(text)
    return load_mc_spec(path, runs=runs)


def _time(spec, executor) -> float:
    t0 = time.perf_counter()
    result = run_campaign(spec, executor)
    assert not result.interrupted
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--chunk", type=int, default=250)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_cluster_"))
    try:
        with LocalProcesses(1) as ex:  # warm the compiled kernels' cache once
            _time(_spec(tmp, "warm", 4, 4), ex)
        rows = []
        for workers in (1, 2):
            with LocalProcesses(workers) as ex:
                wall = _time(_spec(tmp, f"local{workers}", args.runs, args.chunk), ex)
            rows.append((f"{workers} local worker process(es)", wall))
        with LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None,
                          processes=True) as cluster, Client(cluster) as client, DaskCluster(client=client) as ex:
            wall = _time(_spec(tmp, "dask", args.runs, args.chunk), ex)
            rows.append(("Dask LocalCluster, 2 workers on 127.0.0.1", wall))
            n = 200
            tiny = _spec(tmp, "overhead", n, 1, duration=0.01)
            overhead = _time(tiny, ex) / n * ex.workers  # per chunk and worker: what a chunk costs beyond its work
        print(f"HST roll step campaign, {args.runs} episodes of 20 s, chunks of {args.chunk}:")
        for label, wall in rows:
            print(f"  {label:<44} {wall:7.1f} s  {args.runs / wall:8.0f} episodes/s")
        print(f"  overhead per chunk on the cluster: {1e3 * overhead:.1f} ms (chunks of one 0.01 s episode)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
