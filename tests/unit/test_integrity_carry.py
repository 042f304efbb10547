"""A fix of one direction confirmed by a checked fix at another epoch, through the phase of
the arcs both rest on (``carried-along-arcs``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt
from sky import Sky

from groundstation.gnss.orbit import L1_WAVELENGTH_M
from groundstation.solve.integrity import grade as gr
from groundstation.solve.integrity.carry import MIN_SHARED_ARCS, confirmed_along_arcs
from groundstation.solve.integrity.table import PhaseTable

FloatArray = npt.NDArray[np.float64]
SITE = np.array([4146349.2471, 612312.5498, 4791750.8505])
N_SV = 7
COV = np.diag([0.006, 0.007, 0.015]) ** 2  # an engine's fixed position: millimetres, 1.5 cm up


def _flight(seed: int = 3, restart_at_s: float | None = None
            ) -> tuple[PhaseTable, FloatArray]:
    """Seven satellites at 5 Hz for 5 min over a circling rover, one arc each (or, from
    ``restart_at_s`` on, new arcs for satellites 4-7: three left continuous)."""
    rng = np.random.default_rng(seed)
    t_s = np.arange(0.0, 300.0, 0.2)
    n = t_s.size
    ang = 0.1 * t_s
    x = SITE + 100.0 + np.stack([40 * np.cos(ang), 40 * np.sin(ang), 3 * np.sin(0.05 * t_s)], 1)
    arc = np.tile(np.arange(N_SV), (n, 1))
    if restart_at_s is not None:
        arc[t_s >= restart_at_s, 3:] += N_SV
    na = int(arc.max()) + 1
    tab = PhaseTable(
        t_ns=np.round(t_s * 1e9).astype(np.int64), svs=tuple(range(1, N_SV + 1)),
        sd_cyc=np.zeros((n, N_SV)), sd_code_m=np.zeros((n, N_SV)),
        sigma_cyc=np.full((n, N_SV), 0.01), sigma_code_m=np.full((n, N_SV), 0.5), arc=arc,
        n_arcs=na, arc_sv=np.arange(na) % N_SV, base_age_s=np.zeros(n),
        geo=Sky(SITE, t_s, N_SV, rng),  # type: ignore[arg-type]
        lattice_cyc=0.5)
    rng_m, _ = tab.geometry(x)
    sd = (rng_m / L1_WAVELENGTH_M + rng.integers(-50, 50, na).astype(float)[arc]
          + rng.normal(0.0, 30.0, n)[:, None] + rng.normal(0.0, 0.005, (n, N_SV)))
    return replace(tab, sd_cyc=sd), x


def _one_each(x: FloatArray, k: int, k2: int, x_k: FloatArray
              ) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """Forward fixed at ``k`` only (at ``x_k``), a checked fix at ``k2`` (at the truth plus a
    few millimetres)."""
    n = x.shape[0]
    fx, bx = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    fx[k], bx[k2] = x_k, x[k2] + 0.004
    f, b = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    f[k], b[k2] = True, True
    return fx, bx, f, b


def test_a_right_fix_is_confirmed_by_a_checked_fix_minutes_away() -> None:
    tab, x = _flight()
    fx, bx, f, b = _one_each(x, 100, 1200, x[100] + np.array([0.005, -0.004, 0.01]))
    cov = np.broadcast_to(COV, (x.shape[0], 3, 3))
    got = confirmed_along_arcs(tab, fx, cov, f, bx, cov, b)
    assert got[100] and got.sum() == 1


def test_a_fix_a_decimetre_off_is_not() -> None:
    tab, x = _flight()
    cov = np.broadcast_to(COV, (x.shape[0], 3, 3))
    for off in ([0.10, 0.0, 0.0], [0.0, 0.0, 0.12], [0.06, -0.06, 0.05]):
        fx, bx, f, b = _one_each(x, 100, 1200, x[100] + np.array(off))
        assert not confirmed_along_arcs(tab, fx, cov, f, bx, cov, b)[100], off


def test_positions_too_loose_to_see_a_decimetre_confirm_nothing() -> None:
    """Two positions whose summed sigma is 3 cm up cannot tell a fix 10 cm off from a right
    one with the power the check needs (seed 523 of the sweep): a right fix is not confirmed
    either."""
    tab, x = _flight()
    fx, bx, f, b = _one_each(x, 100, 1200, x[100])
    loose = np.broadcast_to(np.diag([0.006, 0.007, 0.022]) ** 2, (x.shape[0], 3, 3))
    assert not confirmed_along_arcs(tab, fx, loose, f, bx, loose, b)[100]
    assert confirmed_along_arcs(tab, fx, loose * 0.5, f, bx, loose * 0.5, b)[100]


def test_an_arc_whose_phase_stepped_between_the_two_epochs_breaks_the_check() -> None:
    """A repair half a cycle wrong between the two fixes: the checked integers do not carry
    over on that arc, and the check must fail rather than pass the fix."""
    tab, x = _flight()
    sd = tab.sd_cyc.copy()
    sd[600:, 2] += 0.5
    tab = replace(tab, sd_cyc=sd)
    cov = np.broadcast_to(COV, (x.shape[0], 3, 3))
    fx, bx, f, b = _one_each(x, 100, 1200, x[100])
    assert not confirmed_along_arcs(tab, fx, cov, f, bx, cov, b)[100]


def test_too_few_shared_arcs_check_nothing() -> None:
    tab, x = _flight(restart_at_s=150.0)  # three satellites continue past 150 s
    assert N_SV - 4 < MIN_SHARED_ARCS
    cov = np.broadcast_to(COV, (x.shape[0], 3, 3))
    fx, bx, f, b = _one_each(x, 100, 1200, x[100])
    assert not confirmed_along_arcs(tab, fx, cov, f, bx, cov, b).any()


def test_the_grade_names_the_check() -> None:
    n = 3
    x = np.tile(SITE, (n, 1))
    cov = np.broadcast_to(COV, (n, 3, 3)).copy()
    fwd = gr.Candidate(x, cov, np.array([1, 1, 2]))
    bwd = gr.Candidate(x + 5.0, cov * 1e4, np.array([2, 2, 2]))  # a float far off, metres
    merged = gr.Candidate(x, cov, np.array([1, 1, 2]))
    none = gr.Candidate(np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan), np.zeros(n, int))
    g = gr.grade(np.zeros(n, dtype=bool), none, fwd, bwd, merged, ours_alone=False,
                 by_arcs=np.array([True, False, False]))
    assert [gr.CHECK_NAMES[c] for c in g.check] == [
        "carried-along-arcs", "demoted:one-direction", "float"]
    assert g.grade.tolist() == [gr.FIXED, gr.FLOAT, gr.FLOAT]
