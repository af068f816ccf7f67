"""The laws' dispatch table, and the numba machinery the compiled loops are built with.

numba cannot index a tuple of functions at run time, and a closure over a
jitted step cannot be cached (a dispatcher's identity differs in every
process). So for the registered laws this module writes one small module,
the dispatch table (:func:`dispatch_source`; ``attitude-sil engine
--source`` prints it), named by a hash of the laws' source, into the user
cache folder (:func:`attitude_sil.core.cache.cache_dir`) and imports it:
numba then caches its functions like any other module's, and an edited law
gets a new hash. For each law (its code is its place in
the registry's order) the table binds the law's step to the loops of
:mod:`attitude_sil.core.control.dispatch`, one line each:

* ``vector_<code>``: the step on every row, the arrays column-major so that
  LLVM packs the episodes into SIMD lanes (the step compiled again to be
  inlined by LLVM, :data:`VECTOR_STEP`, in a loop whose arrays are declared
  free of aliasing, :class:`LanesCompiler`; bench/README.md says why each is
  needed);
* ``rows_<code>``: its rows of a block, one at a time, with the transfer
  offset (the controller bank's call, and the batch engine's for a block of
  several laws);
* ``enter_<code>``: the bumpless entry of one row;
* ``State_<code>``: the law's state record class.

The batch engine calls these at their machine addresses (:func:`law_addresses`,
:func:`call_at`), so each is compiled once, not again inside every variant
of the engine's loop; the loop itself is an ordinary module of the package
(:mod:`attitude_sil.core.sim.batch_loop`).
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys
import threading
from pathlib import Path
from types import ModuleType

import numba
import numpy as np
from numba import types
from numba.core import cgutils
from numba.core.compiler import CompilerBase, DefaultPassBuilder
from numba.core.compiler_machinery import FunctionPass, register_pass
from numba.extending import intrinsic, overload

from attitude_sil.core.cache import cache_dir
from attitude_sil.core.control.law import Law, state_layout

__all__ = ["table_for", "dispatch_source", "LanesCompiler", "VECTOR_STEP", "every_row", "law_addresses",
           "call_at"]

#: how a law's step is compiled again for :func:`vector_<code>`: inlined by LLVM (``alwaysinline``), not by
#: numba. numba's own inlining (``inline="always"``) binds the step's array arguments to new names, and the
#: reference counts it takes and drops for them each row are calls, which keep LLVM's loop vectoriser away
#: (they are pruned only after it has run); an LLVM-inlined call takes none. The batch loop's error model.
VECTOR_STEP = {"forceinline": True, "error_model": "numpy"}


@register_pass(mutates_CFG=False, analysis_only=False)
class _ArraysDoNotAlias(FunctionPass):
    """Declare the function's array arguments free of aliasing (numba's ``noalias`` flag; parfors use it)."""

    _name = "attitude_sil_arrays_do_not_alias"

    def __init__(self) -> None:
        FunctionPass.__init__(self)

    def run_pass(self, state) -> bool:
        state.flags.noalias = True
        return False


class LanesCompiler(CompilerBase):
    """numba's nopython pipeline for a loop over the episodes whose array arguments share no memory.

    A law's step reads ten and more arrays and writes a few; with no promise
    that they do not overlap, LLVM would have to test every pair at run time
    before a packed loop, and past eight pairs it keeps the loop scalar. The
    caller's promise: no array argument is written through while another
    argument reaches the same memory (records are read-only, each state field
    and the command are arrays of their own).
    """

    def define_pipelines(self):
        pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
        pm.add_pass_after(_ArraysDoNotAlias, pm.passes[0][0])
        pm.finalize()
        return [pm]


#: at most this many bool fields of a record get loops of their own in :func:`every_row` (2**n loops)
MAX_VERSIONED_FLAGS = 2


def every_row(step, q, w, q_r, w_r, par, st, dt, u):
    """``step`` on every row of ``u``; compiled, a loop of its own for each value of the record's bool fields.

    A branch on a mode switch of the record (``par.angle_mode``) is the same
    for every episode, but inside one loop LLVM turns it into a select and
    evaluates both sides for every lane: the angle mode's three ``asin``
    calls, scalar, on every PID step, more than doubling its cost. With a
    loop per value, the condition is known inside each
    and the branch disappears. Up to :data:`MAX_VERSIONED_FLAGS` fields, in
    the record's order.
    """
    for p in range(u.shape[0]):
        step(q, w, q_r, w_r, p, par, st, dt, u)


@overload(every_row, inline="always")
def _every_row(step, q, w, q_r, w_r, par, st, dt, u):
    fields = getattr(par, "fields", ())
    flags = [f for f, t in zip(fields, par.types, strict=True) if isinstance(t, types.Boolean)][:MAX_VERSIONED_FLAGS]
    loop = ["for p in range(u.shape[0]):", "    step(q, w, q_r, w_r, p, par, st, dt, u)"]

    def nest(names: list[str]) -> list[str]:
        if not names:
            return loop
        inner = nest(names[1:])
        return [f"if par.{names[0]}:", *("    " + x for x in inner), "else:", *("    " + x for x in inner)]

    source = "\n".join(["def impl(step, q, w, q_r, w_r, par, st, dt, u):", *("    " + x for x in nest(flags))])
    scope: dict = {}
    exec(compile(source, f"<every_row of {', '.join(flags) or 'no flags'}>", "exec"), scope)  # noqa: S102
    return scope["impl"]


#: the types of the batch loop's arrays that the laws' compiled loops take (:func:`law_addresses`): the laws'
#: inputs and the command, (m, width) float64 column-major; the transfer's offsets and last command (m, 3)
#: row-major; flags per row; each row's law code
COLUMNS = types.Array(types.float64, 2, "F")
ROWS = types.Array(types.float64, 2, "C")
FLAGS = types.Array(types.boolean, 1, "C")
CODES = types.Array(types.int64, 1, "C")


def law_addresses(dispatch: ModuleType, codes, pars: tuple, sts: tuple) -> np.ndarray:
    """The machine addresses of each law's compiled loops in ``codes``, compiled for these records.

    Parameters
    ----------
    dispatch : module
        A dispatch table (:func:`table_for`).
    codes : iterable of int
        The laws the engine may run (the others get 0: not callable).
    pars, sts : tuple
        Every law's parameter and state records as the engine's loop receives them (their numba types are
        the compiled signature's).

    Returns
    -------
    numpy.ndarray, shape (3, n_laws), int64
        For :func:`call_at`: row 0 ``vector_<code>`` (every row of a block runs the law), row 1
        ``rows_<code>`` (its rows of a block of several laws, or with a transfer pending), row 2
        ``enter_<code>`` (the bumpless entry of one row). They are valid in this process only, so the loop
        takes them as an argument (its cached machine code holds none).

    Why: a compiled function that calls another links the callee's code into
    its own and LLVM optimises the whole again, once per variant of the
    caller. Every law's step linked into the engine's loop made it the
    costliest function of the package to compile (bench/README.md), and
    again for every variant. Called through its address, each law's loop is
    compiled once per record type and cached on its own.
    """
    out = np.zeros((3, len(pars)), dtype=np.int64)
    for code in codes:
        rec = (numba.typeof(pars[code]), numba.typeof(sts[code]))
        view = (COLUMNS,) * 4
        sigs = ((*view, *rec, types.float64, COLUMNS),
                (CODES, *view, *rec, types.float64, COLUMNS, ROWS, FLAGS, types.float64),
                (*view, types.intp, *rec, types.float64, types.float64, types.Tuple((ROWS, ROWS, FLAGS)), COLUMNS))
        for row, (kind, sig) in enumerate(zip(("vector", "rows", "enter"), sigs, strict=True)):
            fn = getattr(dispatch, f"{kind}_{code}")
            if sig not in fn.overloads:
                fn.compile(sig)
            cres = fn.overloads[sig]
            out[row, code] = cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)
    return out


@intrinsic
def call_at(typingctx, address, args):
    """Call the compiled function at ``address`` (int64, :func:`law_addresses`) with the tuple ``args``.

    numba's own calling convention for a function returning nothing; the
    callee must have been compiled for exactly ``args``' types (an array's
    layout is part of that: :data:`COLUMNS`). An error status the callee
    returns is passed on (the vector loops, compiled with numpy's error
    model, return none).
    """
    if not (isinstance(address, types.Integer) and isinstance(args, types.BaseTuple)):
        return None

    def codegen(context, builder, signature, llargs):
        arg_types = tuple(signature.args[1])
        values = [builder.extract_value(llargs[1], i) for i in range(len(arg_types))]
        fnty = context.call_conv.get_function_type(types.none, arg_types)
        callee = builder.inttoptr(llargs[0], fnty.as_pointer())
        status, _ = context.call_conv.call_function(builder, callee, types.none, arg_types, values)
        with cgutils.if_unlikely(builder, status.is_error):
            context.call_conv.return_status_propagate(builder, status)
        return context.get_dummy_value()

    return types.none(address, args), codegen


_LOCK = threading.Lock()
_MODULES: dict[str, ModuleType] = {}
_BY_NAMES: dict[tuple, ModuleType] = {}


def _source_digest(law: Law) -> str:
    h = hashlib.sha256(law.name.encode())
    for fn in (law.step, law.enter):
        if fn is not None:
            module = sys.modules[fn.py_func.__module__]
            h.update(Path(inspect.getsourcefile(module)).read_bytes())
    return h.hexdigest()


def dispatch_source(laws: list[Law]) -> str:
    """The dispatch table of ``laws`` as Python source: per law, its step bound to the loops of
    :mod:`attitude_sil.core.control.dispatch`, one line each, and its state record class.

    This is all the package generates: the names that vary with the
    installed laws. ``attitude-sil engine --source`` prints it.
    """
    lines = ['"""The dispatch table of the laws ' + ", ".join(x.name for x in laws) + ".",
             "",
             "Generated by attitude_sil.core.control.compiled.dispatch_source (do not edit): each law's",
             "compiled loops are attitude_sil/core/control/dispatch.py's, bound to the law's step, so that",
             'numba compiles and caches them law by law."""',
             "", "from collections import namedtuple", "", "from numba import njit", "",
             "from attitude_sil.core.control.compiled import VECTOR_STEP, LanesCompiler",
             "from attitude_sil.core.control.dispatch import enter_row, generic_enter_row, law_rows, vector_rows",
             "", f"LAWS = {tuple(x.name for x in laws)!r}"]
    own = "@njit(cache=True, error_model='numpy')"
    for i, law in enumerate(laws):
        step = law.step.py_func
        lines += ["", "", f"# law {i}: {law.name}", f"from {step.__module__} import {step.__name__} as _step_{i}"]
        if law.enter is not None:
            lines.append(f"from {law.enter.py_func.__module__} import {law.enter.py_func.__name__} as _enter_{i}")
        enter = (f"enter_row(_step_{i}, _enter_{i}" if law.enter is not None else f"generic_enter_row(_step_{i}, None")
        sat = bool(law.saturated)
        lines += [f"State_{i} = namedtuple('State_{i}', {list(state_layout(law))!r})",
                  f"_lane_step_{i} = njit(**VECTOR_STEP)(_step_{i}.py_func)",
                  "", "",
                  "@njit(cache=True, error_model='numpy', pipeline_class=LanesCompiler)",
                  f"def vector_{i}(q, w, q_r, w_r, par, st, dt, u):",
                  f"    vector_rows(_lane_step_{i}, {sat}, q, w, q_r, w_r, par, st, dt, u)",
                  "", "", own,
                  f"def rows_{i}(law, q, w, q_r, w_r, par, st, dt, u, offset, has_off, decay):",
                  f"    law_rows(_step_{i}, {i}, {sat}, law, (q, w, q_r, w_r), par, st, dt, u, "
                  "(offset, has_off, decay))",
                  "", "", own,
                  f"def enter_{i}(q, w, q_r, w_r, p, par, st, dt, decay, xfer, scratch):",
                  f"    {enter}, (q, w, q_r, w_r), p, par, st, dt, decay, xfer, scratch)"]
    lines.append("")
    return "\n".join(lines)


def _load(name: str, source: str) -> ModuleType:
    with _LOCK:
        if name in _MODULES:
            return _MODULES[name]
        folder = cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{name}.py"
        if not path.exists() or path.read_text() != source:
            tmp = folder / f".{name}.{os.getpid()}.{threading.get_ident()}.tmp"
            tmp.write_text(source)
            os.replace(tmp, path)  # atomic: processes generating the same module at once agree
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # numba's cache finds the module's classes by name
        spec.loader.exec_module(module)
        _MODULES[name] = module
        return module


def table_for(laws: tuple[Law, ...]) -> ModuleType:
    """The dispatch table of ``laws``, in that order (a law's code is its place), generated and imported once per
    process and law set (:func:`attitude_sil.core.control.registry.dispatch_module`: the registered laws')."""
    key = tuple((law.name, id(law)) for law in laws)
    if key not in _BY_NAMES:  # the laws' sources are read and hashed once per process
        source = dispatch_source(list(laws))
        digest = hashlib.sha256(source.encode())
        for law in laws:
            digest.update(_source_digest(law).encode())
        _BY_NAMES[key] = _load(f"attitude_sil_laws_{digest.hexdigest()[:16]}", source)
    return _BY_NAMES[key]
