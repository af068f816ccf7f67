"""Benchmark of the tuner (not a test).

Prints the wall time of paper 000's 50 x 40 GA on the HST roll step (20 s
episodes, 100 Hz, batch mode, both cores), the resident memory of the tuning
process after the first and the last generation (it must stay flat), and the
graph-mode throughput in episodes per second with one and two replicas.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))

import numpy as np  # noqa: E402

from attitude_sil.graph.evaluator import GraphEvaluator  # noqa: E402
from attitude_sil.tuning.optimize import run_tuning  # noqa: E402
from attitude_sil.tuning.spec import load_spec  # noqa: E402


def rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        spec = load_spec(ROOT / "config" / "tune_hst_pid_ga.yaml")
        spec.output = Path(tmp) / "ga"
        memory = []
        t0 = time.perf_counter()
        result = run_tuning(spec, progress=lambda s: memory.append(rss_mib()))
        wall = time.perf_counter() - t0
        print(f"GA 50 x 40 on the HST roll step (batch, {spec.evaluation['workers']} workers): {wall:.1f} s wall, "
              f"{result.evaluations} episodes, {result.evaluations * 20 / wall:,.0f} simulated s per wall s, "
              f"best J {result.best_cost[0]:.3g}")
        print(f"tuner resident memory: {memory[0]:.0f} MiB after generation 1, {memory[-1]:.0f} MiB after "
              f"generation {len(memory)}")
        spec = load_spec(ROOT / "config" / "tune_hst_pid_ga.yaml")
        spec.output = Path(tmp) / "graph"
        x = np.tile([[48.894, 0.071, 106.046, 1.427]], (8, 1)) * np.linspace(0.8, 1.2, 8)[:, None]
        for replicas in (1, 2):
            with GraphEvaluator(spec, replicas=replicas) as graph:
                graph(x[:replicas])  # warm up: discovery, kernels
                t0 = time.perf_counter()
                graph(x)
                wall = time.perf_counter() - t0
            print(f"graph mode, {replicas} replica(s): {len(x) / wall:.2f} episodes per wall s "
                  f"(20 s episodes, {len(x)} candidates)")


if __name__ == "__main__":
    main()
