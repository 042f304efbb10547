"""The integrity stage's parts on values whose answer is known: integer resolution, smoothing,
grading, and the marks' grade and interpolation sigma."""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.solve import interpolate as mi
from groundstation.solve.integrity import grade as gr
from groundstation.solve.integrity.lattice import FIX_SIGMA, decorrelate, ldl, resolve_lattice
from groundstation.solve.integrity.normal import time_correlation
from groundstation.solve.integrity.smooth import smooth
from groundstation.solve.trajectory import make_trajectory


def _float_constants(
    truth: np.ndarray, sd: float, rng: np.random.Generator, corr: float = 0.9,
) -> tuple[np.ndarray, np.ndarray]:
    """Float constants around ``truth`` with a covariance where every arc shares a common
    error (the clock-like part the lattice must not need) and their own ``sd``."""
    n = truth.size
    q = np.full((n, n), corr * 25.0) + np.eye(n) * sd * sd
    common = rng.normal(0.0, 5.0)
    a = truth + common + rng.normal(0.0, sd, n)
    return a, q


def test_ldl_factorises_and_the_reduction_is_unimodular() -> None:
    rng = np.random.default_rng(3)
    m = rng.normal(size=(6, 6))
    q = m @ m.T + np.eye(6)
    low, d = ldl(q)
    assert np.allclose(low.T @ np.diag(d) @ low, q)
    z, low2, d2 = decorrelate(q)
    assert np.allclose(z, np.round(z))
    assert abs(round(np.linalg.det(z))) == 1
    assert np.allclose(low2.T @ np.diag(d2) @ low2, z.T @ q @ z, atol=1e-8)


def test_sure_differences_are_fixed_to_the_truth() -> None:
    rng = np.random.default_rng(1)
    frac = 0.27
    truth = frac + rng.integers(-50, 50, 12).astype(float)
    a, q = _float_constants(truth, 0.01, rng)
    lat = resolve_lattice(a, q, np.ones(12, bool), 1.0)
    assert lat.fixed_combinations == 11 and lat.contradictions == 0
    d = lat.constants - lat.constants[0]
    assert np.allclose(d, truth - truth[0], atol=1e-6)
    # relative covariance: every difference is known
    assert np.allclose(np.diag(lat.cov), 0.0, atol=1e-8)


def test_a_half_cycle_lattice_takes_half_cycles() -> None:
    rng = np.random.default_rng(2)
    truth = 0.1 + rng.integers(-40, 40, 8) / 2.0
    a, q = _float_constants(truth, 0.005, rng)
    lat = resolve_lattice(a, q, np.ones(8, bool), 0.5)
    d = lat.constants - lat.constants[0]
    assert np.allclose(d, truth - truth[0], atol=1e-6)
    one = resolve_lattice(a, q, np.ones(8, bool), 1.0)
    assert one.fixed_combinations < 7  # on a whole-cycle lattice the half cycles stay float


def test_arcs_checked_whole_take_the_whole_cycle_lattice_among_themselves() -> None:
    # RXM-RAW: every pair on half cycles, except between arcs whose half cycle rests on the
    # receivers alone or on decisions of ours that passed their test (PhaseTable.arc_whole).
    # A float of 0.07 cycle is not sure on half cycles (0.14 step) but is on whole ones.
    rng = np.random.default_rng(6)
    truth = 0.3 + rng.integers(-40, 40, 8).astype(float)
    truth[6:] += 0.5  # two arcs half a cycle off the rest: not checked whole
    a, q = _float_constants(truth, 0.05, rng)
    whole = np.array([True] * 6 + [False] * 2)
    half = resolve_lattice(a, q, np.ones(8, bool), 0.5)
    assert half.fixed_combinations == 0
    lat = resolve_lattice(a, q, np.ones(8, bool), 0.5, whole)
    assert lat.fixed_combinations == 5 and lat.contradictions == 0
    d = lat.constants - lat.constants[0]
    assert np.allclose(d[:6], (truth - truth[0])[:6], atol=1e-6)
    assert np.all(np.diag(lat.cov)[6:] > 1e-4)  # the others stay float
    # an arc said whole but half a cycle off: a sure pair off the lattice is never rounded
    a2, q2 = _float_constants(truth, 0.01, rng)
    lie = resolve_lattice(a2, q2, np.ones(8, bool), 0.5, np.ones(8, bool))
    d2 = lie.constants - lie.constants[0]
    assert lie.contradictions >= 1
    assert np.allclose(d2[:6], (truth - truth[0])[:6], atol=1e-6)
    assert np.all(np.abs(d2[6:] - (truth - truth[0])[6:]) < 1e-6)  # tied on half cycles


def test_nothing_unsure_is_fixed() -> None:
    rng = np.random.default_rng(4)
    truth = 0.0 + rng.integers(-9, 9, 6).astype(float)
    a, q = _float_constants(truth, 0.3, rng)  # a third of a cycle: anything could be
    lat = resolve_lattice(a, q, np.ones(6, bool), 1.0)
    assert lat.fixed_combinations == 0
    assert lat.stopped_by == "sigma"
    assert lat.ratio_to_lattice >= FIX_SIGMA


def test_an_arc_off_the_lattice_is_never_rounded_onto_it() -> None:
    rng = np.random.default_rng(5)
    truth = 0.4 + rng.integers(-30, 30, 10).astype(float)
    a, q = _float_constants(truth, 0.005, rng)
    a[3] += 0.45  # e.g. a slip nobody flagged: its float is sure and wrong
    lat = resolve_lattice(a, q, np.ones(10, bool), 1.0)
    d = lat.constants - lat.constants[0]
    others = [i for i in range(10) if i != 3]
    assert np.allclose(d[others], (truth - truth[0])[others], atol=1e-6)
    # arc 3 is not tied to the others: its difference keeps its float uncertainty
    assert lat.cov[3, 3] > 1e-6
    # and the lattice says the model is wrong: one sure difference per other arc was off
    assert lat.contradictions >= 1


def test_time_correlation_is_one_for_white_noise_and_more_for_a_drift() -> None:
    rng = np.random.default_rng(6)
    t = np.arange(3000, dtype=np.int64) * 200_000_000
    white = rng.normal(size=(3000, 5))
    assert time_correlation(t, white) < 1.3
    drift = np.cumsum(rng.normal(size=(3000, 5)), axis=0) * 0.05 + rng.normal(size=(3000, 5))
    assert time_correlation(t, drift) > 5.0


def _flight(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """5 Hz positions of lines and turns (constant speed, turns of 2 s), local ENU."""
    t = np.arange(n) * 0.2
    heading = np.where((t // 20) % 2 == 0, 0.0, np.pi)
    blend = np.clip((t % 20) / 2.0, 0.0, 1.0)  # a 2 s turn at each line start
    prev = np.where((t // 20) % 2 == 0, np.pi, 0.0)
    ang = prev + (heading - prev) * blend
    v = np.column_stack([2.0 * np.cos(ang), 2.0 * np.sin(ang), np.zeros(n)])
    p = np.cumsum(v * 0.2, axis=0)
    p[:, 2] = 30.0 + 0.5 * np.sin(t / 15.0)
    return t, p


def test_the_smoother_follows_the_flight_and_says_how_sure_it_is() -> None:
    rng = np.random.default_rng(7)
    t, p = _flight(3000, rng)
    sd = np.column_stack([np.full(3000, 0.005), np.full(3000, 0.005), np.full(3000, 0.04)])
    meas = p + rng.normal(size=p.shape) * sd
    sm = smooth(t, meas, sd * sd, np.ones(3000, bool))
    ok = np.all(np.isfinite(sm.enu), axis=1)
    assert ok.mean() > 0.95
    err = np.abs(sm.enu[ok] - p[ok])
    # the vertical noise of one epoch (4 cm) is averaged down, and the sigma covers the error
    assert np.sqrt(np.mean(err[:, 2] ** 2)) < 0.02
    z = err / np.sqrt(sm.var[ok])
    assert np.mean(z <= 3.0) > 0.99


def test_the_smoother_leaves_what_does_not_fit_unsmoothed() -> None:
    rng = np.random.default_rng(8)
    t, p = _flight(1500, rng)
    sd = np.full((1500, 3), 0.005)
    meas = p + rng.normal(size=p.shape) * sd
    meas[800:805, 0] += 0.3  # 30 cm for one second: no multicopter does that
    sm = smooth(t, meas, sd * sd, np.ones(1500, bool))
    assert sm.rejected > 0
    assert not np.isfinite(sm.enu[802, 0])


def _cand(x: np.ndarray, sd: float, q: int | np.ndarray) -> gr.Candidate:
    n = x.shape[0]
    cov = np.broadcast_to(np.eye(3) * sd * sd, (n, 3, 3)).copy()
    return gr.Candidate(x, cov, np.broadcast_to(np.asarray(q), (n,)).astype(np.int64))


X0 = np.array([4146349.0, 612312.0, 4791750.0])


def test_grades_our_fix_stands_against_one_direction_but_not_against_a_checked_fix() -> None:
    n = 4
    truth = np.tile(X0, (n, 1))
    ours = _cand(truth.copy(), 0.005, 1)
    wrong = truth.copy()
    wrong[2, 2] += 0.3  # the engine 30 cm off at epoch 2
    # forward alone fixes it there: a guess our whole-arc fix outweighs
    fwd = _cand(wrong, 0.005, 1)
    bwd = _cand(truth.copy(), 0.3, 2)
    g = gr.grade(np.ones(n, bool), ours, fwd, bwd, _cand(wrong, 0.005, 1))
    assert g.grade.tolist() == [gr.FIXED] * 4
    assert gr.CHECK_NAMES[int(g.check[2])] == "arcs"
    assert gr.CHECK_NAMES[int(g.check[0])] == "arcs-and-engine"
    assert g.counts["engine fixes of one direction rejected by arcs"] == 1
    # both directions fixed it there and agree: two checked solutions disagree, neither holds
    both = _cand(wrong, 0.005, 1)
    g = gr.grade(np.ones(n, bool), ours, both, both, both)
    assert g.grade.tolist() == [gr.FIXED, gr.FIXED, gr.FLOAT, gr.FIXED]
    assert gr.CHECK_NAMES[int(g.check[2])] == "demoted:arcs-disagree"
    rot = gr._enu_rot(truth)
    sd = np.sqrt(np.diag(rot @ g.cov[2] @ rot.T))
    off = np.abs(rot @ (g.x[2] - truth[2]))
    assert np.all(off <= sd + 1e-9)  # the middle, with half the difference as sigma


def test_grades_without_our_fix() -> None:
    rng = np.random.default_rng(10)
    n = 65  # epochs 5..64: our fixes, beside which the backward float is measured
    truth = np.tile(X0, (n, 1))
    f = truth.copy()
    b = truth + np.vstack([np.zeros((5, 3)), rng.normal(size=(60, 3)) * 0.01])
    b[1, 0] += 0.4  # both fixed, 40 cm apart
    fq = np.array([1, 1, 1, 2, 2] + [1] * 60)
    bq = np.array([1, 1, 2, 1, 2] + [2] * 60)
    # the floats: backward's at epoch 2 (and beside our fixes) sure to 1 cm, forward's at
    # epoch 3 to 50 cm
    fsd = np.array([0.005, 0.005, 0.005, 0.5, 0.5] + [0.005] * 60)
    bsd = np.array([0.005, 0.005, 0.01, 0.005, 0.5] + [0.01] * 60)
    fwd = gr.Candidate(f, np.stack([np.eye(3) * s * s for s in fsd]), fq)
    bwd = gr.Candidate(b, np.stack([np.eye(3) * s * s for s in bsd]), bq)
    merged = _cand(truth, 0.01, np.array([1, 2, 1, 1, 2] + [1] * 60))
    ours_fixed = np.array([False] * 5 + [True] * 60)
    g = gr.grade(ours_fixed, _cand(truth, 0.005, 0), fwd, bwd, merged)
    assert g.factor_source.startswith("flight") and g.float_factor[0] < 2.0
    names = [gr.CHECK_NAMES[int(c)] for c in g.check]
    assert names[0] == "both-directions" and g.grade[0] == gr.FIXED
    assert g.grade[1] == gr.FLOAT  # the engine's own merge made it float
    # one direction fixed, the other's float is precise (1 cm) and agrees: fixed
    assert names[2] == "other-direction-float" and g.grade[2] == gr.FIXED
    # one direction fixed, the other's float is 50 cm: it cannot tell, demoted
    assert names[3] == "demoted:one-direction" and g.grade[3] == gr.FLOAT
    assert g.grade[4] == gr.FLOAT
    # with nothing to measure the factor on, the default makes every float a metre one
    g5 = gr.grade(np.zeros(5, bool), _cand(truth[:5], 1.0, 0),
                  gr.Candidate(f[:5], fwd.cov[:5], fq[:5]),
                  gr.Candidate(b[:5], bwd.cov[:5], bq[:5]), _cand(truth[:5], 0.01,
                                                                 np.array([1, 2, 1, 1, 2])))
    assert g5.factor_source == "default"
    assert gr.CHECK_NAMES[int(g5.check[2])] == "demoted:one-direction"


def test_the_float_factor_makes_the_float_sigmas_cover_their_errors() -> None:
    rng = np.random.default_rng(9)
    n = 400
    truth = np.tile(X0, (n, 1))
    fl = truth + rng.normal(size=(n, 3)) * 0.3  # errors of 30 cm ...
    fwd = _cand(fl, 0.05, 2)  # ... claimed as 5 cm
    (fh, fv), used = gr.float_factor(truth, [fwd], np.eye(3))
    assert used == n
    assert fh > 5.0 and fv > 5.0
    few, used_few = gr.float_factor(truth[:10], [_cand(fl[:10], 0.05, 2)], np.eye(3))
    assert used_few == 10 and few == (gr.DEFAULT_FLOAT_FACTOR, gr.DEFAULT_FLOAT_FACTOR)
    assert gr.DEFAULT_FLOAT_FACTOR >= 10.0


def test_a_mark_takes_the_worse_grade_and_an_interpolation_sigma() -> None:
    t0 = 1_400_000_000 * 10**9
    t = t0 + np.arange(6) * 200_000_000
    t = np.concatenate([t, [t[-1] + 3_000_000_000, t[-1] + 3_200_000_000]])  # a 3 s gap
    n = t.size
    x = np.tile(X0, (n, 1)) + np.arange(n)[:, None] * np.array([0.4, 0.0, 0.0])
    grade = np.array([gr.FIXED] * 5 + [gr.FLOAT] + [gr.FIXED] * 2)
    check = np.array([gr.C_ARCS] * 5 + [gr.C_FLOAT] + [gr.C_ARCS] * 2)
    traj = make_trajectory(t, x, np.where(grade == gr.FIXED, 1, 2),
                           sd_enu_m=np.full((n, 3), 0.005), grade=grade, check=check)
    times = [int(t[1]) + 100_000_000, int(t[4]) + 100_000_000, int(t[5]) + 1_500_000_000,
             int(t[6]) + 100_000_000]
    mp = mi.interpolate(traj, times, "linear", 5.0)
    assert mp.grade[0] == gr.FIXED
    assert mp.grade[1] == gr.FLOAT  # between a fixed and a float epoch
    assert gr.CHECK_NAMES[int(mp.check[1])] == "float"
    # in the 3 s gap the straight line may miss by a h^2 / 8 of the flight's acceleration
    assert mp.sd_enu_m[2, 0] >= mp.sd_enu_m[0, 0]
    assert mp.grade[3] == gr.FIXED


@pytest.mark.parametrize("accel", [0.0, 2.0])
def test_a_mark_between_fixed_epochs_is_float_when_its_own_sigma_is_not_centimetres(
    accel: float,
) -> None:
    t0 = 1_400_000_000 * 10**9
    t = t0 + np.arange(40) * 1_000_000_000  # 1 Hz
    s = np.arange(40, dtype=float)
    x = np.tile(X0, (40, 1)).astype(float)
    x[:, 0] += 0.5 * accel * s * s  # a walker speeding up
    grade = np.full(40, gr.FIXED)
    traj = make_trajectory(t, x, np.ones(40, int), sd_enu_m=np.full((40, 3), 0.005),
                           grade=grade, check=np.full(40, gr.C_ARCS))
    mp = mi.interpolate(traj, [int(t[20]) + 500_000_000], "linear", 2.0)
    if accel == 0.0:
        assert mp.grade[0] == gr.FIXED
    else:
        # 2 m/s^2 over 1 s: a straight line misses by 25 cm at mid-bracket
        assert mp.grade[0] == gr.FLOAT
        assert gr.CHECK_NAMES[int(mp.check[0])] == "demoted:interpolation"
        assert mp.sd_enu_m[0, 0] > 0.2


def test_two_floats_that_disagree_widen_the_sigma_by_their_difference() -> None:
    n = 3
    truth = np.tile(X0, (n, 1))
    f = truth.copy()
    b = truth.copy()
    b[:, 2] += 0.5  # the two directions' floats 50 cm apart vertically, each claiming 2 cm
    fwd, bwd = _cand(f, 0.02, 2), _cand(b, 0.02, 2)
    merged = _cand((f + b) / 2, 0.014, 2)
    g = gr.grade(np.zeros(n, bool), _cand(truth, 1.0, 0), fwd, bwd, merged)
    rot = gr._enu_rot(truth)
    sd = np.sqrt(np.einsum("eii->ei", np.einsum("ij,ejk,lk->eil", rot, g.cov, rot)))
    assert np.all(g.grade == gr.FLOAT)
    up = np.abs(rot @ np.array([0.0, 0.0, 0.5]))  # how much of the difference is "up"
    assert np.all(sd[:, 2] >= 0.99 * up[2])


def test_our_float_that_disagrees_with_the_engines_widens_its_sigma() -> None:
    """Seed 712 at severity 2: both engine directions float, agreeing 1.6 m from the truth
    with millimetre sigmas; our whole-arc float 8 cm off with 12 cm."""
    n = 70  # epochs 10..69: our fixes, against which the float factor is measured
    truth = np.tile(X0, (n, 1))
    rng = np.random.default_rng(3)
    eng_x = truth + np.vstack([np.tile([1.3, -1.0, 0.05], (10, 1)),
                               rng.normal(size=(60, 3)) * 0.005])
    eng = _cand(eng_x, 0.005, 2)
    ours_x = truth + np.vstack([np.tile([0.05, 0.05, 0.08], (10, 1)), np.zeros((60, 3))])
    ours = gr.Candidate(ours_x, np.stack([np.eye(3) * (0.12 if k < 10 else 0.005) ** 2
                                          for k in range(n)]), np.zeros(n, np.int64))
    ours_fixed = np.arange(n) >= 10
    g = gr.grade(ours_fixed, ours, eng, eng, eng)
    rot = gr._enu_rot(truth)
    off = np.abs((g.x[:10] - truth[:10]) @ rot.T)
    sd = np.sqrt(np.einsum("eii->ei", np.einsum("ij,ejk,lk->eil", rot, g.cov[:10], rot)))
    assert {gr.CHECK_NAMES[int(c)] for c in g.check[:10]} == {"floats-disagree"}
    assert np.all(g.grade[:10] == gr.FLOAT) and np.all(off <= sd)  # covered, not 3 sigma out
    # where our float is the engine's, the engine's stands as it was
    ours_near = gr.Candidate(eng_x.copy(), ours.cov, ours.q)
    g2 = gr.grade(ours_fixed, ours_near, eng, eng, eng)
    assert {gr.CHECK_NAMES[int(c)] for c in g2.check[:10]} == {"float"}
    assert np.allclose(g2.x[:10], eng_x[:10])
    # and ours counts only where its phase behaved as modelled
    g3 = gr.grade(ours_fixed, ours, eng, eng, eng, ours_alone=False)
    assert "floats-disagree" not in {gr.CHECK_NAMES[int(c)] for c in g3.check}


def test_two_floats_that_agree_loosely_give_their_middle_and_cover_both() -> None:
    """Seed 829 at severity 1: the engine's float 15-22 cm off in height under 4-5 cm sigmas,
    ours 2 cm off under 7 cm: within the 0.1 % agreement of each other, 4 sigma out alone."""
    n = 70
    truth = np.tile(X0, (n, 1))
    rng = np.random.default_rng(5)
    rot = gr._enu_rot(truth)
    up = rot[2]
    eng_x = truth + np.vstack([np.tile(0.2 * up, (10, 1)), rng.normal(size=(60, 3)) * 0.005])
    eng = gr.Candidate(eng_x, np.stack([np.eye(3) * (0.045 if k < 10 else 0.005) ** 2
                                        for k in range(n)]), np.array([2] * n))
    ours_x = truth + np.vstack([np.tile(0.02 * up, (10, 1)), np.zeros((60, 3))])
    ours = gr.Candidate(ours_x, np.stack([np.eye(3) * (0.07 if k < 10 else 0.005) ** 2
                                          for k in range(n)]), np.zeros(n, np.int64))
    assert np.all(gr.agree(ours_x[:10], ours.cov[:10], eng_x[:10], eng.cov[:10]))
    g = gr.grade(np.arange(n) >= 10, ours, eng, eng, eng)
    assert {gr.CHECK_NAMES[int(c)] for c in g.check[:10]} == {"float"}
    off = np.abs((g.x[:10] - truth[:10]) @ rot.T)
    sd = np.sqrt(np.einsum("eii->ei", np.einsum("ij,ejk,lk->eil", rot, g.cov[:10], rot)))
    assert np.all(off <= 3.0 * sd)
    # either float alone: the engine's 4 sigma out
    assert 0.2 / 0.045 > 3.0 and np.allclose(g.x[:10], 0.5 * (ours_x[:10] + eng_x[:10]))


def test_an_arc_the_engine_contradicts_takes_away_the_standing_of_every_epoch_on_it() -> None:
    n = 10
    truth = np.tile(X0, (n, 1))
    ours_x = truth.copy()
    ours_x[:, 0] += 0.08  # our solution rests on one wrong arc for the whole stretch
    ours = _cand(ours_x, 0.005, 1)
    checked = truth.copy()
    fq = np.array([1] * 5 + [2] * 5)  # the engine fixed (both ways) only the first half
    eng = gr.Candidate(checked, np.stack([np.eye(3) * (0.005 if q == 1 else 0.5) ** 2
                                          for q in fq]), fq)
    arcs = np.full((n, 8), -1)
    arcs[:, :6] = [3, 4, 5, 6, 7, 9]
    plain = gr.grade(np.ones(n, bool), ours, eng, eng, eng)
    assert np.all(plain.grade[5:] == gr.FIXED)  # without the arcs, the rest would stand
    g = gr.grade(np.ones(n, bool), ours, eng, eng, eng, ours_arcs=arcs)
    # ours in doubt on its arcs: the engine's checked fix stands where it has one ...
    assert np.all(g.grade[:5] == gr.FIXED)
    assert {gr.CHECK_NAMES[int(c)] for c in g.check[:5]} == {"both-directions"}
    assert np.allclose(g.x[:5], truth[:5])
    # ... and where it has none, ours does not stand alone
    assert not np.any(g.grade[5:] == gr.FIXED)


def test_a_demoted_fix_keeps_no_fix_sigma() -> None:
    n = 3
    truth = np.tile(X0, (n, 1))
    wrong = truth.copy()
    wrong[:, 0] += 0.2  # forward fixed 20 cm off
    fwd = _cand(wrong, 0.005, 1)
    bwd = _cand(truth + 0.02, 0.5, 2)  # backward float, too loose to confirm anything
    merged = _cand(wrong, 0.005, 1)
    g = gr.grade(np.zeros(n, bool), _cand(truth, 1.0, 0), fwd, bwd, merged)
    assert np.all(g.grade == gr.FLOAT)
    err = np.linalg.norm(g.x - truth, axis=1)
    sd = np.sqrt(np.trace(g.cov, axis1=1, axis2=2) / 3.0)
    assert np.all(err <= 3 * sd)


def test_a_code_only_epoch_says_so() -> None:
    """A newcomer's finding: "single 32 (float 32)", a code position whose check said float."""
    n = 3
    truth = np.tile(X0, (n, 1))
    single = _cand(truth, 2.0, 5)
    g = gr.grade(np.zeros(n, bool), _cand(truth, 1.0, 0), single, single, single)
    assert np.all(g.grade == gr.SINGLE)
    assert {gr.CHECK_NAMES[int(c)] for c in g.check} == {"code-only"}
    assert gr.CHECK_TEXT["code-only"].startswith("no carrier-phase solution")
