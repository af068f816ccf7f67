"""Benchmark: graph real-time factor and batch-engine throughput (not a test).

Prints, for the HST roll step at 100 Hz control:
* the ROS graph's real-time factor in one process and in one process per node,
  recording on;
* the batch engine's simulated seconds per wall second at P = 1, 50 and 500.

Figures from one run are comparable with each other (the machine is shared);
quote ratios. Run with ``make bench``.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))

from attitude_sil.core.controllers import CONTROLLER_TYPES  # noqa: E402
from attitude_sil.core.engine import build_controller, simulate  # noqa: E402
from attitude_sil.core.quaternion import quat_from_euler  # noqa: E402
from attitude_sil.core.scenario import load_scenario  # noqa: E402
from attitude_sil.graph.session import run_graph  # noqa: E402


def main() -> None:
    scn = load_scenario(ROOT / "config" / "hst_roll_step.yaml")
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
    for p in (1, 50, 500):
        reps = 5 if p < 500 else 2
        best = float("inf")
        for _ in range(reps):
            t0 = time.perf_counter()
            simulate(scn, p)
            best = min(best, time.perf_counter() - t0)
        print(f"batch engine, P = {p:<4}            {p * duration / best:10.0f} simulated s per wall s "
              f"({best * 1e3:.0f} ms per call, best of {reps})")
    costs = {p: controller_cost(scn, p) for p in (1, 50)}
    print("controller cost, us per step per episode (ratio to pid at the same P):")
    for kind in CONTROLLER_TYPES:
        cells = "   ".join(f"P={p:<3} {costs[p][kind]:7.2f} ({costs[p][kind] / costs[p]['pid']:4.1f}x)" for p in costs)
        print(f"  {kind:<10} {cells}")


def controller_cost(scn, n_episodes: int, steps: int = 2000) -> dict[str, float]:
    """Microseconds per step per episode of each law's compute, on the same inputs."""
    rng = np.random.default_rng(0)
    q_BN = quat_from_euler(np.radians(rng.uniform(-2, 2, (n_episodes, 3))))
    w = rng.normal(0, 0.01, (n_episodes, 3))
    q_RN = np.tile([0.0, 0.0, 0.0, 1.0], (n_episodes, 1))
    w_d = np.zeros((n_episodes, 3))
    out = {}
    for kind in CONTROLLER_TYPES:
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
