"""External disturbance torques, batch over episodes: any sum of the models below.

Each model is a name in the ``disturbance`` node's ``models`` list; its
parameters are ``<model>.*`` parameters of that node. The torque of control
step k is held over ``[t_k, t_k + dt]``; a model that varies faster than dt
delivers its mean over the step, so the impulse it gives the body is exact.

* ``constant`` — ``constant.torque`` (N m, body axes).
* ``step`` — ``step.torque`` from ``step.time`` on.
* ``impulse`` — ``impulse.magnitude`` (N m s, or the normalised unit of a
  normalised plant) about body axis ``impulse.axis`` at ``impulse.time``,
  delivered within one control step (torque magnitude/dt); with
  ``impulse.period`` > 0 a pulse train of ``impulse.count`` pulses (0: no end).
  Paper 004: an impulsive torque sets the pitch rate, ``q(0) = T_d``.
* ``noise`` — band-limited white noise (paper 000 section 2.A): a
  zero-order-held Gaussian sequence at ``noise.sample_time`` with variance
  ``power / T_s`` per axis, averaged over the step; seeded per episode
  (``noise.seed`` + episode index), numpy PCG64.
* ``gravity_gradient_linear`` — paper 000 eq. 18, ``G_x = 3 mu / R^3 (I_zz - I_yy) phi``,
  ``G_y = 3 mu / R^3 (I_zz - I_xx) theta``, ``G_z = 0``, angles from the inertial frame.
* ``gravity_gradient`` — paper 001 eq. 3 (with the orbit rate squared, as the
  physics requires: the print shows ``3 Omega_0``): ``M_g = 3 Omega_0^2 n x (J n)``,
  n the nadir unit vector in B.
* ``aerodynamic`` — paper 001 eq. 2: ``M_ad = 0.5 rho C_d A V^2 (v x s_cp)``,
  v the velocity direction in B, ``s_cp`` the centre of pressure from the
  centre of mass in B.

The last two need the orbit frame (LVLH: x along the velocity, y the orbit
normal, z zenith, paper 001). On the circular orbit (``orbit.model:
circular``) LVLH turns about its y axis at ``Omega_0 = sqrt(mu / r^3)``, and
``q_LN(t) = q_LN(0) ⊗ R_y(Omega_0 t)`` (:func:`lvlh_attitude`), the same frame
the guidance node's ``lvlh`` mode tracks. On a propagated orbit
(``keplerian_j2``, :mod:`attitude_sil.core.environment.ephemeris`) the frame,
the gravity-gradient gain ``3 mu / r^3`` and the speed are that orbit's at
each step; the velocity is taken along LVLH x (exact on a circular orbit, off
by the flight-path angle, at most about e rad, on an eccentric one).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from attitude_sil.core.plant.quaternion import (
    cross,
    euler_from_quat,
    quat_from_euler,
    quat_multiply,
)
from attitude_sil.errors import ScenarioError

__all__ = [
    "DISTURBANCE_MODELS",
    "DisturbanceModel",
    "lvlh_attitude",
    "orbit_rate",
    "gravity_gradient_torque",
    "aerodynamic_torque",
    "orbit_torques",
]

DISTURBANCE_MODELS = ("constant", "step", "impulse", "noise", "gravity_gradient_linear", "gravity_gradient",
                      "aerodynamic", "residual_dipole")


def orbit_rate(mu: float, radius: float) -> float:
    """Mean motion of a circular orbit, rad/s."""
    return float(np.sqrt(mu / radius**3))


def lvlh_attitude(t: float, q_LN0: np.ndarray, rate: float) -> np.ndarray:
    """LVLH orientation at time t: ``q_LN(0) ⊗ R_y(rate t)``, shape like ``q_LN0``.

    One frame (``q_LN0`` of shape (4,)), the usual case, is multiplied out in
    floats: :func:`quat_multiply`'s arithmetic in its order, without numpy's
    per-call cost (the guidance and the disturbance ask for it every step).
    """
    half = 0.5 * rate * t
    s, c = float(np.sin(half)), float(np.cos(half))
    if np.shape(q_LN0) != (4,):
        return quat_multiply(q_LN0, np.array([0.0, s, 0.0, c]))
    qx, qy, qz, qw = (float(v) for v in q_LN0)
    return np.array([qw * 0.0 + c * qx + qy * 0.0 - qz * s, qw * s + c * qy + qz * 0.0 - qx * 0.0,
                     qw * 0.0 + c * qz + qx * s - qy * 0.0, qw * c - qx * 0.0 - qy * s - qz * 0.0])


def gravity_gradient_torque(R_BL: np.ndarray, inertia: np.ndarray, rate: float) -> np.ndarray:
    """Full gravity-gradient moment (paper 001 eq. 3), (P, 3) N m.

    Parameters
    ----------
    R_BL : (P, 3, 3) rotation from LVLH to B
    inertia : (P, 3, 3) kg m^2
    rate : orbit rate Omega_0, rad/s
    """
    nadir = -R_BL[..., :, 2]  # -l3 in B
    # J n summed in the order of the row (einsum's order varies): orbit_torques's numbers to the last bit
    jn = inertia[..., 0] * nadir[..., None, 0] + inertia[..., 1] * nadir[..., None, 1] \
        + inertia[..., 2] * nadir[..., None, 2]
    return 3.0 * rate**2 * cross(nadir, jn)


def aerodynamic_torque(R_BL: np.ndarray, density: float, drag_coefficient: float, area: float, speed: float,
                       cp_offset_B: np.ndarray) -> np.ndarray:
    """Aerodynamic drag moment (paper 001 eq. 2), (P, 3) N m; v is l1 (the velocity) in B."""
    v_hat = R_BL[..., :, 0]
    return 0.5 * density * drag_coefficient * area * speed**2 * cross(v_hat, cp_offset_B)


@njit(cache=True, nogil=True)
def step_means(rng: np.random.Generator, n: int, std: np.ndarray, out: np.ndarray) -> None:
    """Each step's mean of ``n`` noise samples times the axis' standard deviation, into ``out`` (K + 1, 3).

    ``rng``: the episode's stream, continued (numpy PCG64; numba draws its
    normals with numpy's algorithm, so the numbers are numpy's), one (n, 3)
    block of samples per step. Each axis' sum runs from the step's first
    sample to its last, as ``np.add.reduce`` over the sample axis of the
    blocks sums them (:meth:`DisturbanceModel.torque`, a step at a time), so the
    means are those bits. ``std`` (3,).
    """
    for k in range(out.shape[0]):
        s0, s1, s2 = rng.standard_normal(), rng.standard_normal(), rng.standard_normal()
        for _ in range(1, n):
            s0 += rng.standard_normal()
            s1 += rng.standard_normal()
            s2 += rng.standard_normal()
        out[k, 0], out[k, 1], out[k, 2] = s0 / n * std[0], s1 / n * std[1], s2 / n * std[2]


@njit(cache=True)
def orbit_torques(q_BN: np.ndarray, q_LN: np.ndarray, inertia: np.ndarray, gg_gain: float, aero_gain: float,
                  cp_offset_B: np.ndarray, gg: bool, aero: bool, tau: np.ndarray) -> None:
    """Add the gravity-gradient and aerodynamic moments of P episodes to ``tau`` (P, 3), N m.

    :func:`gravity_gradient_torque` (gain ``3 Omega_0^2``) and
    :func:`aerodynamic_torque` (gain ``0.5 rho C_d A V^2``) written out per
    episode from the attitude relative to LVLH, ``q_BL = q_LN* ⊗ q_BN`` (the
    numpy forms cost the stepwise driver half of a HawaiiSat step), for the
    models ``gg`` and ``aero`` say are on.

    Parameters
    ----------
    q_BN : (P, 4) attitude; q_LN : (4,) the LVLH frame now (:func:`lvlh_attitude`)
    inertia : (P, 3, 3) kg m^2; cp_offset_B : (3,) centre of pressure from the centre of mass, m
    """
    cx, cy, cz, cw = -q_LN[0], -q_LN[1], -q_LN[2], q_LN[3]
    for p in range(q_BN.shape[0]):
        px, py, pz, pw = q_BN[p, 0], q_BN[p, 1], q_BN[p, 2], q_BN[p, 3]
        x = cw * px + pw * cx + cy * pz - cz * py  # q_BL, as quat_multiply
        y = cw * py + pw * cy + cz * px - cx * pz
        z = cw * pz + pw * cz + cx * py - cy * px
        w = cw * pw - cx * px - cy * py - cz * pz
        if gg:  # nadir -l3 in B: minus the third row of R_LB (quat_to_dcm of q_BL)
            n0, n1, n2 = -(2 * (x * z - y * w)), -(2 * (y * z + x * w)), -(1 - 2 * (x * x + y * y))
            j0 = inertia[p, 0, 0] * n0 + inertia[p, 0, 1] * n1 + inertia[p, 0, 2] * n2
            j1 = inertia[p, 1, 0] * n0 + inertia[p, 1, 1] * n1 + inertia[p, 1, 2] * n2
            j2 = inertia[p, 2, 0] * n0 + inertia[p, 2, 1] * n1 + inertia[p, 2, 2] * n2
            tau[p, 0] += gg_gain * (n1 * j2 - n2 * j1)
            tau[p, 1] += gg_gain * (n2 * j0 - n0 * j2)
            tau[p, 2] += gg_gain * (n0 * j1 - n1 * j0)
        if aero:  # the velocity l1 in B: the first row of R_LB
            v0, v1, v2 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
            c0, c1, c2 = cp_offset_B[0], cp_offset_B[1], cp_offset_B[2]
            tau[p, 0] += aero_gain * (v1 * c2 - v2 * c1)
            tau[p, 1] += aero_gain * (v2 * c0 - v0 * c2)
            tau[p, 2] += aero_gain * (v0 * c1 - v1 * c0)


class DisturbanceModel:
    """Sum of the selected disturbance models for P episodes.

    Parameters
    ----------
    values : dict
        The ``disturbance`` node's parameters (``models``, ``noise.power``, ...).
    inertia : ndarray, shape (P, 3, 3)
        Body inertia for the gravity-gradient models, kg m^2.
    seeds : sequence of int, length P
        Noise seed of each episode.
    orbit : optional
        A propagated orbit (``core.environment.ephemeris.Ephemeris``): the
        orbit models read its LVLH frame, 3 mu / r^3 and speed at each step;
        None: the circular orbit of ``values``.
    field : optional
        The geomagnetic field along the orbit
        (``core.environment.ephemeris.FieldAlongOrbit``, the plant's): the
        ``residual_dipole`` model's torque is m_res x B, m_res
        (``residual_dipole.moment``, (3,) or per episode (P, 3) A m^2 in B).
    """

    def __init__(self, values: dict, inertia: np.ndarray, seeds, orbit=None, field=None) -> None:
        models = list(values["models"])
        unknown = [m for m in models if m not in DISTURBANCE_MODELS]
        if unknown:
            raise ScenarioError(f"unknown disturbance model {unknown[0]!r}; known: {', '.join(DISTURBANCE_MODELS)}")
        self.models = tuple(models)
        self.v = dict(values)
        self.dt = float(values["control_period"])
        self.dt_ns = int(round(self.dt * 1e9))
        self.seeds = [int(s) for s in seeds]
        self.n_episodes = len(self.seeds)
        self.inertia = np.broadcast_to(np.asarray(inertia, dtype=float), (self.n_episodes, 3, 3))
        diag = np.diagonal(self.inertia, axis1=-2, axis2=-1)
        mu, radius = values["orbit.mu"], values["orbit.radius"]
        n2 = 3.0 * mu / radius**3
        self.gg_gain = np.stack((n2 * (diag[:, 2] - diag[:, 1]), n2 * (diag[:, 2] - diag[:, 0])), axis=-1)
        self.rate = orbit_rate(mu, radius)
        self.speed = float(np.sqrt(mu / radius))
        # the drag's gain but the speed squared: 0.5 rho C_d A, the product in the numpy form's order
        self._aero_gain = 0.5 * values["aero.density"] * values["aero.drag_coefficient"] * values["aero.area"]
        # orbit_torques's arguments but the attitude and the frame: the gains' products in the order of the
        # numpy forms (the same numbers), the models on
        self._orbit = (np.ascontiguousarray(self.inertia), float(3.0 * self.rate**2),
                       float(self._aero_gain * self.speed**2), np.ascontiguousarray(values["aero.cp_offset"],
                                                                                  dtype=float),
                       "gravity_gradient" in self.models, "aerodynamic" in self.models)
        self.q_LN0 = quat_from_euler(np.radians(values["orbit.lvlh_initial_rpy_deg"]))
        self.orbit = orbit
        self.field = field
        self.residual_B = np.asarray(values["residual_dipole.moment"], dtype=float)
        if "residual_dipole" in self.models and field is None:
            raise ScenarioError("disturbance model residual_dipole needs the geomagnetic field: set plant "
                                "environment.magnetic_field.model (dipole or igrf)")
        ratio = self.dt / values["noise.sample_time"]
        self.samples_per_step = int(round(ratio))
        if "noise" in self.models and (self.samples_per_step < 1 or abs(ratio - self.samples_per_step) > 1e-9):
            raise ScenarioError(f"noise.sample_time {values['noise.sample_time']} s must divide the control "
                             f"period {self.dt} s")
        noise_std = np.sqrt(np.asarray(values["noise.power"], dtype=float) / values["noise.sample_time"])
        self.noise_std = np.ascontiguousarray(np.broadcast_to(noise_std, (self.n_episodes, 3)))  # (P, 3) N m
        self.reset()

    def reset(self) -> None:
        """Restart every episode's noise stream from its seed (streams exist only where noise is on)."""
        self.rngs = [np.random.Generator(np.random.PCG64(s)) for s in self.seeds] if "noise" in self.models else []
        self._block = np.empty((self.n_episodes, 0, 3))
        self._at = 0

    #: control steps of noise drawn at once per episode (the stream is the same as drawn step by step)
    NOISE_BLOCK = 64

    def _noise(self) -> np.ndarray:
        """This step's noise samples, (P, samples_per_step, 3): the next ones of each episode's stream."""
        n = self.samples_per_step
        if self._at >= self._block.shape[1]:
            self._block = np.stack([rng.standard_normal((self.NOISE_BLOCK * n, 3)) for rng in self.rngs])
            self._at = 0
        out = self._block[:, self._at:self._at + n]
        self._at += n
        return out

    def noise_torque(self, lo: int, hi: int, n_steps: int) -> np.ndarray:
        """The ``noise`` model's torque of steps 0..K for episodes ``lo..hi-1``, (hi - lo, K + 1, 3) N m.

        Drawn from fresh streams of the episodes' seeds: the numbers
        :meth:`torque` adds step by step after a :meth:`reset` (the compiled
        driver adds them in the same place of the sum), drawn and averaged in
        compiled code without the GIL (chunks on threads draw at once).
        """
        out = np.empty((hi - lo, n_steps + 1, 3))
        for e in range(lo, hi):
            step_means(np.random.Generator(np.random.PCG64(self.seeds[e])), self.samples_per_step, self.noise_std[e],
                       out[e - lo])
        return out

    def torque(self, q_BN: np.ndarray, t_ns: int = 0) -> np.ndarray:
        """Disturbance torque held over the step that starts at ``t_ns``, (P, 3) N m.

        Parameters
        ----------
        q_BN : (P, 4) attitude at t_k
        t_ns : int, t_k in nanoseconds
        """
        v = self.v
        tau = np.zeros((q_BN.shape[0], 3))
        k = t_ns // self.dt_ns if self.dt_ns else 0
        if "constant" in self.models:
            tau += np.asarray(v["constant.torque"])
        if "step" in self.models and t_ns >= round(v["step.time"] * 1e9):
            tau += np.asarray(v["step.torque"])
        if "impulse" in self.models:
            tau[:, v["impulse.axis"]] += self._impulse(k) * v["impulse.magnitude"] / self.dt
        if "noise" in self.models:
            # the mean of the step's samples, summed in order (as ndarray.mean over the sample axis): step_means's
            # numbers, here in numpy (a Generator passed into compiled code is boxed anew on every call)
            draws = np.add.reduce(self._noise(), axis=1) / self.samples_per_step
            tau += draws * self.noise_std
        if "gravity_gradient_linear" in self.models:
            rpy = euler_from_quat(q_BN)
            tau[:, :2] += self.gg_gain * rpy[:, :2]
        inertia, _, _, cp, gg, aero = self._orbit
        if gg or aero:  # this step's frame and gains: the propagated orbit's, or the circular one's
            q_LN, gg_gain, aero_gain = self._frame(t_ns)
            orbit_torques(np.ascontiguousarray(q_BN, dtype=float), q_LN, inertia, gg_gain, aero_gain, cp, gg, aero,
                          tau)
        if "residual_dipole" in self.models:  # the spacecraft's own dipole in the field: m_res x B
            b_B = self.field.field_B(np.array([t_ns]), np.asarray(q_BN, dtype=float)[:, None, :])[:, 0]
            tau += cross(np.broadcast_to(self.residual_B, b_B.shape), b_B)
        return tau

    def orbit_frames(self, n_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What :func:`orbit_torques` reads at steps 0..K besides the attitude, as :meth:`torque` computes it:
        the LVLH frame q_LN (K+1, 4), the gravity gradient's gain 3 mu / r^3 (K+1,) 1/s^2 and the drag's
        gain (K+1,) N m (the compiled driver's; no rows without the orbit models)."""
        _, _, _, _, gg, aero = self._orbit
        if not (gg or aero):
            return np.zeros((0, 4)), np.zeros(0), np.zeros(0)
        q_LN, gg_gain, aero_gain = np.empty((n_steps + 1, 4)), np.empty(n_steps + 1), np.empty(n_steps + 1)
        for k in range(n_steps + 1):
            q_LN[k], gg_gain[k], aero_gain[k] = self._frame(k * self.dt_ns)
        return q_LN, gg_gain, aero_gain

    def _frame(self, t_ns: int) -> tuple[np.ndarray, float, float]:
        """The LVLH frame q_LN (4,), the gravity gradient's gain 3 mu / r^3 and the drag's gain at step time
        ``t_ns``: from the propagated orbit, or the circular one's (its gains constant)."""
        if self.orbit is not None:
            now = self.orbit.at(t_ns)
            return now.q_LN, now.gg_gain, self._aero_gain * now.speed**2
        return lvlh_attitude(t_ns * 1e-9, self.q_LN0, self.rate), self._orbit[1], self._orbit[2]

    def _impulse(self, k: int) -> float:
        """1.0 if a pulse falls in step k, else 0.0."""
        v = self.v
        k0 = int(round(v["impulse.time"] * 1e9)) // self.dt_ns
        if k < k0:
            return 0.0
        if v["impulse.period"] <= 0.0:
            return 1.0 if k == k0 else 0.0
        period = int(round(v["impulse.period"] * 1e9)) // self.dt_ns
        n = (k - k0) // period
        count = v["impulse.count"]
        return 1.0 if (k - k0) % period == 0 and (count == 0 or n < count) else 0.0
