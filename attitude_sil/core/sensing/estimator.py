"""What an attitude estimator is to the package: one unit, found through :mod:`attitude_sil.core.sensing.registry`.

An :class:`Estimator` names a filter, describes it, lists its own parameters
(declared on the ``estimator`` node as ``<name>.<param>``, beside the ones
every filter reads: ``initial_attitude_rpy_deg``, ``initial_attitude_sigma_deg``,
``initial_bias_sigma_deg_h``, ``bias_walk_deg_h_rt_h`` and the star tracker's
schedule) and builds it for P episodes. What it builds is a :class:`Filter`:
stepped once per control step k with the gyro reading of [t_(k-1), t_k] and
the star tracker's report due at k (or None), it returns the estimate at t_k.
The graph's ``estimator`` node, the stepwise driver (and so tune, montecarlo
and replay) build it the same way, so a filter flies alike in all of them.
docs/sensors.md shows how to write one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.sensing.mekf import Estimate
from attitude_sil.core.sensing.models import StarTrackerReport

__all__ = ["Estimator", "Filter", "Estimate"]


class Filter(Protocol):
    """An attitude filter on P episodes, as the drivers step it.

    Attributes
    ----------
    dropped : int
        Star tracker reports it did not take (older than it keeps).
    """

    dropped: int

    def step(self, k: int, omega_meas_B: np.ndarray, star_tracker: StarTrackerReport | None = None) -> Estimate:
        """Step ``k``: the gyro reading (P, 3) rad/s of [t_(k-1), t_k] and the report due at k (or None) in, the
        :class:`~attitude_sil.core.sensing.mekf.Estimate` at t_k out (``cov`` (P, 6, 6): attitude error and
        gyro bias, rad and rad/s)."""
        ...

    def set_star_tracker_variance(self, variance: np.ndarray) -> None:
        """The tracker's noise variance per body axis (3,) rad^2, as its messages carry it."""
        ...


@dataclass(frozen=True)
class Estimator:
    """A filter the package can fly.

    Attributes
    ----------
    name : str
        ``estimator.type`` selects it (the entry point's name, for a plugin).
    description : str
        One line for ``--help`` and docs/parameters.md.
    build : callable
        ``build(values, gyro_arw, star_tracker_sigma, dt, n_episodes, reach_steps) -> Filter``: ``values`` the
        ``estimator`` node's parameters (its own under ``<name>.``; ``initial_attitude_rpy_deg`` (3,) or
        (P, 3)), ``gyro_arw`` rad/s^0.5, ``star_tracker_sigma`` (3,) rad per body axis, ``dt`` s, and
        ``reach_steps``: how many steps back a report may be taken (older ones are dropped, counted in
        ``dropped``).
    params : tuple of ParamSpec
        Its own parameters, without the prefix.
    """

    name: str
    description: str
    build: Callable[..., Filter]
    params: tuple[ParamSpec, ...] = ()
