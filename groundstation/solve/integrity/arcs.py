"""Our whole-arc carrier-phase solution: :func:`resolve` runs the package's steps in order
(:mod:`groundstation.solve.integrity`); :func:`without` solves it again with some arcs left
out of the fixing."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from groundstation.solve.integrity import normal, steps
from groundstation.solve.integrity.epochs import EpochSolution, solve_epochs
from groundstation.solve.integrity.lattice import Lattice, resolve_lattice
from groundstation.solve.integrity.steps import GapDoubt
from groundstation.solve.integrity.table import PhaseTable

FloatArray = npt.NDArray[np.float64]

MAX_SPLIT_ROUNDS = 24
"""Rounds of step tests (each splits at most one step per arc, or every arc at the gap with the
most evident joint step and at others sharing no arc with it, or, the first time nothing
steps, every arc at the gaps whose continuity is in doubt)."""
MAX_GAP_JUDGEMENTS = 3
"""Judgements of the gaps' continuity: the first on the model as the step tests leave it, the
others only when the fixed solution's lattice contradicts the model (:func:`resolve`)."""
MAX_ARC_CHECK_ROUNDS = 4
"""Rounds of fixing, checking every fixed arc against the fixed solution, leaving out the
arcs that do not fit."""
ARC_MISFIT_CYC = 0.1
"""A fixed arc whose residuals average more than this does not fit (2 cm; the noise of one
epoch's between-receiver phase, multipath included, averages well below it over an arc)."""
ARC_MISFIT_T = 5.0
"""... and the average must be this many standard errors from zero."""
MIN_ARC_EPOCHS = 3
"""Fewer epochs than this and an arc's average says nothing."""


@dataclass(frozen=True, slots=True)
class Resolution:
    """What :func:`resolve` found.

    Attributes:
        tab: the table with arcs split where steps were found.
        float_arcs: the arcs' float constants.
        lattice: the constants with the sure integer combinations held.
        solution: positions per epoch with them.
        steps: (GPS satellite number, GPS ns of the first epoch after it) of each split.
        code_inflation: the code's variance factor for its correlation in time.
        misfits: arcs left out of the fixing because their phase did not fit the fixed
            solution.
        phase_factor: the phase's variance factor (its scatter,
            :func:`normal.phase_variance_factor`, times its correlation in time,
            :func:`normal.time_correlation`).
    """

    tab: PhaseTable
    float_arcs: normal.FloatArcs
    lattice: Lattice
    solution: EpochSolution
    steps: tuple[tuple[int, int], ...]
    code_inflation: float
    misfits: tuple[int, ...] = ()
    phase_factor: float = 1.0
    x0: FloatArray | None = None
    """The positions the solution is linearised at."""
    left_out: tuple[int, ...] = ()
    """Arcs left out of the fixing because a checked fix of the engine contradicted the
    solution they gave (:func:`without`)."""
    gap_doubts: tuple[GapDoubt, ...] = ()
    """Gaps across which every arc was split: a joint step there was found, or could have
    hidden (:func:`steps.gap_doubts`)."""
    gap_judgements: int = 1
    """How many times the gaps were judged (again when the lattice contradicted the model)."""


def resolve(tab: PhaseTable, x0: FloatArray) -> Resolution:
    """The whole solution from a table and positions to linearise at (metre level will do)."""
    found_all: list[tuple[int, int]] = []
    gap_doubts: list[GapDoubt] = []
    x = np.array(x0, dtype=np.float64, copy=True)
    code_infl = 1.0
    nominal = float(np.median(np.diff(tab.t_ns))) / 1e9 if tab.n_epochs > 1 else 1.0
    # The positions to linearise at (the engine's solution) are metres at worst: the
    # second-order error of that is below a micrometre, so they are not iterated here.
    for judgement in range(MAX_GAP_JUDGEMENTS):
        split_tab, split_infl, found, doubts = _split(tab, x, code_infl, nominal)
        if judgement and not found and not doubts:
            break  # judged again, nothing new: the solution stands as it is
        tab, code_infl = split_tab, split_infl
        found_all += found
        gap_doubts += doubts
        system = normal.epoch_system(tab, x, code_infl)
        fl = normal.float_arcs(tab, system)
        # The phase's own residuals say how noisy it is and how many independent looks at the
        # geometry the flight holds (multipath drifts over tens of seconds on a real antenna):
        # both scale its weight, so that slow errors are not taken for geometry.
        e_m = normal.float_phase_residuals(tab, system, x, fl)
        phase_fac = (normal.phase_variance_factor(tab, e_m)
                     * max(1.0, normal.time_correlation(tab.t_ns, e_m)))
        if phase_fac > 1.0:
            system = normal.epoch_system(tab, x, code_infl, np.sqrt(phase_fac))
            fl = normal.float_arcs(tab, system)
        if tab.arc_whole is not None:
            whole = tab.arc_whole.copy()
            whole[steps.unverified(tab, system, fl)] = False
            tab = replace(tab, arc_whole=whole)
        lat, sol, suspects = _fix(tab, x, fl, fl.informed.copy(), code_infl, phase_fac)
        # A sure difference off the lattice proves the model wrong somewhere. The gaps were
        # judged on the model before their own splits: a gap whose reliability came from arcs
        # that were then split across another gap may now be one where a joint step hides
        # (seed 608 at severity 1: half a cycle on three of five satellites at one gap,
        # reliable with the flight's arcs whole, not once the gap 70 s before was split;
        # the pairs fixed across it were wrong and the positions 25 cm off). So the gaps are
        # judged again on the model as it now stands, only when the lattice says it is wrong.
        if not lat.contradictions:
            break
    return Resolution(tab, fl, lat, sol, tuple(found_all), code_infl, tuple(suspects),
                      phase_fac, x, gap_doubts=tuple(gap_doubts), gap_judgements=judgement + 1)


def _split(tab: PhaseTable, x: FloatArray, code_infl: float, nominal: float,
           ) -> tuple[PhaseTable, float, list[tuple[int, int]], list[GapDoubt]]:
    """Split the arcs at the steps the single tests find, then at the gaps where a joint step
    is found (the most evident first, with others sharing no arc with it, and test again)
    and, once none is left, at the gaps where one could hide; (table, code inflation, steps,
    doubts)."""
    found_all: list[tuple[int, int]] = []
    gap_doubts: list[GapDoubt] = []
    gaps_judged = False
    for _ in range(MAX_SPLIT_ROUNDS):
        system = normal.epoch_system(tab, x, code_infl)
        fl = normal.float_arcs(tab, system)
        code_infl = max(1.0, normal.code_correlation(tab, x, normal.clock_m(tab, x, fl.a)))
        found = steps.step_tests(tab, system, fl, nominal)
        if found:
            cut = [(a, r) for a, r, _, _ in found]
            found_all += [(tab.svs[int(tab.arc_sv[a])], int(tab.t_ns[r])) for a, r in cut]
            tab = steps.split_arcs(tab, cut)
            continue
        # No single arc stepped: did several step at once across a gap? A joint step at one
        # gap shows in the test of every earlier gap of the same arcs (each tests the arcs'
        # data from its gap on against their whole), so only the most evident is taken as
        # found (and any other sharing no arc with it) and the others tested again without it
        # (Baarda's identification, one alternative at a time; seed 829 at severity 1: one
        # joint half-cycle step at a 2.2 s gap contradicted all 73 gaps of the 270 s around
        # it, which were all split and left that stretch without a fix).
        doubts = steps.gap_doubts(tab, system, fl, nominal)
        evident = steps.most_evident(doubts)
        if evident:
            gap_doubts += evident
            tab = steps.split_at_gaps(tab, evident)
            continue
        # Nothing stepped: are the arcs' continuities across the gaps to be relied on? Each
        # gap is judged once, on the model as the tests above left it (Baarda: every
        # alternative against the same null): judging again after splitting would deny a gap
        # the evidence of its neighbours' continuity only because theirs was not provable,
        # and cascade through the flight (seed 506 at severity 1.5: 21 gaps split once, 229
        # when judged again until nothing changed). :func:`resolve` judges again only when
        # the fixed solution proves the model wrong.
        if gaps_judged or not doubts:
            break
        gaps_judged = True
        gap_doubts += doubts
        tab = steps.split_at_gaps(tab, doubts)
    else:
        # rounds spent with steps still being found: whatever gap is still in doubt is split,
        # all at once (nothing is left relying on a continuity not checked)
        system = normal.epoch_system(tab, x, code_infl)
        doubts = steps.gap_doubts(tab, system, normal.float_arcs(tab, system), nominal)
        gap_doubts += doubts
        tab = steps.split_at_gaps(tab, doubts)
    return tab, code_infl, found_all, gap_doubts


def _fix(tab: PhaseTable, x: FloatArray, fl: normal.FloatArcs, usable: npt.NDArray[np.bool_],
         code_infl: float, phase_fac: float, rounds: int = MAX_ARC_CHECK_ROUNDS,
         ) -> tuple[Lattice, EpochSolution, list[int]]:
    """Fix the usable arcs, solve the epochs, leave out the fixed arcs that do not fit and
    fix again (at most ``rounds`` times); (lattice, solution, arcs left out)."""
    usable = usable.copy()
    suspects: list[int] = []
    for _ in range(rounds):
        lat = resolve_lattice(fl.a, fl.q, usable, tab.lattice_cyc, tab.arc_whole)
        sol = solve_epochs(tab, x, lat, code_infl, phase_fac)
        bad = arc_misfits(tab, sol)
        if not bad:
            break
        suspects += bad
        usable[bad] = False
    return lat, sol, suspects


def without(res: Resolution, arcs: list[int], rounds: int = MAX_ARC_CHECK_ROUNDS,
            ) -> Resolution:
    """The solution again with ``arcs`` left out of the fixing (they stay float); ``rounds``
    of the misfit check (one for a trial)."""
    assert res.x0 is not None
    usable = res.float_arcs.informed.copy()
    usable[list(res.misfits)] = False
    usable[list(res.left_out) + arcs] = False
    lat, sol, more = _fix(res.tab, res.x0, res.float_arcs, usable, res.code_inflation,
                          res.phase_factor, rounds)
    return replace(res, lattice=lat, solution=sol, misfits=(*res.misfits, *more),
                   left_out=(*res.left_out, *arcs))


def arc_misfits(tab: PhaseTable, sol: EpochSolution) -> list[int]:
    """Arcs held fixed whose phase does not fit the fixed solution over their length: the
    mean of their residuals is off by more than :data:`ARC_MISFIT_CYC` (a wrong whole or half
    cycle shows as a share of a lattice step once the position has taken its part) and more
    than :data:`ARC_MISFIT_T` standard errors of that mean (the residuals' own scatter)."""
    r = np.where(sol.slot_fixed, sol.residual_cyc, np.nan)
    out: list[int] = []
    ok = np.isfinite(r) & (tab.arc >= 0)
    if not ok.any():
        return out
    arcs = tab.arc[ok]
    vals = r[ok]
    n = np.bincount(arcs, minlength=tab.n_arcs)
    s1 = np.bincount(arcs, weights=vals, minlength=tab.n_arcs)
    s2 = np.bincount(arcs, weights=vals * vals, minlength=tab.n_arcs)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        sd = np.sqrt(np.maximum(s2 / n - mean * mean, 0.0))
        t = np.abs(mean) / np.maximum(sd / np.sqrt(n), 1e-4)
    bad = (n >= MIN_ARC_EPOCHS) & (np.abs(mean) > ARC_MISFIT_CYC) & (t > ARC_MISFIT_T)
    return [int(a) for a in np.flatnonzero(bad)]
