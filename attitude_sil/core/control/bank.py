"""The controller bank: every registered law for P episodes, one active, swapped bumplessly.

The bank is what the controller node (P = 1) and the stepwise batch driver
call each control step; the compiled driver (:mod:`attitude_sil.core.sim.batch`)
takes its records and runs the same law steps in its own loop. Each law's
parameters come from the controller's values (``pid.kp``, ...) through the
law's ``record``; its state is the law's declared layout
(:mod:`attitude_sil.core.control.law`).

:meth:`ControllerBank.request` schedules a swap that takes effect at the next
:meth:`ControllerBank.compute` (a step boundary). Bumpless transfer:

* the new law's state is zeroed; then, if the old law commanded the same
  kind (volts or N m), the law's ``enter`` sets its state so the first
  command equals the old law's last (the ``pid`` and ``fuzzy_pid`` laws),
  or, for a law without ``enter``, a decaying offset
  (``bumpless_time_constant``) makes the first command equal the last;
* between command kinds there is nothing to match: the new law starts from
  its own command; the jump is bounded by ``|u_last| + u_max`` of the new law.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from attitude_sil.core.control import registry
from attitude_sil.core.control.law import Law, state_layout
from attitude_sil.core.plant.kernels import measure
from attitude_sil.errors import ScenarioError

__all__ = ["ControllerBank", "law_values"]


def law_values(law: Law, values: Mapping[str, Any]) -> dict[str, Any]:
    """The controller's values as ``law.record`` reads them: the shared names and the law's short ones."""
    view = dict(values)
    prefix = law.name + "."
    view.update({k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)})
    return view


_STAND_INS: dict[tuple[str, float], tuple] = {}


def _stand_in(name: str, dt: float, values: dict, n: int) -> tuple:
    """Law ``name``'s record for no episodes: its numba type (the values do not matter), built once per process.

    Built for the bank's ``n`` episodes, then cut to none: ``values`` may hold
    a value per episode (a population's gains), which fits n rows, not 0.
    """
    key = (name, dt)
    if key not in _STAND_INS:
        law = registry.get(name)
        rec = law.record(law_values(law, values), n, dt)
        _STAND_INS[key] = type(rec)(*(f[:0] if isinstance(f, np.ndarray) and f.ndim >= 1 else f for f in rec))
    return _STAND_INS[key]


class ControllerBank:
    """One record and state of each registered law for P episodes; the active law computes.

    Parameters
    ----------
    values : dict
        The controller node's parameters (``controller_type``, ``pid.kp``, ...).
    dt : float
        Control period, s.
    n_episodes : int
    per_episode : dict, optional
        Per-episode overrides ``{"pid.kp": (P, 3), ...}``.
    """

    def __init__(self, values: dict, dt: float, n_episodes: int, per_episode: dict | None = None) -> None:
        self.dt = float(dt)
        self.n = int(n_episodes)
        self.dispatch = registry.dispatch_module()
        self.names: tuple[str, ...] = self.dispatch.LAWS
        self.codes = {name: i for i, name in enumerate(self.names)}
        self.states = self.new_states(self.n)
        self.per_episode = dict(per_episode or {})
        self.configure(values)
        self.active = values["controller_type"]
        if self.active not in self.codes:
            registry.get(self.active)  # the error names the known laws
        self.pending: str | None = None
        self.u_last: np.ndarray | None = None
        self._law_rows: tuple[str, np.ndarray] | None = None
        self.offset = np.zeros((self.n, 3))
        self.has_offset = np.zeros(self.n, dtype=np.bool_)
        self.reset()

    def new_states(self, n: int, order: str = "C") -> tuple:
        """Every law's state record for n episodes, zeroed (the generated ``State_<code>`` classes); ``order``:
        the arrays' memory order (the batch engine's are column-major, "F")."""
        return tuple(getattr(self.dispatch, f"State_{i}")(
            *(np.zeros((n, int(w)), dtype=d, order=order) for w, d in state_layout(registry.get(name)).values()))
            for i, name in enumerate(self.names))

    def configure(self, values: dict) -> None:
        """Apply (possibly changed) parameters to every law; states are kept."""
        v = dict(values)
        v.update(self.per_episode)
        self.values = v
        self._records: dict[str, tuple] = {}  # built on first use (record, records_for)
        self.command = v["command"]
        tau_b = float(v["bumpless_time_constant"])
        self.decay = float(np.exp(-self.dt / tau_b)) if tau_b > 0.0 else 0.0
        self._set_sensor(v)

    def record(self, name: str) -> tuple:
        """Law ``name``'s parameter record for the bank's P episodes (built on first use after a configure)."""
        if name not in self._records:
            law = registry.get(name)
            self._records[name] = law.record(law_values(law, self.values), self.n, self.dt)
        return self._records[name]

    def records_for(self, names) -> tuple:
        """Every law's record in code order: those ``names`` run, real; the others empty stand-ins of their type.

        A run compiles against every law's record type, but only the laws it
        runs need their P rows built (at P = 1 the building cost more than the run).
        """
        wanted = set(names)
        return tuple(self.record(n) if n in wanted else _stand_in(n, self.dt, self.values, self.n)
                     for n in self.names)

    def _set_sensor(self, v: dict) -> None:
        """Sensor noise on the law's inputs (``sensor_noise.*``, scalars or per-episode (P,) arrays)."""
        seeds = np.atleast_1d(np.asarray(v["sensor_noise.seed"])).astype(np.int64)
        att = np.radians(np.atleast_1d(np.asarray(v["sensor_noise.attitude_std_deg"], dtype=float)))
        rate = np.radians(np.atleast_1d(np.asarray(v["sensor_noise.rate_std_deg_s"], dtype=float)))
        m = max(seeds.size, att.size, rate.size)
        self.sensor_seeds, self.sensor_att_std, self.sensor_rate_std = (
            np.ascontiguousarray(np.broadcast_to(a, (m,))) for a in (seeds, att, rate))
        #: the law sees measurements with noise (else the true state, bit for bit)
        self.noisy = bool(np.any(self.sensor_att_std > 0.0) or np.any(self.sensor_rate_std > 0.0))

    def measure(self, q_BN: np.ndarray, omega_BN_B: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """What the law sees at step ``k``: the state with this step's sensor noise (or the state itself).

        Each draw is a pure function of (``sensor_noise.seed``, k, channel)
        (:func:`attitude_sil.core.plant.kernels.measure`), so a node that knows its
        step draws what the batch engine drew for that episode.
        """
        if not self.noisy:
            return q_BN, omega_BN_B
        return measure(np.ascontiguousarray(q_BN, dtype=float), np.ascontiguousarray(omega_BN_B, dtype=float),
                       int(k), self.sensor_seeds, self.sensor_att_std, self.sensor_rate_std)

    def _codes_of(self, name: str) -> np.ndarray:
        """Every row's law code (the active law's), as the law's compiled ``rows_<code>`` takes them."""
        if self._law_rows is None or self._law_rows[0] != name:
            self._law_rows = (name, np.full(self.n, self.codes[name], dtype=np.int64))
        return self._law_rows[1]

    def _zero_state(self, name: str) -> None:
        for a in self.states[self.codes[name]]:
            a[...] = 0

    def reset(self) -> None:
        """New episode: every law's state cleared, no swap pending."""
        for name in self.names:
            self._zero_state(name)
        self.offset[...] = 0.0
        self.has_offset[...] = False
        self.pending = None
        self.u_last = None

    def request(self, controller_type: str) -> None:
        """Swap to ``controller_type`` at the next step."""
        if controller_type not in self.codes:
            registry.get(controller_type)  # raises, naming the known laws
            raise ScenarioError(f"controller_type {controller_type!r} was registered after this bank was built")
        self.pending = None if controller_type == self.active else controller_type

    @property
    def kind(self) -> str:
        """``voltage`` or ``torque``: what the active law commands."""
        return self.kind_of(self.active)

    def kind_of(self, controller_type: str) -> str:
        """``torque`` for a torque law, else what ``command`` says (volts for wheel presets)."""
        return "torque" if registry.output_of(controller_type) == "torque" else self.command

    def compute(self, q_BN: np.ndarray, omega_BN_B: np.ndarray, q_RN: np.ndarray,
                omega_RN_R: np.ndarray, k: int | None = None) -> np.ndarray:
        """Command (P, 3) of the active law for step ``k`` (V or N m, see :attr:`kind`).

        With sensor noise on (:attr:`noisy`) the law sees :meth:`measure` of
        the state, which needs the step ``k``.
        """
        if self.noisy:
            if k is None:
                raise ScenarioError("sensor noise needs the step index k")
            q_BN, omega_BN_B = self.measure(q_BN, omega_BN_B, k)
        c = np.ascontiguousarray
        q, w, q_r, w_r = (c(a, dtype=float) for a in (q_BN, omega_BN_B, q_RN, omega_RN_R))
        d = self.dispatch
        if self.pending is not None:
            old_kind = self.kind
            self.active, self.pending = self.pending, None
            self._zero_state(self.active)
            self.offset[...] = 0.0
            self.has_offset[...] = False
            if self.u_last is not None and self.kind == old_kind:
                # the law's compiled bumpless entry (generated ``enter_<code>``), row by row: a swap is rare
                code = self.codes[self.active]
                enter, par, st = getattr(d, f"enter_{code}"), self.record(self.active), self.states[code]
                u_last = c(self.u_last, dtype=float)
                xfer, scratch = (u_last, self.offset, self.has_offset), u_last.copy()
                for p in range(q.shape[0]):
                    enter(q, w, q_r, w_r, p, par, st, self.dt, self.decay, xfer, scratch)
        # the active law's compiled step over the rows, with the transfer offset and the clip (generated
        # ``rows_<code>``): compiled for this law alone, so a node loads only its own law's code
        u = np.empty((q.shape[0], 3))
        code = self.codes[self.active]
        getattr(d, f"rows_{code}")(self._codes_of(self.active), q, w, q_r, w_r, self.record(self.active),
                                   self.states[code], self.dt, u, self.offset, self.has_offset, self.decay)
        self.u_last = u
        return u
