"""Fuzzy inference shared by the hybrid fuzzy PID (paper 003) and the GA-FLC (paper 004).

Both controllers use two inputs with seven triangular membership functions
each, a 7x7 rule table whose entries name one of seven output sets
(1..7 = NB/NL, NM, NS, ZO/ZR, PS, PM, PB/PL, paper 004 Table 1), product
inference and weighted-average defuzzification over the output-set centres.

Membership functions are given by their seven vertices ``c1 = -1 < c2 < ...
< c7 = 1`` on the normalised universe; MF i peaks at ``c_i`` and falls to zero
at its neighbours, the outer two are shoulders (inputs are clipped to
[-1, 1]). Such a set partitions unity: the memberships of any input sum to 1,
so the weighted average needs no division guard.

The functions here are the numpy reference (vectorised over a leading batch
shape, no loop over rules); the controllers call the compiled
:func:`attitude_sil.core.plant.kernels.fuzzy_infer`, which exploits that at most two
sets per input are active (4 of the 49 rules fire) and is tested equal to
:func:`infer`.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.errors import ScenarioError

__all__ = [
    "LABELS",
    "UNIFORM_VERTICES",
    "vertices_from_ratios",
    "memberships",
    "infer",
    "PAPER_003_TABLE_3",
    "PAPER_004_TABLE_2",
    "FUZZY_PID_DEFAULT_RULES",
]

LABELS = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
UNIFORM_VERTICES = np.linspace(-1.0, 1.0, 7)

NB, NM, NS, ZO, PS, PM, PB = range(1, 8)

#: Paper 003 Table 3 as printed: rows are the change of error Δe (NL..PL), columns the error e (NL..PL).
PAPER_003_TABLE_3 = np.array(
    [
        [NB, NB, NB, NM, NS, ZO, PS],
        [NB, NB, NM, NS, ZO, PS, PM],
        [NB, NM, NS, ZO, PS, PM, PB],
        [NM, NS, ZO, PS, PM, PB, PB],
        [NS, ZO, PS, PM, PB, PB, PB],
        [ZO, PS, PM, PB, PB, PB, PB],
        [PB, PB, PB, PB, PB, PB, PB],
    ],
    dtype=np.int64,
)

#: Paper 004 Table 2 (GA-generated rules): rows are the angle θ (NB..PB), columns the rate q (NB..PB).
PAPER_004_TABLE_2 = np.array(
    [
        [NS, NM, NB, NB, PB, PS, PS],
        [NS, PM, ZO, NM, PS, ZO, PB],
        [ZO, NB, NB, NM, PS, ZO, PM],
        [ZO, PS, NB, ZO, PM, PS, NB],
        [PM, NB, NB, PS, PS, NM, NS],
        [NM, NB, NB, PM, NS, ZO, ZO],
        [PS, NB, PS, PB, PB, NS, NS],
    ],
    dtype=np.int64,
)


#: Default rules of the hybrid fuzzy PID. Paper 003's printed Table 3 has PS at
#: (Δe, e) = (ZR, ZR), which would push at zero error; its rows NL..PM are the
#: standard table's rows NM..PL, so the print lost the first row and repeated a
#: last one. This is that standard (MacVicar-Whelan) table, odd-symmetric with
#: ZO at the centre (assumed; docs/getting-started.md, "Controllers and live swaps").
FUZZY_PID_DEFAULT_RULES = np.vstack([[1, 1, 1, 1, 2, 3, 4], PAPER_003_TABLE_3[:-1]])


def vertices_from_ratios(ratios: np.ndarray) -> np.ndarray:
    """MF vertices from six positive distance ratios (paper 004 eq. 5).

    ``w1 = 1 / (a1 + a2 + a3)``, ``c_{i+1} = c_i + w1 a_i`` from ``c1 = -1``
    (so ``c4 = 0``), and ``w2 = 1 / (a4 + a5 + a6)`` on the positive side up to
    ``c7 = 1``.

    Parameters
    ----------
    ratios : ndarray, shape (..., 6), all > 0

    Returns
    -------
    ndarray, shape (..., 7), strictly increasing from -1 to 1.
    """
    a = np.asarray(ratios, dtype=float)
    if np.any(a <= 0.0) or not np.all(np.isfinite(a)):
        raise ScenarioError("membership-function ratios must be positive and finite")
    neg = np.cumsum(a[..., :3], axis=-1) / np.sum(a[..., :3], axis=-1, keepdims=True)
    pos = np.cumsum(a[..., 3:], axis=-1) / np.sum(a[..., 3:], axis=-1, keepdims=True)
    c1 = -np.ones(a.shape[:-1] + (1,))
    out = np.concatenate([c1, -1.0 + neg[..., :2], np.zeros_like(c1), pos[..., :2], np.ones_like(c1)], axis=-1)
    return out


def memberships(x: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Degrees of membership of x in the seven triangular sets.

    Parameters
    ----------
    x : ndarray, shape S
        Normalised input; clipped to [-1, 1].
    vertices : ndarray, shape (7,) or S + (7,)

    Returns
    -------
    ndarray, shape S + (7,), each row summing to 1.
    """
    x = np.clip(np.asarray(x, dtype=float), -1.0, 1.0)[..., None]
    c = np.broadcast_to(vertices, x.shape[:-1] + (7,))
    left = c[..., :-1]
    right = c[..., 1:]
    # t in [0, 1] along each of the six segments; x lies in exactly one (or on a vertex)
    t = np.clip((x - left) / (right - left), 0.0, 1.0)
    inside = (x >= left) & (x <= right)
    first = np.argmax(inside, axis=-1)  # the segment x lies in
    t_seg = np.take_along_axis(t, first[..., None], axis=-1)[..., 0]
    mu = np.zeros(x.shape[:-1] + (7,))
    np.put_along_axis(mu, first[..., None], (1.0 - t_seg)[..., None], axis=-1)
    np.put_along_axis(mu, (first + 1)[..., None], t_seg[..., None], axis=-1)
    return mu


def infer(mu_row: np.ndarray, mu_col: np.ndarray, rules: np.ndarray, out_centres: np.ndarray) -> np.ndarray:
    """Product inference and weighted-average defuzzification.

    Parameters
    ----------
    mu_row, mu_col : ndarray, shape S + (7,)
        Memberships of the row input and the column input of the rule table.
    rules : ndarray of int, shape (7, 7) or S + (7, 7)
        Output set (1..7) of each rule.
    out_centres : ndarray, shape (7,) or S + (7,)
        Centres of the output sets on the normalised output universe.

    Returns
    -------
    ndarray, shape S: crisp output in [-1, 1].
    """
    r = np.asarray(rules) - 1
    centres = np.asarray(out_centres, dtype=float)
    shape = np.broadcast_shapes(mu_row.shape[:-1], centres.shape[:-1], r.shape[:-2])
    c_b = np.broadcast_to(centres, shape + (7,))
    r_b = np.broadcast_to(r.reshape(r.shape[:-2] + (49,)), shape + (49,))
    cons = np.take_along_axis(c_b, r_b, axis=-1).reshape(shape + (7, 7))  # consequent of each rule
    w = mu_row[..., :, None] * mu_col[..., None, :]
    return np.sum(w * cons, axis=(-2, -1)) / np.sum(w, axis=(-2, -1))
