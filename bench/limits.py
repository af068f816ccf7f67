"""The machine's physical limit for the batch engine (benchmark helper, not product code).

* :func:`count_step_ops`: the floating-point operations of one episode step of the HST roll step
  with the PID law, counted from the package's own kernels: their Python source (``py_func``) runs
  once on numbers that count every arithmetic operation done to them (the law's step, the wheels'
  step, the body's RK4, with the scenario's real arrays);
* :func:`peak_fma_flops`: the machine's measured peak rate of fused multiply-adds, flop/s (an FMA is
  two flops), on one core or on every core: 64 independent chains of ``x = x * a + b`` that LLVM packs
  into 4-wide FMA instructions (``vfmadd...pd ymm``; about 70 % of the nominal 16 flops per cycle of
  two 4-wide FMA pipes here, the rest lost to the loads and stores of the chains).

The physical limit of the engine is then ``peak / (ops per step x steps per simulated second)``
simulated seconds per wall second. It counts nothing but arithmetic: no load or store, no branch,
no libm call, and it assumes every operation is an FMA's half, which the engine's code (compiled
without ``fastmath``, so no contraction) cannot reach; it is a bound, not a target.
"""

from __future__ import annotations

import contextlib
import time
from collections import Counter
from types import SimpleNamespace

import numpy as np
from numba import njit, prange

OPS = Counter()


class Counted:
    """A float that counts the operations done to it (by kind, in :data:`OPS`)."""

    __slots__ = ("v",)

    def __init__(self, v):
        self.v = float(v.v if isinstance(v, Counted) else v)

    def _op(self, kind, other, fn):
        OPS[kind] += 1
        return Counted(fn(self.v, other.v if isinstance(other, Counted) else float(other)))

    def __add__(self, o): return self._op("add", o, lambda a, b: a + b)
    def __radd__(self, o): return self._op("add", o, lambda a, b: b + a)
    def __sub__(self, o): return self._op("add", o, lambda a, b: a - b)
    def __rsub__(self, o): return self._op("add", o, lambda a, b: b - a)
    def __mul__(self, o): return self._op("mul", o, lambda a, b: a * b)
    def __rmul__(self, o): return self._op("mul", o, lambda a, b: b * a)
    def __truediv__(self, o): return self._op("div", o, lambda a, b: a / b)
    def __rtruediv__(self, o): return self._op("div", o, lambda a, b: b / a)

    def __neg__(self):
        OPS["other"] += 1
        return Counted(-self.v)

    def __abs__(self):
        OPS["other"] += 1
        return Counted(abs(self.v))

    def _cmp(self, o, fn):
        OPS["other"] += 1
        return fn(self.v, o.v if isinstance(o, Counted) else float(o))

    def __lt__(self, o): return self._cmp(o, lambda a, b: a < b)
    def __le__(self, o): return self._cmp(o, lambda a, b: a <= b)
    def __gt__(self, o): return self._cmp(o, lambda a, b: a > b)
    def __ge__(self, o): return self._cmp(o, lambda a, b: a >= b)
    def __eq__(self, o): return self._cmp(o, lambda a, b: a == b)
    def __ne__(self, o): return self._cmp(o, lambda a, b: a != b)
    __hash__ = None

    def __float__(self):
        return self.v

    def sqrt(self):
        OPS["sqrt"] += 1
        return Counted(np.sqrt(self.v))


def counted(a):
    """An object array of :class:`Counted` with a's values (a scalar becomes one Counted)."""
    if isinstance(a, np.ndarray) and a.dtype.kind == "f":
        out = np.empty(a.shape, dtype=object)
        out.flat[:] = [Counted(x) for x in a.flat]
        return out
    if isinstance(a, float):
        return Counted(a)
    return a


@contextlib.contextmanager
def python_kernels(*modules):
    """Every numba function of these modules replaced by its Python source while inside."""
    saved = []
    for mod in modules:
        for name, obj in list(vars(mod).items()):
            if hasattr(obj, "py_func"):
                saved.append((mod, name, obj))
                setattr(mod, name, obj.py_func)
    try:
        yield
    finally:
        for mod, name, obj in saved:
            setattr(mod, name, obj)


def count_step_ops(scn) -> dict[str, int]:
    """Operations of one HST episode step (PID law, wheels, RK4 body) by kind, and ``flops`` (add, mul, div,
    sqrt) and ``total`` (with negation, abs, comparisons: min, max and the branches' tests)."""
    from attitude_sil.core.control import kernels as control_kernels
    from attitude_sil.core.control.laws import pid
    from attitude_sil.core.plant import lanes
    from attitude_sil.core.plant.kernels import WheelFailure, WheelParams
    from attitude_sil.core.sim.build import build_controller, build_guidance, build_plant, build_wheels

    plant, wheels, guide = build_plant(scn, 1), build_wheels(scn, 1), build_guidance(scn, 1)
    par = build_controller(scn, 1).record("pid")
    par = type(par)(*(counted(f) for f in par))
    state = SimpleNamespace(integral=counted(np.zeros((1, 3))), filt=counted(np.zeros((1, 3))))
    q = counted(np.array([[0.01, 0.02, 0.03, 0.9993]]))
    w = counted(np.array([[0.001, 0.002, 0.003]]))
    q_r = counted(np.ascontiguousarray(guide.q_final))
    u = counted(np.zeros((1, 3)))
    wp = WheelParams(*(counted(np.asarray(a, dtype=float)) if isinstance(a, np.ndarray) else counted(float(a))
                       for a in wheels.assembly.params))
    fail = WheelFailure(np.full(1, -1), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=bool), np.zeros(1))
    b = counted(np.zeros((lanes.BODY_ROWS, 1)))
    b[lanes.Q:lanes.Q + 4, 0] = q[0]
    b[lanes.W:lanes.W + 3, 0] = w[0]
    for i in range(9):
        b[lanes.II + i, 0] = Counted(plant.inertia[0].flat[i])
        b[lanes.IV + i, 0] = Counted(plant.inertia_inv[0].flat[i])
    nw = wheels.assembly.n_wheels
    xw = counted(np.full((nw, 3, 1), 1.0))
    xn = counted(np.zeros((nw, 3, 1)))
    with python_kernels(lanes, control_kernels, pid):
        mot = counted(lanes.motor_lanes(wp, 0, 1))
        OPS.clear()  # the motor block is made once per episode, not per step
        pid.step(q, w, q_r, q_r, 0, par, state, Counted(scn.dt), u)
        b[lanes.U:lanes.U + 3, 0] = u[0]
        lanes.wheel_lanes(1, 0, 5, xw, xn, b, mot, np.zeros(1, dtype=bool), wp, fail)
        lanes.rk4_body_lanes(1, b, Counted(scn.dt), int(plant.substeps))
    out = dict(OPS)
    out["flops"] = sum(OPS[k] for k in ("add", "mul", "div", "sqrt"))
    out["total"] = out["flops"] + OPS["other"]
    return out


#: accumulators of the FMA loop: 64 doubles (16 four-wide registers of chains) is the shape that measured
#: fastest here (16, 32 and 48 stayed scalar; 128 and more are bound by loads and stores)
WIDTH = 64


@njit(fastmath=True)
def _fma(acc, a, c, n):
    for _ in range(n):
        for i in range(WIDTH):
            acc[i] = acc[i] * a + c
    return acc.sum()


@njit(parallel=True)
def _fma_threads(a, c, n, out):
    for t in prange(out.shape[0]):
        out[t] = _fma(np.ones(WIDTH), a, c, n)


def peak_fma_flops(threads: int, n: int = 20_000_000) -> float:
    """Measured fused multiply-add rate, flop/s (best of 3), on ``threads`` cores."""
    out = np.zeros(threads)
    a, c = 0.999999, 1e-9
    _fma_threads(a, c, 10, out)
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        _fma_threads(a, c, n, out)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * WIDTH * n * threads / best
