"""The sensing loop's cost: the numpy models, the compiled row kernels, and the compiled engine without sensing.

Issue 44 asks for the compiled engine with the sensors and the MEKF at >= 1/3 of the same engine without them,
per simulated second, at P >= 1,024. The kernels (``attitude_sil/core/sensing/kernels.py``) are not in the
engine's loop yet; this measures what they cost on their own, on a recorded truth, against the engine's own
time for the same episodes, so the ratio the fused loop would reach is known before the wiring:
engine / (engine + kernels). All three in one run; ratios only.

    python bench/bench_sensing.py [P] [DURATION_S]
"""

from __future__ import annotations

import sys
import time

import numpy as np
from numba import njit

from attitude_sil.core.sensing.kernels import (
    gyro_record,
    gyro_row,
    mekf_record,
    mekf_row,
    tracker_record,
    tracker_row,
)
from attitude_sil.core.sim.build import build_sensing
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario


@njit(cache=True)
def _kernels(q, omega, gp, gs, tp, ts, mp, ms, w, qm):
    for k in range(q.shape[1]):
        qk, wk = q[:, k], omega[:, k]
        for p in range(q.shape[0]):
            gyro_row(p, k, qk, wk, gp, gs, w)
            j, valid = tracker_row(p, k, qk, tp, ts, qm)
            mekf_row(p, k, w, j, valid, qm, mp, ms)


def main(P: int = 1024, duration: float = 20.0) -> None:
    scn = load_scenario(default_config_dir() / "hst_roll_step_sensors.yaml").with_values("scenario",
                                                                                        feedback="truth")
    seeds = np.arange(P)
    bare = load_scenario(default_config_dir() / "hst_roll_step.yaml")  # the same episode without sensing
    simulate(bare, P, duration=0.1, driver="compiled", threads=1)  # compiled, cached
    t0 = time.perf_counter()
    truth = simulate(bare, P, duration=duration, driver="compiled", threads=1)
    engine = time.perf_counter() - t0
    q, omega = np.ascontiguousarray(truth.q_BN), np.ascontiguousarray(truth.omega_BN_B)
    K1 = q.shape[1]

    ref = build_sensing(scn, P, seeds)
    t0 = time.perf_counter()
    for k in range(K1):
        s = ref.suite.sample(q[:, k], omega[:, k], k)
        ref.mekf.step(k, s.omega_meas_B, s.star_tracker)
    numpy_s = time.perf_counter() - t0

    def kernels() -> float:
        mine = build_sensing(scn, P, seeds)
        records = (*gyro_record(mine.suite.gyro), *tracker_record(mine.suite.star_tracker), *mekf_record(mine.mekf))
        t = time.perf_counter()
        _kernels(q, omega, *records, np.empty((P, 3)), np.empty((P, 4)))
        return time.perf_counter() - t

    kernels()  # compiled
    compiled_s = min(kernels() for _ in range(2))
    print(f"P = {P}, {duration:g} s of the HST roll step ({K1} steps), one thread, wall s:")
    print(f"  engine without sensing (compiled driver)  {engine:8.3f}")
    print(f"  sensing, numpy models (stepwise driver)   {numpy_s:8.3f}")
    print(f"  sensing, compiled kernels                 {compiled_s:8.3f}   ({numpy_s / compiled_s:.1f}x numpy)")
    print(f"  engine / (engine + kernels)               {engine / (engine + compiled_s):8.3f}   (target >= 0.333)")


if __name__ == "__main__":
    main(*(int(a) if i == 0 else float(a) for i, a in enumerate(sys.argv[1:])))
