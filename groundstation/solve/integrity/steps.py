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

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import numpy.typing as npt

from groundstation.solve.integrity.normal import EpochSystem, FloatArcs, reduced
from groundstation.solve.integrity.table import PhaseTable

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

SPLIT_MIN_CYC = 0.2
"""A step must be at least this large (a slip is a whole or half cycle; less is a trend)."""
SPLIT_MIN_EPOCHS = 5
"""Each side of a step needs this many epochs."""
STEP_W = 5.0
"""Baarda's w of a step parameter beyond which the step is taken as real (normal
distribution: 6e-7 two-sided; candidates are few hundred per flight)."""


def _from_on(red: FloatArray, rhs: FloatArray, arc: IntArray, rows: IntArray, j: int, na: int
             ) -> tuple[FloatArray, FloatArray]:
    """A step of slot ``j``'s arc (at ``rows``) from each of its rows on: its normal column in
    the arcs' constants ((n_rows, na): the epochs' reduced equations of the slot, mapped to
    arcs and summed from that row to the arc's end) and its right-hand side ((n_rows,))."""
    dense = np.zeros((rows.size, na))
    arcs_r = arc[rows]
    ok = arcs_r >= 0
    rr = np.broadcast_to(np.arange(rows.size)[:, None], ok.shape)[ok]
    np.add.at(dense, (rr, arcs_r[ok]), red[rows, j, :][ok])
    cum = np.cumsum(dense[::-1], axis=0)[::-1]
    bcum = np.cumsum(rhs[rows, j][::-1])[::-1]
    return cum, bcum


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
            if tab.decided is not None:  # a phase carried on a decision: a candidate too
                gaps = np.union1d(gaps, np.flatnonzero(tab.decided[rows, j]))
            gaps = gaps[(gaps >= SPLIT_MIN_EPOCHS) & (gaps <= rows.size - SPLIT_MIN_EPOCHS)]
            if gaps.size == 0:
                continue
            w, info, g = _step_w(red, rhs, arc, rows, j, a, gaps, fl)
            size = g / info
            k = int(np.argmax(np.abs(w)))
            if abs(w[k]) > STEP_W and abs(size[k]) > SPLIT_MIN_CYC:
                out.append((a, int(rows[gaps[k]]), float(w[k]), float(size[k])))
    return out


def _step_w(red: FloatArray, rhs: FloatArray, arc: IntArray, rows: IntArray, j: int, a: int,
            at: IntArray, fl: FloatArcs) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Steps of arc ``a`` (slot ``j``, at ``rows``) from each of its rows ``at`` on, tested
    against the whole-flight float system: (Baarda's w, the step's information [1/cycle^2]:
    its variance's inverse, the step's right-hand side)."""
    cum, bcum = _from_on(red, rhs, arc, rows, j, fl.a.size)
    c = cum[at]  # (n_at, na)
    g = bcum[at] - c @ np.nan_to_num(fl.a)
    info = np.maximum(c[:, a] - np.einsum("ki,ij,kj->k", c, fl.q, c), 1e-12)
    return g / np.sqrt(info), info, g


def split_arcs(tab: PhaseTable, steps: list[tuple[int, int]]) -> PhaseTable:
    """The table with each (arc, epoch) of ``steps`` split into two arcs there (an arc may be
    split at several epochs: the later part is cut off first, so that each cut still finds
    the arc it names)."""
    arc = tab.arc.copy()
    sv = list(tab.arc_sv.tolist())
    n = tab.n_arcs
    for a, row in sorted(steps, key=lambda s: -s[1]):
        m = (arc == a)
        m[:row] = False
        arc[m] = n
        sv.append(int(tab.arc_sv[a]))
        n += 1
    # a piece split off may have stepped by half a cycle: it is on the half-cycle lattice; so
    # is the part before a cut at a half cycle put back (that moved the phases before it)
    whole = (None if tab.arc_whole is None
             else np.concatenate([tab.arc_whole, np.zeros(n - tab.n_arcs, dtype=bool)]))
    if whole is not None and tab.put_back is not None:
        for a, row in steps:
            if tab.put_back[row, int(tab.arc_sv[a])]:
                whole[a] = False
    return replace(tab, arc=arc, n_arcs=n, arc_sv=np.asarray(sv, dtype=np.int64),
                   arc_whole=whole)




HALF_CYCLE = 0.5
"""The smallest amount by which a decision of the conditioning can be wrong [cycles]: a
squaring loop's half cycle."""
POWER = 0.8
"""Probability with which a step must be detected for an arc's continuity across a gap to be
relied on (Baarda's reliability; the usual 80 %)."""


def split_at_gaps(tab: PhaseTable, doubts: list[GapDoubt]) -> PhaseTable:
    """The table with the arcs each doubt cuts (:attr:`GapDoubt.cut`) split at its gap."""
    return split_arcs(tab, [(a, d.row) for d in doubts for a in d.cut])


@lru_cache(maxsize=32)
def _differences(n: int) -> FloatArray:
    """An orthonormal basis (n x n-1) of the differences between ``n`` arcs: where a gap's
    test runs, free of what all arcs share (the clocks)."""
    basis: FloatArray = np.linalg.qr(np.eye(n) - 1.0 / n)[0][:, : n - 1]
    basis.flags.writeable = False  # shared by every gap with n arcs, as _patterns
    return basis


@lru_cache(maxsize=32)
def _patterns(n: int) -> FloatArray:
    """The smallest steps an arc set can take at one gap, in lattice units: one or two arcs by
    one unit with any signs, and up to half the arcs by one unit with one sign (a repair of
    every satellite across a radio gap rests on one estimate of the receiver clock, whose
    error moves every satellite near its rounding boundary the same way). More than half
    stepping one way is the rest stepping the other way, which the epochs' clocks absorb."""
    from itertools import combinations

    rows: list[FloatArray] = []
    for i in range(n):
        v = np.zeros(n)
        v[i] = 1.0
        rows.append(v)
    for i, j in combinations(range(n), 2):
        for s in (1.0, -1.0):
            v = np.zeros(n)
            v[i], v[j] = 1.0, s
            rows.append(v)
    for k in range(3, n // 2 + 1):
        for idx in combinations(range(n), k):
            v = np.zeros(n)
            v[list(idx)] = 1.0
            rows.append(v)
    out = np.asarray(rows, dtype=np.float64).reshape(-1, n)
    out.flags.writeable = False  # shared by every gap with n arcs
    return out


@lru_cache(maxsize=64)
def _needed(dof: int) -> tuple[float, float]:
    """A joint test of ``dof`` degrees of freedom at the tail probability of :data:`STEP_W`:
    (its threshold, the non-centrality it detects with probability :data:`POWER`)."""
    # scipy.special's tails are the functions scipy.stats wraps; importing scipy.stats would
    # cost every solve about 0.6 s of CPU
    from scipy import optimize, special

    p_tail = 2.0 * float(special.ndtr(-STEP_W))
    th = float(special.chdtri(dof, p_tail))
    lam = float(optimize.brentq(
        lambda lam_: 1.0 - float(special.chndtr(th, dof, lam_)) - POWER, 1e-6, 1e6))
    return th, lam


def unverified(tab: PhaseTable, sys: EpochSystem, fl: FloatArcs) -> list[int]:
    """Arcs holding a phase carried on a decision of the conditioning (:attr:`PhaseTable.
    decided`) that the data could not check: a step of half a cycle there (the decision
    wrong by the smallest amount a squaring loop allows) would not reach the step test's
    threshold with probability :data:`POWER`, or the test sees a step there.

    The receivers resolve a squaring loop's half cycle from the navigation data; a phase
    resting on nothing else differs from another such by whole cycles. Our decisions round to
    half cycles, and one wrong among them leaves the rest of its arc half a cycle off (on the
    simulator, whose receiver always resolves its half cycles right, every arc half a cycle
    off the others held such a repair: severity 2, seed 1311, 5 of 108). Checked, they are as
    good as the receiver's."""
    if tab.decided is None:
        return []
    red, rhs = reduced(sys)
    arc = np.where(sys.phase_used, tab.arc, -1)
    lam_needed = _needed(1)[1]
    out: list[int] = []
    for j in range(arc.shape[1]):
        col = arc[:, j]
        for a in np.unique(tab.arc[:, j][tab.arc[:, j] >= 0]).tolist():
            rows = np.flatnonzero(col == a)
            k = np.flatnonzero(tab.decided[rows, j])
            if (np.any(tab.decided[(tab.arc[:, j] == a) & (col != a), j])  # phase not taken
                    or (k.size and k[0] == 0)):  # the arc's first: its constant's own
                out.append(int(a))
                continue
            if k.size == 0:
                continue
            w, info, _ = _step_w(red, rhs, arc, rows, j, a, k, fl)
            if np.any(HALF_CYCLE**2 * info < lam_needed) or np.any(np.abs(w) > STEP_W):
                out.append(int(a))
    return out


@dataclass(frozen=True, slots=True)
class GapDoubt:
    """A gap across which the arcs' continuity is not to be relied on.

    Attributes:
        row: the first epoch after the gap.
        arcs: the arcs that continue across it.
        chi2, threshold: the joint test of a step in every one of them.
        weakest: the smallest non-centrality a one-lattice-unit step pattern would give the
            test (:func:`_patterns`); below ``needed`` it could pass unseen.
    """

    row: int
    arcs: tuple[int, ...]
    chi2: float
    threshold: float
    weakest: float
    needed: float
    cut: tuple[int, ...]
    """The arcs split there: all of them where a step was found; where one could hide, those
    whose continuity the others cannot check (:func:`_unverifiable`)."""

    @property
    def contradicted(self) -> bool:
        return self.chi2 > self.threshold


def gap_doubts(tab: PhaseTable, sys: EpochSystem, fl: FloatArcs,
               nominal_s: float) -> list[GapDoubt]:
    """Gaps of the whole table (no phase at all for more than 1.5 nominal intervals: a radio
    gap, a base outage) whose continuing arcs may have stepped without the data showing it.

    Across such a gap every satellite's phase was carried by the conditioning's repair, and
    the single-arc tests of :func:`step_tests` assume one arc stepped: several arcs stepping
    at once (one clock error behind every repair) can hide from each of them. Here the steps
    of all arcs continuing across the gap are tested jointly (chi-square with their number
    minus one degrees of freedom, the common step being the epochs' clocks, at the tail
    probability of :data:`STEP_W`), and their reliability is checked: the smallest step
    patterns of one lattice unit (:func:`_patterns`) must give the test the non-centrality
    that detects them with probability :data:`POWER`. A gap that fails either is a gap where
    the whole-arc solution cannot rely on the arcs being continuous."""
    red, rhs = reduced(sys)
    arc = np.where(sys.phase_used, tab.arc, -1)
    t_s = (tab.t_ns - tab.t_ns[0]) / 1e9
    have = np.flatnonzero(np.any(arc >= 0, axis=1))
    if have.size < 2:
        return []
    starts = have[1:][np.diff(t_s[have]) > 1.5 * nominal_s]
    if starts.size == 0:
        return []
    na = tab.n_arcs
    a_hat = np.nan_to_num(fl.a)

    # per arc crossing a gap: its normal columns (and right-hand side) summed from each gap on
    cols: dict[int, dict[int, tuple[FloatArray, float]]] = {}
    n_sv = arc.shape[1]
    for j in range(n_sv):
        col = arc[:, j]
        for a in np.unique(col[col >= 0]).tolist():
            rows = np.flatnonzero(col == a)
            at = np.searchsorted(rows, starts)
            inside = (at > 0) & (at < rows.size)
            if not inside.any():
                continue
            cum, bcum = _from_on(red, rhs, arc, rows, j, na)
            for g, i in zip(starts[inside].tolist(), at[inside].tolist(), strict=True):
                cols.setdefault(g, {})[int(a)] = (cum[i], float(bcum[i]))
    out: list[GapDoubt] = []
    for g in starts.tolist():
        per = cols.get(g, {})
        n = len(per)
        if n < 2:
            continue
        s_arcs = sorted(per)
        c = np.stack([per[a][0] for a in s_arcs])
        b = np.array([per[a][1] for a in s_arcs])
        v = c[:, s_arcs] - c @ fl.q @ c.T
        v = 0.5 * (v + v.T)
        w = b - c @ a_hat
        # the common step is the epochs' clocks: test in the n-1 differences
        basis = _differences(n)
        vd = basis.T @ v @ basis
        wd = basis.T @ w
        try:
            chi2 = float(wd @ np.linalg.solve(vd, wd))
            weakest, weak = _unverifiable(v, tab.lattice_cyc, lambda m: _needed(m)[1])
        except np.linalg.LinAlgError:
            chi2, weakest, weak = float("inf"), 0.0, list(range(n))
        th, lam = _needed(n - 1)
        if chi2 > th or weakest < lam:
            arcs = tuple(int(a) for a in s_arcs)
            cut = arcs if chi2 > th else tuple(arcs[k] for k in sorted(weak))
            out.append(GapDoubt(int(g), arcs, round(chi2, 1), round(th, 1), round(weakest, 1),
                                round(lam, 1), cut))
    return out


def _unverifiable(v: FloatArray, step: float, needed: Callable[[int], float],
                  ) -> tuple[float, list[int]]:
    """The reliability of a gap's joint test: (the smallest non-centrality of a one-unit step
    pattern with every arc continuing, the arcs (rows of ``v``) whose continuity must be given
    up so that every pattern of the others is detected).

    A pattern's non-centrality is counted in the test as run, in the differences (the common
    part of ``v`` is not zero where the float constants are relative to a reference arc, and
    ``p' v p`` counted it: seed 829 at severity 1, 42 where the test saw 30). Where some
    pattern is too weak, the arc of it whose own step the data determine least (often an arc
    with a few epochs on one side) is given up, its step becomes a free parameter of the
    others' test (``v`` conditioned on it), and the others are checked again: one arc that
    cannot be checked does not cost every other arc its continuity (seed 806 at severity 1.5:
    a 0.4 s gap, seven arcs, the weakest pattern half a cycle on one satellite about to set;
    every arc split there, 500 s of the flight without a fix). A single arc left continuing
    needs no check: its step would be common to everything after the gap, the clocks'."""
    keep = list(range(v.shape[0]))
    free: list[int] = []
    first = float("nan")
    while len(keep) >= 2:
        k = np.asarray(keep)
        vk = v[np.ix_(k, k)]
        if free:
            f = np.asarray(free)
            vkf = v[np.ix_(k, f)]
            vk = vk - vkf @ np.linalg.pinv(v[np.ix_(f, f)]) @ vkf.T
            vk = 0.5 * (vk + vk.T)
        m = k.size
        basis = _differences(m)
        vd = basis.T @ vk @ basis
        pat = _patterns(m) * step
        vp = basis.T @ vk @ pat.T
        lam_p = np.einsum("ip,ip->p", vp, np.linalg.solve(vd, vp))
        j = int(np.argmin(lam_p))
        if not free:
            first = float(lam_p[j])
        if lam_p[j] >= needed(m - 1):
            break
        members = np.flatnonzero(pat[j])
        drop = keep[int(members[np.argmin(np.diag(vk)[members])])]
        keep.remove(drop)
        free.append(drop)
    return first, free


def most_evident(doubts: list[GapDoubt]) -> list[GapDoubt]:
    """The contradicted gaps to take as found: the one whose joint test is the least probable
    under the model (its tail probability, so that tests of different numbers of arcs
    compare), then the next that shares no arc with those taken (a step shows only in the
    tests of gaps its arcs cross), and so on."""
    from scipy import special

    found = sorted((d for d in doubts if d.contradicted),
                   key=lambda d: float(special.chdtrc(len(d.arcs) - 1, d.chi2)))
    taken: list[GapDoubt] = []
    used: set[int] = set()
    for d in found:
        if used.isdisjoint(d.arcs):
            taken.append(d)
            used.update(d.arcs)
    return taken
