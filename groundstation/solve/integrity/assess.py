"""The integrity stage: our whole-arc solution, the engine's runs, one graded trajectory.

What this module owns: running the stage on a rover's (conditioned) observations, its base's,
the ephemerides and the engine's forward, backward and combined solutions, and what it says
about itself (:class:`IntegrityResult`: the graded epochs and a summary for ``engine.json``,
the report and the printout).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation.geodesy import ecef_to_llh, enu_rotation
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.offline.rinex.observations import ObsSet
from groundstation.solve.engine.combine import DTTOL_S
from groundstation.solve.integrity import grade as gr
from groundstation.solve.integrity.arcs import Resolution, resolve, without
from groundstation.solve.integrity.carry import confirmed_along_arcs
from groundstation.solve.integrity.normal import code_positions
from groundstation.solve.integrity.smooth import smooth
from groundstation.solve.integrity.table import build_table

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

MATCH_NS = round(DTTOL_S * 1e9)
"""An engine solution within this of an observation epoch is that epoch's (the tolerance
the engine's solutions are combined with)."""


@dataclass(frozen=True, slots=True)
class EngineSolution:
    """An engine's solution, as columns (a ``trajectory.Trajectory`` has these)."""

    t_gps_ns: IntArray
    ecef_m: FloatArray
    quality: IntArray
    cov: FloatArray  # (n, 3, 3) ECEF


@dataclass(frozen=True, slots=True)
class IntegrityResult:
    """The graded trajectory and what decided it.

    Attributes:
        t_gps_ns, ecef_m, cov, quality, grade, check: per epoch (see :class:`grade.Graded`).
        summary: JSON-ready figures for ``engine.json`` and the report.
    """

    t_gps_ns: IntArray
    ecef_m: FloatArray
    cov: FloatArray
    quality: IntArray
    grade: IntArray
    check: IntArray
    summary: dict[str, object]

    def sd_enu_m(self) -> FloatArray:
        """(n, 3) standard deviations east, north, up."""
        ok = np.all(np.isfinite(self.ecef_m), axis=1)
        if not ok.any():
            return np.full((self.t_gps_ns.size, 3), np.nan)
        lat, lon, _ = ecef_to_llh(*(float(v) for v in self.ecef_m[ok][0]))
        rot = np.asarray(enu_rotation(lat, lon))
        c = np.einsum("ij,ejk,lk->eil", rot, self.cov, rot)
        return np.asarray(np.sqrt(np.clip(np.einsum("eii->ei", c), 0.0, None)), np.float64)


def _at(sol: EngineSolution | None, t_ns: IntArray) -> gr.Candidate | None:
    """The engine solution at the observation epochs (nearest within :data:`MATCH_NS`)."""
    if sol is None:
        return None
    n = t_ns.size
    x = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    q = np.zeros(n, dtype=np.int64)
    if sol.t_gps_ns.size:
        hi = np.clip(np.searchsorted(sol.t_gps_ns, t_ns), 1, max(sol.t_gps_ns.size - 1, 1))
        lo = np.maximum(hi - 1, 0)
        hi = np.minimum(hi, sol.t_gps_ns.size - 1)
        j = np.where(np.abs(sol.t_gps_ns[lo] - t_ns) <= np.abs(sol.t_gps_ns[hi] - t_ns), lo, hi)
        hit = np.abs(sol.t_gps_ns[j] - t_ns) <= MATCH_NS
        x[hit] = sol.ecef_m[j[hit]]
        cov[hit] = sol.cov[j[hit]]
        q[hit] = sol.quality[j[hit]]
    return gr.Candidate(x, cov, q)


@dataclass(frozen=True, slots=True)
class Arcs:
    """Our whole-arc solution at the rover's epochs, before the engine runs.

    Attributes:
        t_ns: the rover's epoch times (receiver time).
        x, cov: (n, 3) ECEF positions, (n, 3, 3) covariances (smoothed where fixed).
        fixed: (n,) epochs our solution fixed with a centimetre sigma.
        stands_alone: the phase behaved as modelled (:data:`grade.PHASE_MODEL_FACTOR`).
        summary: JSON-ready figures of the solution.
        wall_s: its time.
        resolution: the solution itself (to fix again without an arc).
    """

    t_ns: IntArray
    x: FloatArray
    cov: FloatArray
    fixed: npt.NDArray[np.bool_]
    stands_alone: bool
    summary: dict[str, object]
    wall_s: float
    resolution: Resolution

    def fixed_trajectory(self) -> tuple[IntArray, FloatArray, npt.NDArray[np.bool_]]:
        """(times, positions, which are fixed): what the dynamics are measured on."""
        return self.t_ns, self.x, self.fixed


def arcs_stage(
    rover: ObsSet, base: ObsSet, ephemerides: Sequence[BroadcastEphemeris],
    base_ecef_m: tuple[float, float, float],
    decisions: Sequence[tuple[int, str, int]] | None = None,
) -> Arcs | None:
    """Our whole-arc solution (:func:`groundstation.solve.integrity.arcs.resolve`, smoothed), from
    the observations alone: linearised at the code's positions, so it can run before the
    engine (and give the engine its motion model). None without rover epochs or without a
    phase shared with the base (another day's base). ``decisions``: the conditioning's
    (:func:`table.build_table`)."""
    t0 = time.perf_counter()
    base_x = np.asarray(base_ecef_m, dtype=np.float64)
    tab = build_table(rover, base, ephemerides, base_ecef_m, decisions=decisions)
    if tab.t_ns.size == 0 or tab.n_arcs == 0:  # no epoch, or no phase shared with the base
        return None
    start = code_positions(tab, base_x)
    start = np.where(np.isfinite(start), start, base_x)
    return _arcs_of(resolve(tab, start), base_x, t0)


def _arcs_of(res: Resolution, base_x: FloatArray, t0: float) -> Arcs:
    """:class:`Arcs` of a solution: its fixed epochs smoothed over their runs in a local
    frame, and kept as fixed only where their sigma is a centimetre one."""
    sol = res.solution
    t_ns = res.tab.t_ns
    ok = np.all(np.isfinite(sol.x), axis=1)
    origin = sol.x[ok][0] if ok.any() else base_x
    lat, lon, _ = ecef_to_llh(*(float(v) for v in origin))
    rot = np.asarray(enu_rotation(lat, lon))
    enu = (sol.x - origin) @ rot.T
    var = np.einsum("eii->ei", np.einsum("ij,ejk,lk->eil", rot, sol.cov, rot))
    t_s = (t_ns - t_ns[0]) / 1e9
    sm = smooth(t_s, enu, var, sol.fixed)
    smoothed = np.all(np.isfinite(sm.enu), axis=1)
    ours_x = sol.x.copy()
    ours_cov = sol.cov.copy()
    ours_x[smoothed] = origin + sm.enu[smoothed] @ rot
    ours_cov[smoothed] = np.einsum("ji,ej,jk->eik", rot, sm.var[smoothed], rot)
    sd = np.sqrt(np.clip(np.einsum("eii->ei", np.einsum("ij,ejk,lk->eil", rot, ours_cov, rot)),
                         0.0, None))
    precise = np.all(sd <= gr.FIXED_MAX_SIGMA_M, axis=1)
    ours_fixed = sol.fixed & precise
    alone = bool(res.phase_factor <= gr.PHASE_MODEL_FACTOR)
    lat_res = res.lattice
    summary: dict[str, object] = {
        "satellites": [f"G{s:02d}" for s in res.tab.svs],
        "arcs": res.tab.n_arcs,
        "lattice_cycles": res.tab.lattice_cyc,
        "arcs_on_whole_cycles": (None if res.tab.arc_whole is None
                                 else int(res.tab.arc_whole.sum())),
        "integer_combinations": lat_res.combinations,
        "fixed_combinations": lat_res.fixed_combinations,
        "stopped_by": lat_res.stopped_by,
        "contradictions": lat_res.contradictions,
        "gap_judgements": res.gap_judgements,
        "first_float_sigma_steps": round(lat_res.ratio_to_lattice, 3),
        "slips_found_as_steps": [
            {"satellite": f"G{sv:02d}", "t_gps_ns": t} for sv, t in res.steps],
        "gaps_split": {
            "steps_found": sum(d.contradicted for d in res.gap_doubts),
            "steps_could_hide": sum(not d.contradicted for d in res.gap_doubts),
            "arcs_split_where_steps_could_hide": sum(
                len(d.cut) for d in res.gap_doubts if not d.contradicted),
        },
        "code_variance_factor": round(res.code_inflation, 2),
        "phase_variance_factor": round(res.phase_factor, 2),
        "stands_alone": alone,
        "arcs_left_out_misfit": len(res.misfits),
        "arcs_left_out_engine": [f"G{res.tab.svs[int(res.tab.arc_sv[a])]:02d}"
                                 for a in res.left_out],
        "epochs_fixed": int(sol.fixed.sum()),
        "epochs_fixed_precise": int(ours_fixed.sum()),
        "smoothing": {
            "jerk_density_h_m2_s5": sm.jerk_h, "jerk_density_v_m2_s5": sm.jerk_v,
            "runs": sm.runs, "epochs_left_unsmoothed": sm.rejected,
        },
    }
    return Arcs(t_ns, ours_x, ours_cov, ours_fixed, alone, summary,
                round(time.perf_counter() - t0, 3), res)


MIN_CONFLICT_EPOCHS = 5
"""Epochs where the engine's checked fix contradicts ours before an arc is looked for."""
MAX_RECONCILE = 3
"""Arcs left out at most when reconciling with the engine's checked fixes."""
MAX_CANDIDATES = 8
"""Arcs tried at each step of the reconciliation (those fixed at most contradicted epochs)."""


def reconcile(arcs: Arcs, checked: npt.NDArray[np.bool_], engine: gr.Candidate) -> Arcs:
    """Our solution where the engine's checked fixes (both directions agreeing) contradict
    it: one of our fixed arcs is then the likeliest culprit (a slip nobody flagged, a float
    that rounded wrongly). Each arc fixed at those epochs is left out in turn; the one whose
    absence removes the most contradictions, and at least half of them, without new ones
    elsewhere, is left out for good; up to :data:`MAX_RECONCILE` arcs. The engine's fix is
    thus the check of ours as ours is of it ("a rerun without the satellites" of the
    issue), and the contradictions left demote both (:func:`grade.grade`). An arc counts as
    the culprit only where, without it, our solution agrees with the engine at more than half
    of those epochs (minus the new contradictions it makes): leaving out arcs until nothing is
    fixed would end the contradictions too."""
    base_x = arcs.x[np.all(np.isfinite(arcs.x), axis=1)][0] if np.isfinite(arcs.x).any() else (
        np.zeros(3))
    current = arcs
    for _ in range(MAX_RECONCILE):
        conflict = current.fixed & checked & ~gr.agree(current.x, current.cov, engine.x,
                                                       engine.cov)
        n_conf = int(conflict.sum())
        if n_conf < MIN_CONFLICT_EPOCHS:
            break
        res = current.resolution
        slots = res.solution.slot_fixed & conflict[:, None] & (res.tab.arc >= 0)
        cands, counts = np.unique(res.tab.arc[slots], return_counts=True)
        best: int | None = None
        best_gain = n_conf // 2  # at least half of the contradictions must turn to agreement
        for a in cands[np.argsort(-counts)][:MAX_CANDIDATES].tolist():
            # a trial judged on its epochs' own positions (smoothing only for the one kept)
            sol = without(res, [int(a)], rounds=1).solution
            agrees = sol.fixed & checked & gr.agree(sol.x, sol.cov, engine.x, engine.cov)
            disagree = sol.fixed & checked & ~gr.agree(sol.x, sol.cov, engine.x, engine.cov)
            gain = int((agrees & conflict).sum()) - int((disagree & ~conflict).sum())
            if gain > best_gain:
                best, best_gain = int(a), gain
        if best is None:
            break
        current = _arcs_of(without(res, [best]), base_x, time.perf_counter())
    return current


def grade_stage(
    arcs: Arcs | None, merged: EngineSolution, forward: EngineSolution | None = None,
    backward: EngineSolution | None = None,
) -> IntegrityResult:
    """The graded trajectory from our solution (None: the engine's runs alone) and the
    engine's (see :mod:`.grade`), at the rover's epochs (or the engine's when ours is
    None)."""
    t0 = time.perf_counter()
    t_ns = arcs.t_ns if arcs is not None else merged.t_gps_ns
    n = t_ns.size
    m = _at(merged, t_ns)
    assert m is not None
    fwd, bwd = _at(forward, t_ns), _at(backward, t_ns)
    if arcs is not None and fwd is not None and bwd is not None:
        checked = ((m.q == 1) & (fwd.q == 1) & (bwd.q == 1)
                   & gr.agree(fwd.x, fwd.cov, bwd.x, bwd.cov))
        arcs = reconcile(arcs, checked, m)
    ours_arcs = None
    if arcs is not None:
        ours = gr.Candidate(arcs.x, arcs.cov, np.where(arcs.fixed, 1, 0))
        ours_fixed, alone = arcs.fixed, arcs.stands_alone
        rs = arcs.resolution
        ours_arcs = np.where(rs.solution.slot_fixed, rs.tab.arc, -1)
    else:
        ours = gr.Candidate(np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan),
                            np.zeros(n, dtype=np.int64))
        ours_fixed, alone = np.zeros(n, dtype=bool), False
    g = gr.grade(ours_fixed, ours, fwd, bwd, m, ours_alone=alone, ours_arcs=ours_arcs)
    if arcs is not None and fwd is not None and bwd is not None:
        # one direction's fixes the checked fixes of other epochs confirm along their arcs
        tab = arcs.resolution.tab
        f_fix, b_fix = fwd.q == 1, bwd.q == 1
        checked = g.grade == gr.FIXED
        by_arcs = (
            confirmed_along_arcs(tab, fwd.x, fwd.cov, f_fix & ~b_fix, g.x, g.cov, checked)
            | confirmed_along_arcs(tab, bwd.x, bwd.cov, b_fix & ~f_fix, g.x, g.cov, checked))
        if by_arcs.any():
            g = gr.grade(ours_fixed, ours, fwd, bwd, m, ours_alone=alone, ours_arcs=ours_arcs,
                         by_arcs=by_arcs)
    # the epochs' times: the engine's (receiver clock removed) where it has the epoch
    t_out = t_ns.copy()
    if merged.t_gps_ns.size:
        j = np.clip(np.searchsorted(merged.t_gps_ns, t_ns), 0, merged.t_gps_ns.size - 1)
        j0 = np.maximum(j - 1, 0)
        j = np.where(np.abs(merged.t_gps_ns[j0] - t_ns) < np.abs(merged.t_gps_ns[j] - t_ns), j0, j)
        near = np.abs(merged.t_gps_ns[j] - t_ns) <= MATCH_NS
        t_out[near] = merged.t_gps_ns[j[near]]
    keep = np.all(np.isfinite(g.x), axis=1)
    summary: dict[str, object] = {
        "epochs": int(keep.sum()),
        "grades": {gr.GRADE_NAMES[k]: int(np.sum(g.grade[keep] == k)) for k in gr.GRADE_NAMES
                   if np.any(g.grade[keep] == k)},
        "checks": g.counts,
        "arcs": arcs.summary if arcs is not None else None,
        "float_sigma_factor": {"horizontal": round(g.float_factor[0], 3),
                               "vertical": round(g.float_factor[1], 3),
                               "from": g.factor_source},
        "wall_s": round(time.perf_counter() - t0 + (arcs.wall_s if arcs else 0.0), 3),
    }
    return IntegrityResult(t_out[keep], g.x[keep], g.cov[keep], g.quality[keep],
                           g.grade[keep], g.check[keep], summary)


def assess(
    rover: ObsSet, base: ObsSet, ephemerides: Sequence[BroadcastEphemeris],
    base_ecef_m: tuple[float, float, float], merged: EngineSolution,
    forward: EngineSolution | None = None, backward: EngineSolution | None = None,
) -> IntegrityResult:
    """The whole stage in one call (:func:`arcs_stage`, then :func:`grade_stage`)."""
    return grade_stage(arcs_stage(rover, base, ephemerides, base_ecef_m), merged, forward,
                       backward)
