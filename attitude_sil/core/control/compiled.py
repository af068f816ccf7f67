"""Compiled dispatch over a set of laws, generated as a module and cached by numba.

numba cannot index a tuple of functions at run time, and a closure over a
jitted step cannot be cached safely (numba does not see its free variables
change). So for each set of laws this module writes a small Python module,
named by a hash of the laws' source, into the user cache folder
(``$ATTITUDE_SIL_CACHE_DIR``, else ``$XDG_CACHE_HOME/attitude_sil``, else
``~/.cache/attitude_sil``) and imports it: numba then caches its functions
beside it like any other module, and an edited law gets a new hash. The
generated module holds:

* ``law_reset``, ``law_is_torque``, ``enter_at``: an if-chain over the codes,
  for the rare swap;
* each law's compiled loops, each compiled on its own: the batch engine calls
  them at their addresses (:func:`law_addresses`, :func:`call_at`), so that
  they are compiled once, not again inside every variant of the engine's
  loop, and the controller bank (the nodes with P = 1 and the stepwise
  driver) calls ``rows_<code>`` and ``enter_<code>`` of its active law from
  Python (one law's code to compile and load: an entry point inlining every
  law's step, as the bank had, took 73 s of a cold cache's compiling here,
  the package's costliest functions after the batch loop):
  ``vector_<code>(q, w, q_r, w_r, par, st, dt, u)``, the law's step on
  every row, with the arrays in column-major order (the episodes contiguous
  in every column) so that LLVM packs the episodes into SIMD lanes (the
  law's own step, unchanged, inlined by LLVM (:data:`VECTOR_STEP`) into a
  loop compiled with its arrays declared free of aliasing
  (:class:`LanesCompiler`); bench/README.md says why each is needed);
  ``rows_<code>``, its rows of a block of several laws one at a time, with
  the transfer offset; ``enter_<code>``, the bumpless entry of one row
  (``enter_at`` picks it by code);
* ``State_<code>``: each law's state record class.

:func:`from_template` makes a module of another compiled loop (the batch
engine's chunk) with the dispatch of a law set in place of its stubs.
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

from attitude_sil.core.control import registry
from attitude_sil.core.control.law import Law, state_layout

__all__ = ["dispatch_module", "from_template", "cache_dir", "LanesCompiler", "VECTOR_STEP", "every_row",
           "law_addresses", "call_at", "STUB_BEGIN", "STUB_END"]

#: the lines that delimit a template's stand-ins for the generated dispatch
STUB_BEGIN = "# >>> law dispatch stubs"
STUB_END = "# <<< law dispatch stubs"

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
    calls, scalar, on every PID step (30-45 ns per episode instead of 12-14
    in one run). With a loop per value, the condition is known inside each
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
        A generated dispatch module (:func:`dispatch_module`).
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
_BY_NAMES: dict[tuple[str, ...], ModuleType] = {}


def cache_dir() -> Path:
    """Where generated modules (and numba's cache of them) live."""
    base = os.environ.get("ATTITUDE_SIL_CACHE_DIR")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "attitude_sil"


def _source_digest(law: Law) -> str:
    h = hashlib.sha256(law.name.encode())
    for fn in (law.step, law.enter):
        if fn is not None:
            module = sys.modules[fn.py_func.__module__]
            h.update(Path(inspect.getsourcefile(module)).read_bytes())
    return h.hexdigest()


def _core_digest() -> str:
    """Every source file of ``attitude_sil.core``: what a law's step and the loop inline from the package.

    numba's cache sees only the generated module's own file, so an edit of an
    inlined helper (``control/kernels.py``, the wheel kernel) must change the
    generated module's name to be compiled again.
    """
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()


def _zero(dtype) -> str:
    return "False" if np.dtype(dtype) == np.bool_ else "0"


#: the names the stage code uses for the loop's variables, and what a template may rename them to
_STAGE_NAMES = ("law", "present", "q", "w", "q_r", "w_r", "dt", "u", "offset", "has_off", "decay", "at")


def _record_lines(laws: list[Law]) -> list[str]:
    """Each law's records out of their tuples, once (inside a loop each take costs reference counts)."""
    return [f"par_{i}, st_{i} = pars[{i}], sts[{i}]" for i in range(len(laws))]


def _clip_lines(i: int, u: str) -> list[str]:
    """Row ``p`` of the command ``u`` clipped to law ``i``'s ``u_max`` (a law that does not saturate itself)."""
    return ["for j in range(3):", f"    {u}[p, j] = min(max({u}[p, j], -par_{i}.u_max), par_{i}.u_max)"]


def _rows_lines(i: int, law: Law, names: dict[str, str]) -> list[str]:
    """Law ``i``'s command on each row that runs it, one row at a time: its step, the transfer offset, the clip."""
    n = {k: names.get(k, k) for k in _STAGE_NAMES}
    clip = _clip_lines(i, n["u"])
    out = [f"for p in range({n['law']}.shape[0]):",
           f"    if {n['law']}[p] == {i}:",
           f"        _step_{i}({n['q']}, {n['w']}, {n['q_r']}, {n['w_r']}, p, par_{i}, st_{i}, {n['dt']}, {n['u']})",
           f"        if {n['has_off']}[p]:",
           f"            offset_row({n['u']}, p, {n['offset']}, {n['has_off']}, {n['decay']})",
           *("            " + c for c in clip)]
    if not law.saturated:
        out += ["        else:", *("            " + c for c in clip)]
    return out


def _stage_lines(laws: list[Law], names: dict[str, str]) -> list[str]:
    """The batch engine's command stage: each law's compiled loops called at their addresses.

    ``at`` (:func:`law_addresses`): ``vector_<code>`` when every row runs one
    law with no transfer pending (its arrays column-major), then the clip for a
    law that does not saturate; else ``rows_<code>`` for each law present (its
    step, the transfer offset and the clip, row by row). ``names`` renames the
    loop's variables (:data:`_STAGE_NAMES`).
    """
    n = {k: names.get(k, k) for k in _STAGE_NAMES}
    view = f"{n['q']}, {n['w']}, {n['q_r']}, {n['w_r']}"
    # the common case first: every row runs one law with no transfer offset pending; then the law's step
    # runs in a loop of its own with no test per row (a test per row kept the PID's loop from being
    # optimised: bench/README.md)
    out = ["only = " + n["law"] + "[0] if " + n["law"] + ".shape[0] > 0 else -1",
           f"for p in range({n['law']}.shape[0]):",
           f"    if {n['law']}[p] != only or {n['has_off']}[p]:",
           "        only = -1",
           "        break"]
    for i, law in enumerate(laws):
        out += [f"if only == {i}:",
                f"    call_at({n['at']}[0, {i}], ({view}, par_{i}, st_{i}, {n['dt']}, {n['u']}))"]
        if not law.saturated:
            out += [f"    for p in range({n['law']}.shape[0]):", *("        " + c for c in _clip_lines(i, n["u"]))]
        out += [f"elif only < 0 and {n['present']}[{i}]:",
                f"    call_at({n['at']}[1, {i}], ({n['law']}, {view}, par_{i}, st_{i}, {n['dt']}, {n['u']}, "
                f"{n['offset']}, {n['has_off']}, {n['decay']}))"]
    return out


def _zero_lines(law: Law, st: str) -> list[str]:
    """Zero row ``p`` of the law's state record ``st``."""
    out = []
    for name, (width, dtype) in state_layout(law).items():
        out += [f"for j in range({int(width)}):", f"    {st}.{name}[p, j] = {_zero(dtype)}"]
    return out


def _entry_lines(i: int, law: Law) -> list[str]:
    """The bumpless entry of row p into law i (``par_{i}``, ``st_{i}``); the expression's value: whether a
    decaying offset remains. A law with no ``enter`` of its own keeps its fresh state and hands the
    difference to the offset."""
    args = f"q, w, q_r, w_r, p, par_{i}, st_{i}, dt"
    if law.enter is not None:
        return [f"return _enter_{i}({args}, decay, u_last, offset)"]
    return ["if decay > 0.0:",
            f"    _step_{i}({args}, scratch)",
            *("    " + x for x in _zero_lines(law, f"st_{i}")),
            "    for j in range(3):",
            "        offset[p, j] = u_last[p, j] - scratch[p, j]",
            "    return True",
            "return False"]


def _dispatch_source(laws: list[Law]) -> str:
    lines = ['"""Generated by attitude_sil.core.control.compiled for the laws ' + ", ".join(x.name for x in laws)
             + ' (do not edit)."""', "", "from collections import namedtuple", "",
             "from numba import njit", "", "from attitude_sil.core.control.kernels import offset_row", ""]
    for i, law in enumerate(laws):
        mod = law.step.py_func.__module__
        lines.append(f"from {mod} import {law.step.py_func.__name__} as _step_{i}")
        if law.enter is not None:
            lines.append(f"from {law.enter.py_func.__module__} import {law.enter.py_func.__name__} as _enter_{i}")
    lines += ["", "from attitude_sil.core.control.compiled import VECTOR_STEP, LanesCompiler, call_at, every_row"]
    lines.append("")
    lines.append(f"LAWS = {tuple(x.name for x in laws)!r}")
    for i, law in enumerate(laws):
        lines.append(f"State_{i} = namedtuple('State_{i}', {list(state_layout(law))!r})")

    def chain(body_of, indent="    "):
        out = []
        for i, law in enumerate(laws):
            out.append(f"{indent}{'if' if i == 0 else 'elif'} code == {i}:")
            out.extend(f"{indent}    {b}" for b in body_of(i, law))
        return out

    jit = "@njit(cache=True, inline='always')"
    own = "@njit(cache=True, error_model='numpy')"  # compiled on their own (called at their address, or by the bank)
    loops = []
    for i, law in enumerate(laws):
        loops += ["", "", f"_lane_step_{i} = njit(**VECTOR_STEP)(_step_{i}.py_func)", "", "",
                  "@njit(cache=True, error_model='numpy', pipeline_class=LanesCompiler)",
                  f"def vector_{i}(q, w, q_r, w_r, par, st, dt, u):",
                  "    # every row's command by this law: the rows are SIMD lanes when the arrays are",
                  "    # column-major (a column's episodes contiguous)",
                  f"    every_row(_lane_step_{i}, q, w, q_r, w_r, par, st, dt, u)",
                  "", "", own,
                  f"def rows_{i}(law, q, w, q_r, w_r, par_{i}, st_{i}, dt, u, offset, has_off, decay):",
                  "    # the command of the rows that run this law, one at a time (a block of several laws, or",
                  "    # a transfer pending)",
                  *("    " + x for x in _rows_lines(i, law, {})),
                  "", "", jit,
                  f"def _entry_{i}(q, w, q_r, w_r, p, par_{i}, st_{i}, dt, decay, u_last, offset, scratch):",
                  *("    " + x for x in _entry_lines(i, law)),
                  "", "", own,
                  f"def enter_{i}(q, w, q_r, w_r, p, par_{i}, st_{i}, dt, decay, xfer, scratch):",
                  "    # the bumpless entry of row p (its state reset); xfer: the transfer's (u_last, offset,",
                  "    # has_off), has_off[p]: a decaying offset remains",
                  "    u_last, offset, has_off = xfer",
                  f"    has_off[p] = _entry_{i}(q, w, q_r, w_r, p, par_{i}, st_{i}, dt, decay, u_last, offset, "
                  "scratch)"]
    torque = " or ".join(f"code == {i}" for i, x in enumerate(laws) if x.output == "torque") or "False"
    lines += ["", "", jit, "def law_reset(code, p, sts):", "    # zero row p of the law's state",
              *chain(lambda i, law: [f"st = sts[{i}]", *_zero_lines(law, "st")]),
              "", "", jit, "def enter_at(code, at, view, p, pars, sts, dt, decay, xfer, scratch):",
              "    # the law's bumpless entry of row p called at its address (at: law_addresses): has_off[p]",
              "    q, w, q_r, w_r = view",
              *chain(lambda i, law: [f"call_at(at[2, {i}], (q, w, q_r, w_r, p, pars[{i}], sts[{i}], dt, decay, "
                                     "xfer, scratch))"]),
              "", "", jit, "def law_is_torque(code):", f"    return {torque}",
              *loops,
              ""]
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


def dispatch_module(law_names: tuple[str, ...] | None = None) -> ModuleType:
    """The generated dispatch module of these laws (default: every registered law), in that order."""
    key = tuple(law_names or registry.names())
    if key not in _BY_NAMES:  # the laws' sources are read and hashed once per process
        _BY_NAMES[key] = _dispatch_module(key)
    return _BY_NAMES[key]


def _dispatch_module(law_names: tuple[str, ...]) -> ModuleType:
    laws = [registry.get(n) for n in law_names]
    source = _dispatch_source(laws)
    digest = hashlib.sha256((source + _core_digest()).encode())
    for law in laws:
        digest.update(_source_digest(law).encode())
    return _load(f"attitude_sil_laws_{digest.hexdigest()[:16]}", source)


def from_template(template: ModuleType, law_names: tuple[str, ...] | None = None) -> ModuleType:
    """``template``'s source with the law set's dispatch in place of its stubs and markers.

    The template is an ordinary module of the package (linted and read like
    any other); its imports must be absolute. Between :data:`STUB_BEGIN` and
    :data:`STUB_END` it has stand-ins that keep it importable: they become an
    import of the generated ``enter_at``, ``law_reset`` and ``law_is_torque``.
    A line ``# @laws records`` becomes the laws' records taken out of ``pars``
    and ``sts`` once, and a line ``# @laws stage NAME=VAR ...`` the command
    stage written out in place (no call: an inlined call would copy every
    law's records each step), with the loop's variables renamed as given.
    """
    key = tuple(law_names or registry.names())
    dispatch = dispatch_module(key)
    laws = [registry.get(n) for n in key]
    text = Path(inspect.getsourcefile(template)).read_text()
    head, rest = text.split(STUB_BEGIN, 1)
    _, tail = rest.split(STUB_END, 1)
    imports = [f"from {dispatch.__name__} import enter_at, law_is_torque, law_reset",
               "from attitude_sil.core.control.compiled import call_at"]
    lines = []
    for line in (head + "\n".join(imports) + "\n" + tail).split("\n"):
        marker = line.strip()
        indent = line[: len(line) - len(line.lstrip())]
        if marker == "# @laws records":
            lines += [indent + x for x in _record_lines(laws)]
        elif marker.startswith("# @laws stage"):
            names = dict(item.split("=", 1) for item in marker.split()[3:])
            lines += [indent + x for x in _stage_lines(laws, names)]
        else:
            lines.append(line)
    source = "\n".join(lines)
    digest = hashlib.sha256((source + dispatch.__name__).encode()).hexdigest()[:16]
    return _load(f"{template.__name__.rpartition('.')[2]}_{digest}", source)
