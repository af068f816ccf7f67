"""Stability margins of the sampled PID loop, the reference of the controller-output fault tests.

The loop is the one the drivers fly, linearised: the package's discrete PID
(:mod:`attitude_sil.core.control.laws.pid`, its interval-mean form) in series
with the linearised body and wheel motors of
:func:`attitude_sil.tuning.rootlocus.roll_loop` held over each control period
(``control.c2d``, zero-order hold, exact: the wheels hold the voltage over the
step), at the sample times, so

    L(z) = C(z) P_zoh(z),
    C(z) = Kp + Ki dt (1/(z - 1) + 1/2) + Kd (1 - a)/dt (z - 1)/(z - a),  a = exp(-N dt).

The margins are read from ``L(exp(j w dt))`` (python-control's frequency
response) up to the Nyquist frequency:

* the gain margin ``1/|L|`` where the phase crosses -180 deg (the upper one:
  the lowest gain above 1 that closes the loop on the unit circle);
* the phase margin at the gain crossover and the delay margin ``PM / w_c``,
  the delay whose phase lag ``w_c D`` uses it up (a delay of ``D / dt`` whole
  steps is exactly ``z^-D/dt`` in the sampled loop).

python-control's ``stability_margins`` is not used: on this loop (ten states,
motor poles at -1000 rad/s, the other axes' free integrators) its polynomial
method returns spurious crossings; the crossings here are bracketed on a dense
grid and refined with ``scipy.optimize.brentq``.

python-control is imported in the functions, as in :mod:`attitude_sil.tuning.rootlocus`.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

from attitude_sil.tuning.rootlocus import roll_loop

__all__ = ["pid_z", "sampled_pid_loop", "loop_margins"]


def pid_z(kp: float, ki: float, kd: float, n: float, dt: float):
    """The package's discrete PID (``pid`` law, one axis) as a python-control transfer function in z.

    Parameters
    ----------
    kp, ki, kd : gains, V per unit error, V/s, V s
    n : derivative filter coefficient, rad/s
    dt : control period, s
    """
    import control

    a = float(np.exp(-n * dt))
    z = control.tf([1.0, 0.0], [1.0], dt)
    return kp + ki * dt * (1.0 / (z - 1.0) + 0.5) + kd * (1.0 - a) / dt * (z - 1.0) / (z - a)


def sampled_pid_loop(scn, axis: int = 0):
    """The open loop ``C(z) P_zoh(z)`` (python-control state space, sample time the control period) of the
    scenario's ``pid`` gains on ``axis`` around :func:`~attitude_sil.tuning.rootlocus.roll_loop`."""
    import control

    c = scn.values["controller"]
    dt = float(scn.values["wheels"]["control_period"])
    gains = (float(c[f"pid.{g}"][axis]) for g in ("kp", "ki", "kd", "n"))
    return control.series(control.ss(pid_z(*gains, dt)), control.c2d(roll_loop(scn, axis), dt, "zoh"))


def loop_margins(loop, w_min: float = 1e-2, points: int = 20_000) -> dict:
    """Gain, phase and delay margins of a sampled open loop (module docstring).

    Parameters
    ----------
    loop : python-control LTI with a sample time (negative feedback around it)
    w_min : lowest frequency searched, rad/s (the grid runs log-spaced to the Nyquist frequency)
    points : grid size

    Returns
    -------
    dict with ``gain_margin`` (ratio; inf: no -180 deg crossing above unity gain), ``phase_crossover_rad_s``,
    ``phase_margin_deg`` and ``gain_crossover_rad_s`` at the gain crossover with the least delay margin
    ``delay_margin_s`` (``PM / w_c``; the phase margin counted in [0, 360) deg, as a delay only lags).
    """
    dt = float(loop.dt)
    w = np.logspace(np.log10(w_min), np.log10(np.pi / dt) - 1e-9, points)

    def l_of(x):
        return complex(np.asarray(loop.frequency_response([x]).complex).ravel()[0])

    h = np.asarray(loop.frequency_response(w).complex).ravel()
    mag = np.abs(h)
    out = {"gain_margin": np.inf, "phase_crossover_rad_s": np.nan}
    # -180 deg: the imaginary part changes sign where the real part is negative
    for i in np.nonzero(np.diff(np.sign(h.imag)))[0]:
        if h[i].real < 0.0 and h[i + 1].real < 0.0:
            wx = brentq(lambda x: l_of(x).imag, w[i], w[i + 1], xtol=1e-12)
            gm = 1.0 / abs(l_of(wx))
            if 1.0 < gm < out["gain_margin"]:
                out["gain_margin"], out["phase_crossover_rad_s"] = gm, wx
    out.update(phase_margin_deg=np.inf, gain_crossover_rad_s=np.nan, delay_margin_s=np.inf)
    for i in np.nonzero(np.diff(np.sign(mag - 1.0)))[0]:  # each gain crossover: the delay that uses up its PM
        wc = brentq(lambda x: abs(l_of(x)) - 1.0, w[i], w[i + 1], xtol=1e-12)
        pm = (float(np.angle(l_of(wc))) + np.pi) % (2.0 * np.pi)  # in [0, 2 pi): a lag can only add phase
        if pm / wc < out["delay_margin_s"]:
            out.update(phase_margin_deg=float(np.degrees(pm)), gain_crossover_rad_s=wc, delay_margin_s=pm / wc)
    return out
