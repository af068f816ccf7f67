"""Seeded noise streams of the sensor models: a draw is a pure function of (seed, stream, step, channel).

Built on the counter-based generator of :func:`attitude_sil.core.plant.kernels.normal_draw`, so a node that
knows only its step draws what the batch engine drew for the same episode, whatever the batch, thread or
process. Each error source of a sensor has its own stream number, so switching one off leaves the others'
numbers as they were.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from attitude_sil.core.plant.kernels import normal_draw

__all__ = ["normals", "STREAMS", "STREAM_SHIFT"]

#: one stream per error source (a contract: changing a number changes every seeded run)
STREAMS = {"gyro_white": 1, "gyro_markov": 2, "gyro_walk": 3, "gyro_markov_init": 4, "star_tracker": 5,
           "magnetometer": 6}

#: the stream's offset in the generator's seed space: seeds below 2**40 never meet another stream's
STREAM_SHIFT = 1 << 40


@njit(cache=True)
def _normals(seeds, k, stream, n):
    out = np.empty((seeds.shape[0], n))
    for p in range(seeds.shape[0]):
        s = seeds[p] + stream * STREAM_SHIFT
        for i in range(n):
            out[p, i] = normal_draw(s, k, i)
    return out


def normals(seeds: np.ndarray, k: int, stream: str, n: int = 3) -> np.ndarray:
    """Standard normal numbers (P, n) of step ``k`` on ``stream`` for each episode's seed (P,) int64, n <= 8."""
    return _normals(np.asarray(seeds, dtype=np.int64), int(k), STREAMS[stream], int(n))
