"""``pid``: per-axis PID on the quaternion error vector (paper 000 eq. 19, second line).

``u = Kp e + Ki ∫e dt + Kd N s / (s + N) e`` per body axis, volts (or N m on a
torque preset).

Discretisation at the control period ``dt`` (state held between steps): the
command held over ``[t_k, t_k + dt)`` is the *mean over that interval* of the
continuous PID's output for the error ``e[k]`` held there, so results converge
as ``dt`` shrinks even when the filter is fast (``N dt`` near or above 1):

* the error vector is ``e = -vec(q_RN* ⊗ q_BN)`` with the scalar part made
  non-negative (:func:`attitude_sil.core.plant.kernels.error3_row`); in the angle
  mode (``error_mode: angle``) each component becomes ``2 asin(e_i)``;
* derivative filter: low-pass state ``x_f`` of ``N / (s + N)``, exact for a
  held error, ``x_f[k+1] = a x_f[k] + (1 - a) e[k]`` with ``a = exp(-N dt)``;
  the continuous derivative term ``N (e - x_f(t))`` decays as ``exp(-N t)``
  over the interval, and its mean is ``(1 - a) / dt (e[k] - x_f[k])``: the
  derivative kick of a step keeps the continuous area ``Kd e`` at any ``dt``
  (the sample value ``N (e[k] - x_f[k])`` made it ``N dt / (1 - a)`` times too
  large: +7.7 % at ``N dt = 0.15``). ``x_f`` starts at 0, so a step at t = 0
  gives the derivative kick a continuous PID has; as ``N -> inf`` the term
  becomes the backward difference ``(e[k] - e[k-1]) / dt``;
* integrator: exact for the held error, ``I[k+1] = I[k] + e[k] dt``, and the
  command uses its interval mean ``I[k] + e[k] dt / 2``;
* output saturation at ``±output_limit`` with anti-windup by conditional
  integration: the integrator holds while the output is saturated and the
  error pushes further into the limit.

Bumpless entry (:func:`enter`): the filter state is set so the derivative
term starts at the measured error rate (``x_f = e - ė / N``, ``ė`` from
:func:`attitude_sil.core.plant.kernels.error_and_rate_row`), and the integrator
takes the rest, ``I = (u_last - Kp e - Kd ė) / Ki``; the first command then
equals ``u_last`` exactly when ``Ki > 0``, and the integrator holds only the
real difference between the two laws.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.control.kernels import error3_row, error_and_rate_row
from attitude_sil.core.control.law import Law, lanes
from attitude_sil.core.paramspec import double_array

__all__ = ["LAW", "Params", "pid_axis", "pid_bumpless_row", "pid_record"]


class Params(NamedTuple):
    """The PID's record: gains per episode and axis, (n, 3) each, and the shared settings."""

    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    n: np.ndarray
    a: np.ndarray  # exp(-N dt): the filter's discrete pole
    u_max: float  # output limit, V (or N m)
    angle_mode: bool


@njit(cache=True, inline="always")
def pid_axis(e, i, p, par, st, dt):
    """One PID step of axis ``i`` of row ``p`` on the error ``e``: the saturated output; updates the state.

    ``par`` needs the fields ``kp``, ``ki``, ``kd``, ``n``, ``a`` (n, 3) and
    ``u_max``; ``st`` the fields ``integral`` and ``filt`` (n, 3): the PID's
    record and state, or any law's that carries a PID (the fuzzy PID).
    """
    a = par.a[p, i]
    deriv = (1.0 - a) / dt * (e - st.filt[p, i])  # interval mean of N (e - x_f(t)) (module docstring)
    raw = par.kp[p, i] * e + par.ki[p, i] * (st.integral[p, i] + 0.5 * e * dt) + par.kd[p, i] * deriv
    out = min(max(raw, -par.u_max), par.u_max)
    # conditional integration as a select, stored either way: on the episode axis a conditional store is a
    # masked store, which some CPUs run many times slower than a plain one
    held = out != raw and e * raw > 0.0
    st.integral[p, i] = st.integral[p, i] if held else st.integral[p, i] + e * dt
    st.filt[p, i] = a * st.filt[p, i] + (1.0 - a) * e
    return out


@njit(cache=True, inline="always")
def pid_bumpless_row(e, de, p, par, st, u_last, dt):
    """Set the PID state of row ``p`` so its next command is ``clip(u_last)`` (a 3-tuple; module docstring).

    ``e``, ``de``: the error and its rate (3-tuples); ``par`` and ``st`` as for :func:`pid_axis`;
    ``dt``: the control period, s.
    """
    for i in range(3):
        target = min(max(u_last[i], -par.u_max), par.u_max)
        st.filt[p, i] = e[i] - de[i] / par.n[p, i]
        deriv = (1.0 - par.a[p, i]) / dt * (e[i] - st.filt[p, i])
        rest = target - par.kp[p, i] * e[i] - par.kd[p, i] * deriv
        st.integral[p, i] = rest / par.ki[p, i] - 0.5 * e[i] * dt if par.ki[p, i] > 0.0 else 0.0


@njit(cache=True, inline="always")
def step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u):
    """The law's step (:mod:`attitude_sil.core.control.law`)."""
    e = error3_row(q_BN, q_RN, p, par.angle_mode)
    for i in range(3):
        u[p, i] = pid_axis(e[i], i, p, par, st, dt)


@njit(cache=True, inline="always")
def enter(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, decay, u_last, offset):
    """Bumpless entry: the state that makes the first command ``u_last[p]`` (no offset left)."""
    e, de = error_and_rate_row(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par.angle_mode)
    pid_bumpless_row(e, de, p, par, st, (u_last[p, 0], u_last[p, 1], u_last[p, 2]), dt)
    return False


def pid_record(values, n: int, dt: float, prefix: str = "") -> Params:
    """The record of the PID gains ``{prefix}kp`` ... ``{prefix}n`` of ``values`` for n episodes."""
    kp, ki, kd, nf = (lanes(values[prefix + g], n) for g in ("kp", "ki", "kd", "n"))
    return Params(kp, ki, kd, nf, np.exp(-nf * dt), float(values["output_limit"]), values["error_mode"] == "angle")


LAW = Law(
    name="pid",
    summary="per-axis PID on the quaternion error with a filtered derivative (paper 000 eq. 19)",
    params=(
        double_array("kp", [48.894] * 3, "proportional gain per body axis, V per unit quaternion error",
                     lengths=(3,), min=0.0, runtime=True),
        double_array("ki", [0.071] * 3, "integral gain per body axis, V/s per unit error", lengths=(3,), min=0.0,
                     runtime=True),
        double_array("kd", [106.046] * 3, "derivative gain per body axis, V s per unit error", lengths=(3,),
                     min=0.0, runtime=True),
        double_array("n", [1.427] * 3, "derivative filter coefficient N per body axis, rad/s", lengths=(3,),
                     min=0.0, min_exclusive=True, runtime=True),
    ),
    state={"integral": (3, np.float64), "filt": (3, np.float64)},
    record=pid_record,
    step=step,
    enter=enter,
)
