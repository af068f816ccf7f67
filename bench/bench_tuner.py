"""Benchmark of the tuner (not a test).

Prints the wall time of the tuning example (docs/tuning.md) as a user runs it
(``attitude-sil tune config/tune_hst_pid_ga.yaml``: paper 000's 50 x 40 GA on
the HST roll step, each generation's best written as a bag, the final best
recorded through the node graph), the optimisation alone, the resident memory
of the tuning process after the first and the last generation (it must stay
flat), the peak memory of one 10,000-episode evaluation, and the graph-mode
throughput in episodes per second with one and two replicas.
"""

from __future__ import annotations

import os
import subprocess
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


_EVALUATE_10K = """
import resource, numpy as np
from attitude_sil.tuning.evaluate import evaluate
from attitude_sil.tuning.spec import load_spec
spec = load_spec("config/tune_hst_pid_ga.yaml")
evaluate(spec, np.tile([[48.894, 0.071, 106.046, 1.427]], (2, 1)))  # load the kernels
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
x = np.random.default_rng(0).uniform([10, 0, 50, 1], [100, 1, 200, 10], (10_000, 4))
ev = evaluate(spec, x)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(before / 1024, after / 1024, int(np.sum(ev.F[:, 0] < 1e6)))
"""


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        cli = [sys.executable, "-m", "attitude_sil.cli", "tune", "config/tune_hst_pid_ga.yaml", "--quiet",
               "--set", f"output={tmp}/example"]
        t0 = time.perf_counter()
        subprocess.run(cli, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
        bags = len(list(Path(tmp, "example", "bags").iterdir()))
        print(f"attitude-sil tune config/tune_hst_pid_ga.yaml (the tuning example, {bags} bags): "
              f"{time.perf_counter() - t0:.1f} s wall, process start included")
        out = subprocess.run([sys.executable, "-c", _EVALUATE_10K], cwd=ROOT, check=True, capture_output=True,
                             text=True).stdout.split()
        print(f"one evaluation of 10,000 candidates: peak resident memory {float(out[1]):.0f} MiB "
              f"({float(out[1]) - float(out[0]):.0f} MiB above the loaded process), {out[2]} scored")
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
