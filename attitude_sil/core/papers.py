"""The five papers as the package names them, and the published constants quoted in several places.

A light module (no numpy): the command line's help reads it without loading
the engine. The papers themselves are summarised in docs/papers.md.
"""

from __future__ import annotations

__all__ = ["PAPERS", "PAPER_000_COMPARISON_GAINS", "PAPER_000_TABLE_1_DURATION"]

#: the papers' ids (docs/papers.md): 000 HST, 001 Hawai'iSat-1, 002 flexible axis, 003 CubeSat, 004 pitch FLC
PAPERS = ("000", "001", "002", "003", "004")

#: the PID used for the comparison in paper 000 (Kp, Ki, Kd, N)
PAPER_000_COMPARISON_GAINS = (52.995, 2.488, 132.442, 4.748)

#: run length of the Table 1 comparison, s: identified by least squares of log(project / paper) over the 15
#: cells (the paper gives none; 9-14 s scanned, residual RMS of the log ratio 0.47 at 10.5 s, docs/fidelity.md)
PAPER_000_TABLE_1_DURATION = 10.5
