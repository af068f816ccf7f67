"""``fuzzy_pid``: the hybrid fuzzy PID of paper 003, section 5, per body axis (volts).

* Fuzzy part: inputs the error ``e`` (the quaternion error vector, as the PID
  law's) and its change ``de = (e[k] - e[k-1]) / dt`` (0 at the first step),
  normalised by ``e_scale`` and ``de_scale`` to [-1, 1]; seven evenly spaced
  triangular sets each; rule table indexed ``rules[Δe, e]`` (paper 003
  Table 3 layout); product inference and weighted-average defuzzification;
  output scaled by ``u_scale`` (V).
* PID part: the ``pid`` law's arithmetic (:func:`attitude_sil.core.control.laws.pid.pid_axis`)
  with its own gains.
* Mixing (paper 003): ``f(e) = e_n^2`` with ``e_n = clip(e / e_scale, -1, 1)``.
  The paper leaves "which response is faster" open; here, per axis and
  causally, **the faster response is the one whose command at this step is
  larger in magnitude** (it would accelerate the body harder now).
  Case 1, fuzzy faster (``|u_f| > |u_pid|``): ``u = f u_pid + (1 - f) u_f``;
  case 2, PID faster: ``u = (1 - f) u_pid + f u_f``; case 3, equal (within
  1e-12 V): ``u = u_pid``. Then ``u`` is saturated at ``output_limit``.

Bumpless entry (:func:`enter`): the change-of-error memory is set from the
measured error rate (``e[k-1] = e - ė dt``), then the PID's state is set so
the mixed command equals the old controller's last whenever some PID output
achieves that (solved per case). When none does (for small errors the mix
follows whichever command is larger, so e.g. a small braking command cannot
come out while the fuzzy part pushes), the PID gets the target and the rest
is a decaying offset (``bumpless_time_constant``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.control.fuzzy import FUZZY_PID_DEFAULT_RULES, UNIFORM_VERTICES
from attitude_sil.core.control.kernels import error3_row, error_and_rate_row, infer_uniform_row, infer_vertices_row
from attitude_sil.core.control.law import Law, lanes
from attitude_sil.core.control.laws.pid import pid_axis, pid_bumpless_row, pid_record
from attitude_sil.core.paramspec import ParamSpec, double_array

__all__ = ["LAW", "Params", "mix"]

#: the evenly spaced sets -1, -2/3, ..., 1 as (1, 1, 7) vertices (rows, columns and output alike)
_V = np.ascontiguousarray(UNIFORM_VERTICES.reshape(1, 1, 7))


class Params(NamedTuple):
    """The fuzzy PID's record: the PID part's gains and the fuzzy part's universes, (n, 3) each."""

    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    n: np.ndarray
    a: np.ndarray
    e_scale: np.ndarray
    de_scale: np.ndarray
    u_scale: np.ndarray
    rules: np.ndarray  # (n, 7, 7) int64, 1..7
    u_max: float
    angle_mode: bool


@njit(cache=True, inline="always")
def mix(u_p, u_f, f):
    """Paper 003's mixing block with the magnitude rule (module docstring), one element."""
    if abs(u_f) > abs(u_p) + 1e-12:
        return f * u_p + (1.0 - f) * u_f
    if abs(u_p) > abs(u_f) + 1e-12:
        return (1.0 - f) * u_p + f * u_f
    return u_p


@njit(cache=True, inline="always")
def step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u):
    """The law's step: the mixed command before the final saturation (the bank clips it)."""
    e3 = error3_row(q_BN, q_RN, p, par.angle_mode)
    has_prev = st.has_prev[p, 0]
    for i in range(3):
        e = e3[i]
        de = (e - st.e_prev[p, i]) / dt if has_prev else 0.0
        xe = e / par.e_scale[p, i]
        u_f = par.u_scale[p, i] * infer_uniform_row(de / par.de_scale[p, i], xe, par.rules, p)
        u_p = pid_axis(e, i, p, par, st, dt)  # the PID part: the pid law's arithmetic
        # mixing block, f(e) = e_n^2
        en = min(max(xe, -1.0), 1.0)
        u[p, i] = mix(u_p, u_f, en * en)
        st.e_prev[p, i] = e
    st.has_prev[p, 0] = True


@njit(cache=True, inline="always")
def enter(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, decay, u_last, offset):
    """Bumpless entry for row ``p`` (module docstring); True when a decaying offset remains."""
    e, de = error_and_rate_row(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par.angle_mode)
    u_pid = np.empty(3)
    rest = np.empty(3)
    for i in range(3):
        st.e_prev[p, i] = e[i] - de[i] * dt  # de starts at the measured rate
    for i in range(3):
        d = (e[i] - st.e_prev[p, i]) / dt
        x_e = e[i] / par.e_scale[p, i]
        u_f = par.u_scale[p, i] * infer_vertices_row(d / par.de_scale[p, i], x_e, _V, par.rules, p)
        en = min(max(x_e, -1.0), 1.0)
        f = en * en
        target = min(max(u_last[p, i], -par.u_max), par.u_max)
        p2 = (target - f * u_f) / (1.0 - f) if f != 1.0 else np.inf  # case 2: PID faster
        p1 = (target - (1.0 - f) * u_f) / f if f != 0.0 else np.inf  # case 1: fuzzy faster
        if np.isfinite(p2) and abs(p2) > abs(u_f) + 1e-12:
            up = p2
        elif np.isfinite(p1) and abs(p1) < abs(u_f) - 1e-12:
            up = p1
        else:
            up = target
        u_pid[i] = up
        rest[i] = target - mix(up, u_f, f)
    pid_bumpless_row(e, de, p, par, st, (u_pid[0], u_pid[1], u_pid[2]), dt)
    st.has_prev[p, 0] = True
    needed = decay > 0.0 and (abs(rest[0]) > 1e-12 or abs(rest[1]) > 1e-12 or abs(rest[2]) > 1e-12)
    for i in range(3):
        offset[p, i] = rest[i] if needed else 0.0
    return needed


def _record(values, n: int, dt: float) -> Params:
    pid = pid_record(values, n, dt)
    rules = lanes(np.asarray(values["rules"], dtype=np.int64), n, (7, 7), np.int64)
    return Params(*pid[:5], lanes(values["e_scale"], n), lanes(values["de_scale"], n), lanes(values["u_scale"], n),
                  rules, pid.u_max, pid.angle_mode)


LAW = Law(
    name="fuzzy_pid",
    summary="hybrid fuzzy PID: 7x7 fuzzy rules mixed with a PID by e^2 (paper 003 section 5)",
    params=(
        double_array("kp", [48.894] * 3, "PID part: proportional gain per axis, V per unit error",
                     lengths=(3,), min=0.0, runtime=True),
        double_array("ki", [0.071] * 3, "PID part: integral gain per axis", lengths=(3,), min=0.0, runtime=True),
        double_array("kd", [106.046] * 3, "PID part: derivative gain per axis", lengths=(3,), min=0.0,
                     runtime=True),
        double_array("n", [1.427] * 3, "PID part: derivative filter N per axis, rad/s", lengths=(3,),
                     min=0.0, min_exclusive=True, runtime=True),
        double_array("e_scale", [0.0175] * 3, "error universe: |e| at which e is 'large', unit quaternion error",
                     lengths=(3,), min=0.0, min_exclusive=True, runtime=True),
        double_array("de_scale", [0.01] * 3, "change-of-error universe, 1/s", lengths=(3,), min=0.0,
                     min_exclusive=True, runtime=True),
        double_array("u_scale", [2.0] * 3, "fuzzy output universe, V", lengths=(3,), min=0.0, runtime=True),
        ParamSpec("rules", "integer_array", FUZZY_PID_DEFAULT_RULES.ravel().tolist(),
                  "49 rule outputs 1..7 (NL..PL), row-major: rows change of error NL..PL, columns error NL..PL "
                  "(assumed: paper 003 Table 3 with its misprinted row restored, docs/getting-started.md)",
                  lengths=(49,), min=1, max=7, runtime=True),
    ),
    state={"integral": (3, np.float64), "filt": (3, np.float64), "e_prev": (3, np.float64),
           "has_prev": (1, np.bool_)},
    record=_record,
    step=step,
    enter=enter,
    saturated=False,
)
