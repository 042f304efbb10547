"""Grades: what each position may be called, which check decided it, and an honest sigma.

What this module owns: the grade names and codes every output uses, the rule that combines our
whole-arc solution (:mod:`groundstation.solve.integrity`) with the PPK engine's forward and
backward runs into one graded trajectory, and the calibration of float sigmas on the flight's
own data.

The rule, per epoch:

1. Our whole-arc solution fixed the epoch (integer combinations sure to 5 sigma, six satellites
   on fixed constants, its residuals passing their chi-square test) and the engine's checked
   fix (both directions fixed and agreeing) does not contradict it: **fixed**, checked by
   ``arcs`` (``arcs-and-engine`` where an engine fix agrees; only those where the phase did
   not behave as modelled, :data:`PHASE_MODEL_FACTOR`). Where the engine's checked fix is
   elsewhere (beyond the two covariances, chi-square 3 dof at 0.1 %), our solution is fixed
   again without each of its arcs at those epochs in turn, and the arc whose absence ends
   most of the contradictions is left out (``assess.reconcile``); what still disagrees
   demotes both: **demoted**, ``demoted:arcs-disagree``, at their middle with a sigma on
   every axis of half their distance. An engine fix of one direction that disagrees with
   our standing fix is rejected (counted in ``engine.json``).
2. Otherwise the engine fixed it in both directions and the two agree (the full-covariance test
   of :mod:`groundstation.solve.engine.combine`): **fixed**, checked by ``both-directions``.
3. Otherwise the engine fixed it in one direction only and the other direction's float
   position, precise enough to tell a wrong integer set (calibrated sigma under
   :data:`FIXED_MAX_SIGMA_M` on every axis), agrees with that fix within its calibrated
   covariance (chi-square, 3 degrees of freedom, 0.1 %): **fixed**, checked by
   ``other-direction-float``; or a checked fix at another epoch, on the same unbroken arcs,
   gives the same position through their phase (:mod:`.carry`, the rule run a second time
   with the first run's checked fixes): **fixed**, checked by ``carried-along-arcs``.
4. An engine that combined its two directions itself (``--engine rnx2rtkp``) cannot be
   checked this way: its remaining fixes are **fixed-unchecked** (its own sigma, Q 1).
5. Otherwise a fix of the engine is **demoted** to float (its check names why), and the epoch
   gets the engine's combined float position with the calibrated float sigma. Where no fix
   was made at all and our whole-arc float (its phase as modelled) is there too, the epoch
   gets their middle with half their distance as sigma, plus the larger of their own (their
   distance measures the float's error there); ``floats-disagree`` where they disagree beyond
   their covariances.

A float sigma is the engine's formal one times a factor measured on this flight: at epochs
where a position is fixed and checked, each direction's float position there is compared with
it; the factor makes 99 % of those comparisons fall within 3 sigma per axis (never below 1).
With too few comparisons the factor is :data:`DEFAULT_FLOAT_FACTOR`, measured over the
benchmark's flights (``benchmarks/RESULTS.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

FIXED, FIXED_UNCHECKED, FLOAT, SINGLE, NONE = 1, 2, 3, 4, 5
GRADE_NAMES: dict[int, str] = {
    FIXED: "fixed", FIXED_UNCHECKED: "fixed-unchecked", FLOAT: "float", SINGLE: "single",
    NONE: "none",
}
"""Grade code -> name, best first (a mark takes the worse of its two epochs)."""
GRADE_MEANING: dict[str, str] = {
    "fixed": "integer carrier-phase solution that passed a check independent of the engine's "
             "ratio test; centimetre sigma",
    "fixed-unchecked": "the engine's integer fix with nothing to check it against (a .pos "
                       "file given with --positions, RINEX inputs, an engine that combined "
                       "its directions itself); its sigma is the engine's",
    "float": "carrier-phase float solution, or an engine fix that failed its check; sigma "
             "calibrated on the flight's own checked fixes",
    "single": "code only (single point, DGPS, the receiver's own fix): metre level",
    "none": "no position",
}

CHECK_TEXT: dict[str, str] = {  # in the order of the check codes, from 1
    "arcs": "our whole-arc phase solution fixed it on its own",
    "both-directions": "the engine fixed it forward and backward, alike",
    "other-direction-float": "one direction fixed, the other's precise float agrees",
    "demoted:directions-disagree": "both directions fixed, differently",
    "demoted:float-disagrees": "one direction fixed, the other's precise float disagrees",
    "demoted:arcs-disagree": "our whole-arc fix and an engine fix disagree",
    "demoted:one-direction": "one direction fixed, nothing precise to compare it with",
    "float": "no fix anywhere: the engine's float, or its middle with ours",
    "unchecked": "nothing to check with (a .pos file)",
    "demoted:interpolation": "fixed around the mark, not a centimetre position at it",
    "arcs-and-engine": "our whole-arc fix and the engine's fix agree",
    "demoted:camera-clock": "fixed, but the photo's time comes from the camera clock",
    "carried-along-arcs": "one direction fixed, a checked fix on the same arcs agrees",
    "floats-disagree": "no fix; the engine's float and ours disagree: their middle, wide sigma",
    "code-only": "no carrier-phase solution: the code's metre-level position",
}
"""Check name -> what it means, in a line (the printout's legend, the report's;
docs/integrity.md says more)."""
CHECK_NAMES: tuple[str, ...] = ("", *CHECK_TEXT)
"""Check code -> name: which check decided an epoch's grade (0: no check made)."""
C_ARCS, C_BOTH, C_OTHER_FLOAT = 1, 2, 3
C_DEM_DIRECTIONS, C_DEM_FLOAT, C_DEM_ARCS, C_DEM_ONE, C_FLOAT, C_UNCHECKED = 4, 5, 6, 7, 8, 9
C_DEM_INTERP = 10
C_ARCS_ENGINE = 11
C_DEM_CLOCK = 12
C_BY_ARCS = 13
C_FLOATS_DISAGREE = 14
C_CODE_ONLY = 15
TAINT_EPOCHS = 5
"""Contradicted epochs that take away an arc's standing (one is an accident of the engine)."""
PHASE_MODEL_FACTOR = 2.0
"""Our whole-arc fix stands on its own only where the phase behaved as its noise model says
(its variance factor, scatter times correlation in time, at most this): a real antenna whose
phase drifts with multipath for tens of seconds can lead the whole-arc solution to a wrong
integer set that fits (measured on the 2018-10-09 flight); there our fix counts only where
the engine fixed the same position in one direction at least."""

FIXED_MAX_SIGMA_M = 0.1 / 3
"""A position is called fixed only where its sigma on every axis is below this: a fixed camera
position promises to be within 10 cm at 3 sigma. An integer solution with weak geometry, or a
mark interpolated across a gap, is not a centimetre position even when its ambiguities are
right (it keeps its honest sigma, graded float)."""
CHI2_3_AGREE = 16.27
"""Chi-square, 3 degrees of freedom, 0.1 %: two estimates of one position agree below this."""
DEFAULT_FLOAT_FACTOR = 80.0
"""Float sigma factor when the flight gives too few comparisons to measure its own: a flight
nothing could be checked on is taken to be as overconfident as the worst tenth of the flights
measured. ``benchmarks/RESULTS.md`` (issue 22 sweep): the engine's float sigmas on the real
2018-10-09 flight as a LEA-6T, without and with the seed link, needed factors of 3.6 to 93
horizontally and 1.9 to 130 vertically (90th percentile about 80); with 3, the 2018-10-04
run-2 flight, where nothing fixes, had up to 17 % of its camera positions beyond 3 sigma."""
MIN_CALIBRATION_SAMPLES = 50
"""Comparisons a flight needs before its own float factor is used."""


@dataclass(frozen=True, slots=True)
class Candidate:
    """One source of positions at the graded epochs (NaN where it has none).

    Attributes:
        x: (n, 3) ECEF.
        cov: (n, 3, 3) covariance (ECEF).
        q: (n,) RTKLIB quality (1 fix, 2 float, ...; 0 none).
    """

    x: FloatArray
    cov: FloatArray
    q: IntArray


@dataclass(frozen=True, slots=True)
class Graded:
    """The graded trajectory.

    Attributes:
        x, cov: (n, 3) ECEF and (n, 3, 3) covariance (float sigmas calibrated).
        quality: RTKLIB Q as it should be read: 1 only where the grade is fixed.
        grade: grade code per epoch (:data:`GRADE_NAMES`).
        check: check code per epoch (:data:`CHECK_NAMES`).
        float_factor: (horizontal, vertical) factor the float sigmas were multiplied by.
        factor_source: "flight (N comparisons)" or "default".
        counts: epochs per check name.
    """

    x: FloatArray
    cov: FloatArray
    quality: IntArray
    grade: IntArray
    check: IntArray
    float_factor: tuple[float, float]
    factor_source: str
    counts: dict[str, int] = field(default_factory=dict)


def agree(xa: FloatArray, ca: FloatArray, xb: FloatArray, cb: FloatArray) -> BoolArray:
    """Per epoch: the two positions agree within their summed covariance (chi-square 3 dof)."""
    d = xa - xb
    s = ca + cb
    ok = np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(s), axis=(1, 2))
    out = np.zeros(d.shape[0], dtype=bool)
    if ok.any():
        s_ok = s[ok] + np.eye(3) * 1e-10
        sol = np.linalg.solve(s_ok, d[ok][..., None])[..., 0]
        out[ok] = np.einsum("ei,ei->e", d[ok], sol) <= CHI2_3_AGREE
    return out


def _enu_rot(x: FloatArray) -> FloatArray:
    from groundstation.geodesy import ecef_to_llh, enu_rotation

    ok = np.all(np.isfinite(x), axis=1)
    if not ok.any():
        return np.eye(3)
    lat, lon, _ = ecef_to_llh(*(float(v) for v in x[ok][0]))
    return np.asarray(enu_rotation(lat, lon), dtype=np.float64)


def float_factor(truth_x: FloatArray, floats: list[Candidate], rot: FloatArray
                 ) -> tuple[tuple[float, float], int]:
    """(horizontal, vertical) factor making 99 % of the float positions' differences from
    the checked fixes ``truth_x`` fall within 3 factor-scaled sigmas, and how many
    comparisons it rests on."""
    ratios_h: list[FloatArray] = []
    ratios_v: list[FloatArray] = []
    for c in floats:
        sel = (c.q == 2) & np.all(np.isfinite(truth_x), axis=1) & np.all(np.isfinite(c.x), axis=1)
        if not sel.any():
            continue
        d = (c.x[sel] - truth_x[sel]) @ rot.T
        cov = np.einsum("ij,ejk,lk->eil", rot, c.cov[sel], rot)
        sd = np.sqrt(np.maximum(np.einsum("eii->ei", cov), 1e-12))
        z = np.abs(d) / sd
        ratios_h.append(np.maximum(z[:, 0], z[:, 1]))
        ratios_v.append(z[:, 2])
    n = int(sum(r.size for r in ratios_h))
    if n < MIN_CALIBRATION_SAMPLES:
        return (DEFAULT_FLOAT_FACTOR, DEFAULT_FLOAT_FACTOR), n
    zh = np.concatenate(ratios_h)
    zv = np.concatenate(ratios_v)
    fh = max(1.0, float(np.quantile(zh, 0.99)) / 3.0)
    fv = max(1.0, float(np.quantile(zv, 0.99)) / 3.0)
    return (fh, fv), n


def _scale_cov(cov: FloatArray, rot: FloatArray, fh: float, fv: float) -> FloatArray:
    """Covariances scaled by ``fh`` horizontally and ``fv`` vertically (in the local frame)."""
    s = np.diag([fh, fh, fv])
    m = rot.T @ s @ rot
    return np.asarray(m @ cov @ m.T, dtype=np.float64)


def _middle(xa: FloatArray, ca: FloatArray, xb: FloatArray, cb: FloatArray,
            ) -> tuple[FloatArray, FloatArray]:
    """Two estimates that disagree, the truth near one of them: their middle, and on every
    axis a variance of half their distance squared plus the larger of their own (mean per
    axis); (n, 3) positions and (n, 3, 3) covariances."""
    dist = np.linalg.norm(xa - xb, axis=1)
    own = np.maximum(np.trace(ca, axis1=1, axis2=2), np.trace(cb, axis1=1, axis2=2)) / 3.0
    return 0.5 * (xa + xb), (0.25 * dist * dist + own)[:, None, None] * np.eye(3)[None]


def grade(ours_fixed: BoolArray, ours: Candidate, forward: Candidate | None,
          backward: Candidate | None, merged: Candidate, ours_alone: bool = True,
          ours_arcs: IntArray | None = None, by_arcs: BoolArray | None = None) -> Graded:
    """The rule of the module doc.

    Args:
        ours_fixed: (n,) epochs our whole-arc solution fixed (and smoothed where it could).
        ours: our positions and covariances at those epochs.
        forward, backward: the engine's two directions (None when it did not run them).
        merged: the engine's combined solution.
        ours_alone: our fix may stand without an engine fix beside it (the phase behaved as
            modelled: :data:`PHASE_MODEL_FACTOR`).
        ours_arcs: (n, n_sv) the arcs each of our fixed epochs rests on (-1: none): an arc
            the engine's checked fixes contradicted at :data:`TAINT_EPOCHS` epochs or more
            takes away our standing at every epoch that rests on it.
        by_arcs: (n,) epochs whose fix of one direction a checked fix of another epoch
            confirms along their shared arcs
            (:func:`.carry.confirmed_along_arcs`).
    """
    n = merged.q.size
    rot = _enu_rot(np.where(np.isfinite(ours.x), ours.x, merged.x))
    gradec = np.full(n, NONE, dtype=np.int64)
    check = np.zeros(n, dtype=np.int64)
    x = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)

    f_fix = (forward.q == 1) if forward is not None else np.zeros(n, dtype=bool)
    b_fix = (backward.q == 1) if backward is not None else np.zeros(n, dtype=bool)
    m_fix = merged.q == 1
    # The engine's own checked fixes: both directions fixed, and agreeing.
    engine_checked = m_fix & f_fix & b_fix
    if forward is not None and backward is not None:
        engine_checked &= agree(forward.x, forward.cov, backward.x, backward.cov)
    # 1. ours, unless the engine's checked fix contradicts it: two checked integer solutions
    # that disagree cannot both be right, and nothing says which is wrong. A fix of one
    # direction only is a guess the whole-arc solution has checked more than the engine has.
    contradicted = ours_fixed & engine_checked & ~agree(ours.x, ours.cov, merged.x, merged.cov)
    rejected = np.zeros(n, dtype=bool)
    for c, fx in ((forward, f_fix), (backward, b_fix)):
        if c is not None:
            rejected |= ours_fixed & fx & ~agree(ours.x, ours.cov, c.x, c.cov)
    ours_ok = ours_fixed & ~contradicted
    corroborated = np.zeros(n, dtype=bool)
    for c, fx in ((forward, f_fix), (backward, b_fix)):
        if c is not None:
            corroborated |= ours_ok & fx & agree(ours.x, ours.cov, c.x, c.cov)
    alone = np.full(n, ours_alone, dtype=bool)
    if ours_arcs is not None and contradicted.any():
        # A wrong integer set fits its own arcs' phase: where the engine's checked fix (its
        # two directions, independent runs, agreeing) contradicts ours at several epochs,
        # every epoch resting on one of the arcs there is in doubt, not only those the engine
        # happened to fix in both directions; there ours stands only where an engine fix
        # agrees with it, and does not veto the engine's.
        ids, hits = np.unique(ours_arcs[contradicted][ours_arcs[contradicted] >= 0],
                              return_counts=True)
        taint = ids[hits >= TAINT_EPOCHS]
        if taint.size:
            alone &= ~np.any(np.isin(ours_arcs, taint), axis=1)
    ours_ok = np.where(alone, ours_ok, corroborated)
    x[ours_ok] = ours.x[ours_ok]
    cov[ours_ok] = ours.cov[ours_ok]
    gradec[ours_ok] = FIXED
    check[ours_ok] = np.where(corroborated[ours_ok], C_ARCS_ENGINE, C_ARCS)
    rest = ~ours_ok

    # calibration of the float sigmas against the positions fixed so far (ours and the
    # engine's both-direction fixes that agree)
    # Our fix vetoes the engine's only where it can stand on its own: where the phase did not
    # behave as modelled, our disagreeing fix is not evidence against the engine's.
    veto = np.where(alone, contradicted | (rejected & ~ours_ok), False)
    # where ours stands, an engine fix of one direction that disagrees is rejected
    engine_rejected = ours_ok & rejected
    both = rest & ~veto & f_fix & b_fix & m_fix
    if forward is not None and backward is not None:
        both &= agree(forward.x, forward.cov, backward.x, backward.cov)
    anchor = np.where((ours_fixed | both)[:, None], np.where(ours_fixed[:, None], ours.x,
                                                             merged.x), np.nan)
    floats = [c for c in (forward, backward) if c is not None]
    (fh, fv), n_cal = float_factor(anchor, floats, rot)
    source = f"flight ({n_cal} comparisons)" if n_cal >= MIN_CALIBRATION_SAMPLES else "default"

    def scaled(c: Candidate) -> FloatArray:
        return _scale_cov(c.cov, rot, fh, fv)

    # 2. both directions
    x[both] = merged.x[both]
    cov[both] = merged.cov[both]
    gradec[both] = FIXED
    check[both] = C_BOTH
    # 3. one direction fixed, the other's float agrees
    one = rest & ~veto & ~both & m_fix & (f_fix ^ b_fix)
    if forward is not None and backward is not None:
        fixed_x = np.where(f_fix[:, None], forward.x, backward.x)
        fixed_c = np.where(f_fix[:, None, None], forward.cov, backward.cov)
        other = np.where(f_fix[:, None], backward.x, forward.x)
        other_q = np.where(f_fix, backward.q, forward.q)
        other_c = np.where(f_fix[:, None, None], scaled(backward), scaled(forward))
        # The other direction's float can only confirm the fix to its own precision: a
        # wrong integer set is a decimetre or more off, so the float must be sure to
        # FIXED_MAX_SIGMA_M (10 cm at 3 sigma) on every axis for its agreement to count.
        other_sd = np.sqrt(np.clip(np.einsum("eii->ei", np.einsum(
            "ij,ejk,lk->eil", rot, np.nan_to_num(other_c), rot)), 0.0, None))
        precise = np.all(other_sd <= FIXED_MAX_SIGMA_M, axis=1)
        agrees = agree(fixed_x, fixed_c, other, other_c) & (other_q == 2) & precise
        carried = by_arcs if by_arcs is not None else np.zeros(n, dtype=bool)
        ok1 = one & (agrees | carried)
        x[ok1] = fixed_x[ok1]
        cov[ok1] = fixed_c[ok1]
        gradec[ok1] = FIXED
        check[ok1] = np.where(agrees[ok1], C_OTHER_FLOAT, C_BY_ARCS)
        dem_float = one & ~ok1 & (other_q == 2) & precise
        dem_one = one & ~ok1 & ~((other_q == 2) & precise)
    else:
        dem_float = np.zeros(n, dtype=bool)
        dem_one = one
    # an engine that combined its directions itself (rnx2rtkp): its fixes cannot be checked
    # against either direction; they are what it says, graded unchecked
    if forward is None or backward is None:
        unchecked = (gradec == NONE) & m_fix & ~veto
        x[unchecked] = merged.x[unchecked]
        cov[unchecked] = merged.cov[unchecked]
        gradec[unchecked] = FIXED_UNCHECKED
        check[unchecked] = C_UNCHECKED
    # 4. the rest: the engine's combined solution as float, demotions named
    left = (gradec == NONE) & (merged.q > 0) & np.all(np.isfinite(merged.x), axis=1)
    x[left] = merged.x[left]
    cov[left] = scaled(merged)[left]
    # A demoted fix keeps no fix's sigma. One direction's fix that failed its check: the
    # other direction's float is the position, its calibrated sigma widened by the distance
    # to the fix (the truth is near one of them). Two directions' fixes that disagree: their
    # middle, half their distance on every axis.
    if forward is not None and backward is not None:
        demoted_one = left & m_fix & (f_fix ^ b_fix) & ~veto
        if demoted_one.any():
            fl_x = np.where(f_fix[:, None], backward.x, forward.x)[demoted_one]
            fl_c = np.where(f_fix[:, None, None], scaled(backward), scaled(forward))[demoted_one]
            fx_x = np.where(f_fix[:, None], forward.x, backward.x)[demoted_one]
            ok_fl = np.all(np.isfinite(fl_x), axis=1)
            dist2 = np.sum((fx_x - fl_x) ** 2, axis=1)
            xd = np.where(ok_fl[:, None], fl_x, x[demoted_one])
            cd = np.where(ok_fl[:, None, None], fl_c + dist2[:, None, None] * np.eye(3)[None],
                          cov[demoted_one])
            x[demoted_one] = xd
            cov[demoted_one] = cd
        disagree = left & m_fix & f_fix & b_fix & ~veto
        if disagree.any():
            x[disagree], cov[disagree] = _middle(forward.x[disagree], forward.cov[disagree],
                                                 backward.x[disagree], backward.cov[disagree])
    # Two fixes that disagree: the truth is near one of them, so the position is their middle
    # and its sigma on every local axis half their distance, plus the larger of their own.
    split = left & veto & np.all(np.isfinite(ours.x), axis=1)
    if split.any():
        x[split], cov[split] = _middle(ours.x[split], ours.cov[split], merged.x[split],
                                       merged.cov[split])
    # Where both directions are float, they are two estimates of the same position from
    # disjoint data: their difference is a measure of the float's error at that very epoch,
    # added to its variance on each local axis.
    if forward is not None and backward is not None:
        both_float = left & (forward.q == 2) & (backward.q == 2)
        if both_float.any():
            d = (forward.x[both_float] - backward.x[both_float]) @ rot.T
            extra = np.zeros((d.shape[0], 3, 3))
            extra[:, [0, 1, 2], [0, 1, 2]] = d * d
            cov[both_float] += np.einsum("ji,ejk,kl->eil", rot, extra, rot)
    # Where no fix stands, our whole-arc float (where its phase behaved as modelled) is a
    # second estimate of the position from another model of the same data: their distance is
    # a measure of the float's error at that epoch, as the two directions' is. The position is
    # their middle and its sigma half their distance on every axis plus the larger of their
    # own, whether they agree within their covariances or not (seed 829 at severity 1: the
    # engine's float 15-22 cm off in height under 4-5 cm sigmas, ours 2 cm off under 7 cm,
    # within the 0.1 % agreement). Where they disagree beyond it, the check says so (seed
    # 712 at severity 2: the engine's two directions agreed 1.6 m from the truth with 5 mm
    # sigmas, ours was 8 cm off with 12 cm).
    plain = (left & ~m_fix & (merged.q == 2) & alone & ~ours_fixed
             & np.all(np.isfinite(ours.x), axis=1) & np.all(np.isfinite(x), axis=1))
    floats_disagree = plain & ~agree(ours.x, ours.cov, x, cov)
    if plain.any():
        x[plain], cov[plain] = _middle(ours.x[plain], ours.cov[plain], x[plain], cov[plain])
    is_float = left & (merged.q <= 2)
    gradec[is_float] = FLOAT
    gradec[left & (merged.q > 2)] = SINGLE
    check[left] = C_FLOAT
    check[left & (merged.q > 2)] = C_CODE_ONLY
    check[left & m_fix & f_fix & b_fix] = C_DEM_DIRECTIONS
    check[left & dem_float] = C_DEM_FLOAT
    check[left & dem_one] = C_DEM_ONE
    check[left & veto] = C_DEM_ARCS
    check[floats_disagree] = C_FLOATS_DISAGREE
    quality = np.where((gradec == FIXED) | (gradec == FIXED_UNCHECKED), 1,
                       np.where(gradec == FLOAT, 2, np.where(gradec == SINGLE, 5, 0)))
    counts = {CHECK_NAMES[k]: int(np.sum(check == k)) for k in range(1, len(CHECK_NAMES))
              if np.any(check == k)}
    if engine_rejected.any():
        counts["engine fixes of one direction rejected by arcs"] = int(engine_rejected.sum())
    return Graded(x, cov, quality.astype(np.int64), gradec, check, (fh, fv), source, counts)
