"""Slips neither receiver flagged, found as steps in the whole-flight float solution.

What this module owns: where an arc's constant changes without a loss-of-lock flag, and the
table with such arcs split in two.

A slip the receivers did not flag (and the conditioning did not find) can only hide where an
arc's usable phase has a hole (a radio gap, a half-cycle period, a dip below the mask): those
are the candidates. Each is tested as a step parameter added to the whole-flight float system
(Baarda's w-test): its normal column is the sum of the epochs' reduced equations from the step
on, cumulated from the end, so each candidate costs one product with the covariance.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from groundstation.solve.integrity.normal import EpochSystem, FloatArcs, reduced
from groundstation.solve.integrity.table import PhaseTable

FloatArray = npt.NDArray[np.float64]

SPLIT_MIN_CYC = 0.2
"""A step must be at least this large (a slip is a whole or half cycle; less is a trend)."""
SPLIT_MIN_EPOCHS = 5
"""Each side of a step needs this many epochs."""
STEP_W = 5.0
"""Baarda's w of a step parameter beyond which the step is taken as real (normal
distribution: 6e-7 two-sided; candidates are few hundred per flight)."""


def step_tests(tab: PhaseTable, sys: EpochSystem, fl: FloatArcs,
               nominal_s: float) -> list[tuple[int, int, float, float]]:
    """Unflagged steps in the arcs, by Baarda's w-test of a step parameter added to the
    whole-flight float system.

    A slip the receivers did not flag (and the conditioning did not find) can only hide where
    an arc's usable phase has a hole (a radio gap, a half-cycle period, a dip below the mask):
    those are the candidates, each arc's first usable epoch after a hole longer than 1.5
    nominal intervals. For a step from epoch ``k`` on, its normal column is the sum of the
    epochs' reduced equations from ``k`` on (cumulated from the end), so every candidate costs
    one dot product with the covariance.

    Returns:
        (arc, row of the first epoch after the step, w, step size [cycles]) of the most
        significant step of each arc whose ``|w| > STEP_W`` and step above
        :data:`SPLIT_MIN_CYC`.
    """
    red, rhs = reduced(sys)
    arc = np.where(sys.phase_used, tab.arc, -1)
    na = tab.n_arcs
    a_hat = np.nan_to_num(fl.a)
    n_ep, n_sv = arc.shape
    t_s = (tab.t_ns - tab.t_ns[0]) / 1e9
    out: list[tuple[int, int, float, float]] = []
    for j in range(n_sv):
        col = arc[:, j]
        for a in np.unique(col[col >= 0]).tolist():
            rows = np.flatnonzero(col == a)
            if rows.size < 2 * SPLIT_MIN_EPOCHS:
                continue
            gaps = np.flatnonzero(np.diff(t_s[rows]) > 1.5 * nominal_s) + 1
            gaps = gaps[(gaps >= SPLIT_MIN_EPOCHS) & (gaps <= rows.size - SPLIT_MIN_EPOCHS)]
            if gaps.size == 0:
                continue
            # rows of the reduced matrices for this slot, mapped to arcs
            m = red[rows, j, :]  # (n_rows, n_sv)
            dense = np.zeros((rows.size, na))
            arcs_r = arc[rows]
            ok = arcs_r >= 0
            rr = np.broadcast_to(np.arange(rows.size)[:, None], ok.shape)[ok]
            np.add.at(dense, (rr, arcs_r[ok]), m[ok])
            cum = np.cumsum(dense[::-1], axis=0)[::-1]
            bcum = np.cumsum(rhs[rows, j][::-1])[::-1]
            c = cum[gaps]  # (n_gaps, na)
            g = bcum[gaps] - c @ a_hat
            nss = c[:, a]
            var = nss - np.einsum("ki,ij,kj->k", c, fl.q, c)
            var = np.maximum(var, 1e-12)
            w = g / np.sqrt(var)
            size = g / var
            k = int(np.argmax(np.abs(w)))
            if abs(w[k]) > STEP_W and abs(size[k]) > SPLIT_MIN_CYC:
                out.append((a, int(rows[gaps[k]]), float(w[k]), float(size[k])))
    return out


def split_arcs(tab: PhaseTable, steps: list[tuple[int, int]]) -> PhaseTable:
    """The table with each (arc, epoch) of ``steps`` split into two arcs there."""
    arc = tab.arc.copy()
    sv = list(tab.arc_sv.tolist())
    n = tab.n_arcs
    for a, row in steps:
        m = (arc == a)
        m[:row] = False
        arc[m] = n
        sv.append(int(tab.arc_sv[a]))
        n += 1
    return replace(tab, arc=arc, n_arcs=n, arc_sv=np.asarray(sv, dtype=np.int64))


