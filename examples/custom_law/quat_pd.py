"""``quat_pd``: a quaternion-error PD law, the example of a control law in a package of its own.

This file is the whole law. Installed with ``pip install ./examples/custom_law``,
it registers through the entry point ``attitude_sil.laws`` (see
``pyproject.toml``) and is then a ``controller_type`` like the built-in ones:
``attitude-sil run ... --controller quat_pd``, ``--swap 5:quat_pd``,
``attitude-sil param set controller controller_type quat_pd``, the batch
engine, ``tune``, ``montecarlo`` and ``replay --verify-controller``. The
guide is docs/writing-a-law.md of attitude_sil.

The law, per body axis ``i`` (volts on wheel presets, N m on torque presets)::

    u_i = kp_i e_i + kd_i (ν_i - ω_i),    e = -vec(q_BR),  ν = Q^T ω_d

with ``q_BR = q_RN* ⊗ q_BN`` (scalar part made non-negative, the short way
round) and ``ν`` the reference rate in B; saturated at ``output_limit``. It
has no state: a swap to it starts from the old law's last command through the
package's generic decaying offset (``bumpless_time_constant``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.control.kernels import error_quat_row, reference_rate_row
from attitude_sil.core.control.law import Law, lanes
from attitude_sil.core.paramspec import double_array


class Params(NamedTuple):
    """The law's parameter record: one row per episode."""

    kp: np.ndarray  # (n, 3) V per unit quaternion error
    kd: np.ndarray  # (n, 3) V s/rad
    u_max: float  # V (the controller's output_limit)


@njit(cache=True, inline="always")
def step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u):
    """Row ``p`` of the command: PD on the quaternion error and the rate error, saturated."""
    x, y, z, w = error_quat_row(q_BN, q_RN, p)
    nu = reference_rate_row(x, y, z, w, omega_RN_R, p)
    e = (-x, -y, -z)
    for i in range(3):
        raw = par.kp[p, i] * e[i] + par.kd[p, i] * (nu[i] - omega_BN_B[p, i])
        u[p, i] = min(max(raw, -par.u_max), par.u_max)


def record(values, n: int, dt: float) -> Params:
    """The record for n episodes from the controller's values (short names for this law's own)."""
    return Params(lanes(values["kp"], n), lanes(values["kd"], n), float(values["output_limit"]))


LAW = Law(
    name="quat_pd",
    summary="quaternion-error PD with rate feedback (example plugin, examples/custom_law)",
    params=(
        double_array("kp", [50.0] * 3, "proportional gain per body axis, V per unit quaternion error",
                     lengths=(3,), min=0.0, runtime=True),
        double_array("kd", [50.0] * 3, "rate gain per body axis, V s/rad", lengths=(3,), min=0.0, runtime=True),
    ),
    state={},
    record=record,
    step=step,
)
