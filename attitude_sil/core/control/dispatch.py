"""The laws' compiled loops, written once for every law, and how a compiled loop reaches a law chosen at run time.

A law's ``step`` computes one row (:mod:`attitude_sil.core.control.law`).
The loops here run it over the rows of a block, and they take the step as
their first argument: the dispatch table of
:mod:`attitude_sil.core.control.compiled` binds each registered law's step
to them, one line a law, so that numba compiles and caches every law's loops
on their own. The batch engine calls those compiled loops at their machine
addresses (:func:`~attitude_sil.core.control.compiled.call_at`); the
controller bank (the nodes and the stepwise driver) calls them as functions.

* :func:`vector_rows`: every row runs the law, with no transfer pending (the
  common case; its rows are SIMD lanes when the arrays are column-major);
* :func:`law_rows`: the rows of a block whose code is this law's, one at a
  time, with the bumpless transfer's decaying offset;
* :func:`enter_row` / :func:`generic_enter_row`: the bumpless entry of one
  row into the law.

A compiled loop cannot index a tuple of differently typed records with a
run-time law code, so the batch loop holds the laws' records as one tuple
``recs`` of ``(par, st)`` pairs and walks it with ``numba.literal_unroll``
(:func:`command_stage`, :func:`reset_row`, :func:`enter_at`): the loop body
is compiled once per law, and the pair whose position equals the code runs.
These three are compiled as functions of their own (numba's literal_unroll
does not run inside a function that numba inlines) and marked for LLVM to
inline (``forceinline``): a call per step would pass every law's records by
value.
"""

from __future__ import annotations

from numba import literal_unroll, njit, types
from numba.extending import overload

from attitude_sil.core.control.compiled import call_at, every_row
from attitude_sil.core.control.kernels import offset_row

__all__ = ["vector_rows", "law_rows", "enter_row", "generic_enter_row", "zero_row", "command_stage", "reset_row",
           "enter_at", "only_law"]


@njit(inline="always")
def clip_row(u, p, u_max):
    """Row ``p`` of the command ``u`` (n, 3) clipped to +-``u_max`` (a law that does not saturate itself)."""
    for j in range(3):
        u[p, j] = min(max(u[p, j], -u_max), u_max)


@njit(inline="always")
def vector_rows(lane_step, saturated, q, w, q_r, w_r, par, st, dt, u):
    """The law's command on every row of ``u`` (m, 3), then the clip to ``par.u_max`` unless it saturates itself.

    ``lane_step``: the law's step compiled to be inlined by LLVM, run on
    every row by :func:`~attitude_sil.core.control.compiled.every_row`.
    Arrays column-major (m, width).
    """
    every_row(lane_step, q, w, q_r, w_r, par, st, dt, u)
    if not saturated:
        for p in range(u.shape[0]):
            clip_row(u, p, par.u_max)


@njit(inline="always")
def law_rows(step, code, saturated, law, view, par, st, dt, u, transfer):
    """The command of each row ``p`` with ``law[p] == code``: the step, the transfer's offset, the clip.

    ``view``: the law's inputs (q, w, q_r, w_r); ``transfer``: ``(offset,
    has_off, decay)``, the bumpless transfer's decaying offset (m, 3), (m,)
    (:func:`~attitude_sil.core.control.kernels.offset_row`); a row with an
    offset is clipped whatever the law, since the offset can take it past
    ``u_max``.
    """
    q, w, q_r, w_r = view
    offset, has_off, decay = transfer
    for p in range(law.shape[0]):
        if law[p] == code:
            step(q, w, q_r, w_r, p, par, st, dt, u)
            if has_off[p]:
                offset_row(u, p, offset, has_off, decay)
                clip_row(u, p, par.u_max)
            elif not saturated:
                clip_row(u, p, par.u_max)


def zero_row(st, p):
    """Zero row ``p`` of every field of the state record ``st`` (a NamedTuple of (n, width) arrays)."""
    for a in st:
        a[p, :] = 0


@overload(zero_row)
def _zero_row(st, p):
    # one loop per field: the fields' dtypes differ (float, bool), so no loop over the record can type them all.
    # Not inline="always": numba's own inlining of this overload lost a store that follows the call in the
    # caller (generic_enter_row's has_off[p] = True; test_engine_source holds it); as a call, LLVM inlines it
    if not isinstance(st, types.BaseTuple):
        return None
    lines = ["def impl(st, p):"]
    for i, t in enumerate(st.types):
        zero = "False" if isinstance(t.dtype, types.Boolean) else "0.0"
        lines += [f"    for j in range(st[{i}].shape[1]):", f"        st[{i}][p, j] = {zero}"]
    if len(st.types) == 0:
        lines.append("    return")
    scope: dict = {}
    exec(compile("\n".join(lines), f"<zero_row of {len(st.types)} fields>", "exec"), scope)  # noqa: S102
    return scope["impl"]


@njit(inline="always")
def enter_row(step, enter, view, p, par, st, dt, decay, xfer, scratch):
    """The law's own bumpless entry of row ``p`` (its ``enter``); ``view``: the law's inputs (q, w, q_r, w_r);
    ``xfer``: the transfer's (u_last, offset, has_off), ``has_off[p]`` set when a decaying offset remains.
    ``step`` and ``scratch`` are unused here (the signature is :func:`generic_enter_row`'s)."""
    q, w, q_r, w_r = view
    u_last, offset, has_off = xfer
    has_off[p] = enter(q, w, q_r, w_r, p, par, st, dt, decay, u_last, offset)


@njit(inline="always")
def generic_enter_row(step, enter, view, p, par, st, dt, decay, xfer, scratch):
    """The bumpless entry of row ``p`` into a law with no ``enter`` of its own.

    The law keeps its fresh state; its first command on that state is
    computed into ``scratch`` (then the state is zeroed again), and the
    difference to the last command, ``u_last[p] - scratch[p]``, becomes the
    offset that decays by ``decay`` per step. With no decay (an abrupt
    swap) there is no offset.
    """
    q, w, q_r, w_r = view
    u_last, offset, has_off = xfer
    if decay > 0.0:
        step(q, w, q_r, w_r, p, par, st, dt, scratch)
        zero_row(st, p)
        for j in range(3):
            offset[p, j] = u_last[p, j] - scratch[p, j]
        has_off[p] = True
    else:
        has_off[p] = False


@njit(inline="always")
def only_law(law, has_off):
    """The one law code every row runs with no transfer offset pending, or -1 (several, a transfer, no rows)."""
    only = law[0] if law.shape[0] > 0 else -1
    for p in range(law.shape[0]):
        if law[p] != only or has_off[p]:
            return -1
    return only


@njit(forceinline=True, error_model="numpy", _nrt=False)
def command_stage(law, present, view, recs, dt, u, xfer, decay, at):
    """Every row's command by its law, through the laws' compiled loops at their addresses ``at`` (3, n_laws).

    When every row runs one law with no transfer pending (the common case),
    that law's ``vector`` loop (``at[0]``) runs alone with no test per row;
    else each law ``present`` in the block runs its ``rows`` loop
    (``at[1]``). ``view``: the laws' inputs (q, w, q_r, w_r), (m, width)
    column-major; ``recs``: each law's ``(par, st)``, in code order; ``xfer``:
    the transfer's (u_last, offset, has_off).
    """
    q, w, q_r, w_r = view
    offset, has_off = xfer[1], xfer[2]
    only = only_law(law, has_off)
    code = 0
    for rec in literal_unroll(recs):
        if only == code:
            call_at(at[0, code], (q, w, q_r, w_r, rec[0], rec[1], dt, u))
        elif only < 0 and present[code]:
            call_at(at[1, code], (law, q, w, q_r, w_r, rec[0], rec[1], dt, u, offset, has_off, decay))
        code += 1


@njit(forceinline=True, error_model="numpy", _nrt=False)
def reset_row(code, p, recs):
    """Zero row ``p`` of law ``code``'s state (``recs``: each law's ``(par, st)``)."""
    i = 0
    for rec in literal_unroll(recs):
        if i == code:
            zero_row(rec[1], p)
        i += 1


@njit(forceinline=True, error_model="numpy", _nrt=False)
def enter_at(code, at, view, p, recs, dt, decay, xfer, scratch):
    """The bumpless entry of row ``p`` into law ``code``, its ``enter`` loop called at ``at[2, code]``."""
    q, w, q_r, w_r = view
    i = 0
    for rec in literal_unroll(recs):
        if i == code:
            call_at(at[2, i], (q, w, q_r, w_r, p, rec[0], rec[1], dt, decay, xfer, scratch))
        i += 1
