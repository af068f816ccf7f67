"""``mekf``: the multiplicative EKF on attitude and gyro bias, the package's first estimator (:mod:`..mekf`)."""

from __future__ import annotations

import numpy as np

from attitude_sil.core.sensing.estimator import Estimator
from attitude_sil.core.sensing.mekf import Mekf, MekfSettings


def build(values: dict, gyro_arw: float, star_tracker_sigma: np.ndarray, dt: float, n_episodes: int,
          reach_steps: int) -> Mekf:
    """The MEKF of the ``estimator`` parameters ``values`` for ``n_episodes`` (:class:`Estimator`'s ``build``)."""
    return Mekf(MekfSettings.from_values(values, gyro_arw, star_tracker_sigma), dt, n_episodes, reach_steps)


ESTIMATOR = Estimator(
    name="mekf",
    description="multiplicative EKF on attitude and gyro bias (Lefferts, Markley and Shuster 1982)",
    build=build,
)
