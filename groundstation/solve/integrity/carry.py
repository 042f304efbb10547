"""A fix of one direction confirmed by a checked fix at another epoch, carried along the arcs
both rest on.

What this module owns: the check ``carried-along-arcs`` of :mod:`.grade`. On a flight whose
satellites keep losing lock (a walking antenna, a banking copter), the engine's forward and
backward runs often fix different stretches, and a fix of one direction alone has nothing at
its own epoch to be checked against. But an integer ambiguity is one constant over an arc (a
stretch of unbroken lock of both receivers, :mod:`.table`): a fix at epoch ``k`` and a checked
fix at epoch ``k'`` (both directions agreeing, or our whole-arc solution with an engine fix, or
the other direction's precise float: the grade's own checks) that rest on the same arcs must
carry the same integers, and then the same position at ``k`` follows from either.

How, for a fix ``x_k`` of one direction only and the nearest checked fix ``x_k'`` sharing at
least :data:`MIN_SHARED_ARCS` arcs with it:

1. each shared arc's phase residual at ``k'`` with ``x_k'`` is its constant plus the epoch's
   clock (:meth:`~.table.PhaseTable.residuals`): the checked integers, as phase;
2. at ``k``, the same arcs' residuals with ``x_k`` minus those constants leave a clock and
   the geometry of the two positions' difference: least squares for the displacement ``d``
   of the position the checked integers give at ``k`` from ``x_k``, and a clock;
3. the fix is confirmed where ``d`` is within the two positions' summed covariance
   (chi-square, 3 degrees of freedom, :data:`CHI2_3_CONFIRM`), that covariance is tight enough
   for the test to see a fix 10 cm off (:data:`RELIABLE_SIGMA_M`), and no arc's residual after
   the fit is :data:`MAX_ARC_MISFIT_CYC` or more (a whole or half cycle on one arc that the
   geometry could partly absorb).

Only a checked fix may confirm: two fixes of the engine's two directions at different epochs
can share a wrong integer set (the seed profile's seed 523 at severity 1: a stretch where both
runs held the same set 8-16 cm off, which our whole-arc solution contradicted; confirmed by each
other along the arcs, 16 camera positions came out fixed and wrong). The arcs are our table's,
repairs of the conditioning included: a repair that was wrong shows as a misfit, and the check
then fails; it cannot pass a wrong fix.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from groundstation.gnss.orbit import L1_WAVELENGTH_M
from groundstation.solve.integrity.table import PhaseTable

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

MIN_SHARED_ARCS = 5
"""Arcs two epochs must share: four unknowns (the displacement and a clock) and one more, so
that a wrong integer on one arc shows as a misfit."""
MAX_ARC_MISFIT_CYC = 0.25
"""An arc's residual after the fit at or beyond this (half the spacing of a half-cycle
lattice) is a different integer on it, not noise (a fixed position's phase residuals are
millimetres; a real antenna's multipath a few centimetres, a fifth of a cycle at most)."""
CHI2_3_CONFIRM = 7.81
"""Chi-square, 3 degrees of freedom, 5 %: the two positions agree below this. Stricter than
``both-directions``' 0.1 %: here a false alarm only leaves a fix demoted, as it was, while a
missed one confirms a wrong fix, so the test is sized for power."""
RELIABLE_SIGMA_M = 0.10 / (2.80 + 0.84)
"""The two positions' summed covariance must be this tight on its loosest axis, so that a fix
10 cm off (a wrong fix by the issue's bar) fails the test (2.80 sigma at 5 %) with 80 %
probability (0.84 sigma more): a test too loose to see the error it guards against confirms
nothing (seed 523 of the sweep: one-direction fixes 8-16 cm off, with sigmas of several
centimetres on themselves and their partners, passed the 0.1 % test)."""
NEAREST = 64
"""Checked fixes tried per epoch, nearest in time first."""


def confirmed_along_arcs(
    tab: PhaseTable, one_x: FloatArray, one_cov: FloatArray, one: BoolArray,
    other_x: FloatArray, other_cov: FloatArray, other_fixed: BoolArray,
) -> BoolArray:
    """Per table row: the fix of ``one`` (positions ``one_x``, covariances ``one_cov``) is
    confirmed by a checked fix (``other_fixed`` rows of ``other_x``, covariances
    ``other_cov``) on the arcs both rest on (see the module doc)."""
    n = tab.n_epochs
    out = np.zeros(n, dtype=bool)
    rows = np.flatnonzero(one & np.all(np.isfinite(one_x), axis=1))
    partners = np.flatnonzero(other_fixed & np.all(np.isfinite(other_x), axis=1))
    if rows.size == 0 or partners.size == 0:
        return out
    # rows without a position take any finite one: their residuals are not used
    v_one, los = tab.residuals(np.where(np.isfinite(one_x), one_x, one_x[rows[0]]))
    v_other, _ = tab.residuals(np.where(np.isfinite(other_x), other_x, one_x[rows[0]]))
    for k in rows.tolist():
        arcs_k = tab.arc[k]
        have = (arcs_k >= 0) & np.isfinite(v_one[k])
        if int(have.sum()) < MIN_SHARED_ARCS:
            continue
        j = int(np.searchsorted(partners, k))
        near = partners[max(0, j - NEAREST): j + NEAREST]
        near = near[np.argsort(np.abs(near - k), kind="stable")]
        same = (tab.arc[near] == arcs_k[None, :]) & have[None, :] & np.isfinite(v_other[near])
        enough = np.flatnonzero(same.sum(axis=1) >= MIN_SHARED_ARCS)
        if enough.size == 0:
            continue
        p = int(near[enough[0]])
        cols = np.flatnonzero(same[enough[0]])
        out[k] = _agree(v_one[k, cols] - v_other[p, cols], los[k, cols],
                        one_cov[k] + other_cov[p])
    return out


def _agree(r: FloatArray, los: FloatArray, cov: FloatArray) -> bool:
    """The displacement fitted to residual differences ``r`` [cycles] (lines of sight ``los``)
    is within ``cov`` and leaves no arc misfit."""
    h = np.hstack([-los / L1_WAVELENGTH_M, np.ones((los.shape[0], 1))])
    sol, *_ = np.linalg.lstsq(h, r, rcond=None)
    if not np.all(np.isfinite(sol)):
        return False
    misfit = r - h @ sol
    if float(np.max(np.abs(misfit))) >= MAX_ARC_MISFIT_CYC:
        return False
    d = sol[:3]
    if not np.all(np.isfinite(cov)) or float(np.linalg.eigvalsh(cov)[-1]) > RELIABLE_SIGMA_M ** 2:
        return False
    try:
        chi2 = float(d @ np.linalg.solve(cov + np.eye(3) * 1e-10, d))
    except np.linalg.LinAlgError:
        return False
    return chi2 <= CHI2_3_CONFIRM
