"""Whole-flight least squares of every arc's constant from all of the flight's code and phase.

What this module owns: the per-epoch normal equations of the between-receiver code and phase
(:mod:`.table`), the constants of the arcs estimated from all epochs at once (float), and the
code-only positions the phase solution is linearised at.

Model, per epoch ``t`` and satellite ``s`` (metres, linearised at a trajectory ``x0``)::

    phase:  lambda * res_phase[t, s] = -u[t, s] . dx[t] + c[t] + lambda * A[arc(t, s)] + e
    code:            res_code[t, s]  = -u[t, s] . dx[t] + c[t]                          + e

The position change ``dx[t]`` and the clock ``c[t]`` are free at every epoch (no dynamics are
assumed: a multicopter may do anything between epochs) and are eliminated epoch by epoch; what
is left is a normal system in the arc constants ``A`` alone, summed over the flight. An arc's
constant is known from its own code-minus-phase over its length and, through the epochs it
shares with others, from the geometry.

The code's errors are not white on a real antenna (multipath is correlated for tens of
seconds): its weight is divided by the correlation its own residuals show
(:func:`code_correlation`), so that averaging many epochs of code does not pretend to more than
it knows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation.gnss.orbit import L1_WAVELENGTH_M
from groundstation.solve.integrity.table import PhaseTable

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

LAM = L1_WAVELENGTH_M
PHASE_FLOOR_M = 0.002
"""Smallest noise of one between-receiver phase [m]."""
CODE_FLOOR_M = 0.2
"""Smallest noise of one between-receiver code [m]."""


@dataclass(frozen=True, slots=True)
class EpochSystem:
    """Each epoch's normal equations with the position and clock still in them.

    Attributes:
        nxx: (n_ep, 4, 4) position+clock block.
        nxa: (n_ep, 4, n_sv) position+clock x the satellite slots' arc constants [per cycle].
        naa: (n_ep, n_sv) the slots' own diagonal [per cycle^2].
        bx: (n_ep, 4) right-hand side of the position and clock.
        ba: (n_ep, n_sv) right-hand side of the slots [per cycle].
        ok: (n_ep,) the epoch determines its position (enough code).
        phase_used: (n_ep, n_sv) slots with a phase in the system.
    """

    nxx: FloatArray
    nxa: FloatArray
    naa: FloatArray
    bx: FloatArray
    ba: FloatArray
    ok: BoolArray
    phase_used: BoolArray


def epoch_system(tab: PhaseTable, x0: FloatArray, code_inflation: float = 1.0,
                 phase_scale: float = 1.0, arcs: BoolArray | None = None) -> EpochSystem:
    """The per-epoch normal equations at trajectory ``x0`` (see the module doc); with
    ``arcs``, the phase of those arcs only."""
    res_phase, los = tab.residuals(x0)
    res_code = tab.code_residuals(x0)
    n_ep, n_sv = res_phase.shape
    use_p = np.isfinite(res_phase) & (tab.arc >= 0)
    if arcs is not None:
        use_p &= arcs[np.maximum(tab.arc, 0)]
    use_c = np.isfinite(res_code) & np.all(np.isfinite(los), axis=2)
    sp_m = np.maximum(tab.sigma_cyc * LAM, PHASE_FLOOR_M) * phase_scale
    sc_m = np.maximum(tab.sigma_code_m, CODE_FLOOR_M) * np.sqrt(code_inflation)
    wp = np.where(use_p, 1.0 / (sp_m * sp_m), 0.0)
    wc = np.where(use_c, 1.0 / (sc_m * sc_m), 0.0)
    h = np.concatenate([-np.nan_to_num(los), np.ones((n_ep, n_sv, 1))], axis=2)
    yp = np.where(use_p, res_phase * LAM, 0.0)
    yc = np.where(use_c, res_code, 0.0)
    nxx = np.einsum("esi,esj,es->eij", h, h, wp + wc)
    bx = np.einsum("esi,es->ei", h, wp * yp + wc * yc)
    nxa = np.einsum("esi,es->eis", h, wp * LAM)
    naa = wp * LAM * LAM
    ba = wp * LAM * yp
    ok = np.sum(use_c, axis=1) >= 5
    nxx[~ok] = np.eye(4)
    bx[~ok] = 0.0
    nxa[~ok] = 0.0
    naa[~ok] = 0.0
    ba[~ok] = 0.0
    return EpochSystem(nxx, nxa, naa, bx, ba, ok, use_p & ok[:, None])


@dataclass(frozen=True, slots=True)
class FloatArcs:
    """The float constants of the arcs and their covariance (cycles)."""

    a: FloatArray
    q: FloatArray
    informed: BoolArray
    """Arcs with phase in the system (the others carry no information)."""


def reduced(sys: EpochSystem) -> tuple[FloatArray, FloatArray]:
    """Each epoch's normal equations in its satellite slots' constants alone, the position
    and clock eliminated: ((n_ep, n_sv, n_sv) matrices, (n_ep, n_sv) right-hand sides)."""
    n_sv = sys.naa.shape[1]
    inv = np.linalg.inv(sys.nxx)
    k = np.einsum("eij,ejs->eis", inv, sys.nxa)  # (n_ep, 4, n_sv)
    red = -np.einsum("eis,eit->est", sys.nxa, k)
    red[:, np.arange(n_sv), np.arange(n_sv)] += sys.naa
    rhs = sys.ba - np.einsum("eis,ei->es", k, sys.bx)
    return red, rhs


def float_arcs(tab: PhaseTable, sys: EpochSystem) -> FloatArcs:
    """The arcs' constants from the whole flight: the epochs' positions and clocks
    eliminated, the reduced normal equations summed and solved."""
    red, rhs = reduced(sys)
    arc = np.where(sys.phase_used, tab.arc, -1)
    na = tab.n_arcs
    big = np.zeros((na, na))
    ii = np.broadcast_to(arc[:, :, None], red.shape)
    jj = np.broadcast_to(arc[:, None, :], red.shape)
    sel = (ii >= 0) & (jj >= 0)
    np.add.at(big, (ii[sel], jj[sel]), red[sel])
    b = np.zeros(na)
    np.add.at(b, arc[arc >= 0], rhs[arc >= 0])
    informed = np.diag(big) > 0
    idx = np.flatnonzero(~informed)
    big[idx, idx] = 1.0
    q = np.linalg.inv(big)
    q = 0.5 * (q + q.T)
    a = q @ b
    a[~informed] = np.nan
    return FloatArcs(a, q, informed)


def code_correlation(tab: PhaseTable, x: FloatArray, clock_m: FloatArray,
                     max_lag_s: float = 120.0) -> float:
    """How many times the code's variance must be multiplied for its errors' correlation in
    time (:func:`time_correlation` of the code residuals)."""
    return time_correlation(tab.t_ns, tab.code_residuals(x) - clock_m[:, None], max_lag_s)


def clock_m(tab: PhaseTable, x: FloatArray, a: FloatArray) -> FloatArray:
    """Each epoch's clock [m] from the phase with constants ``a`` (weighted mean)."""
    res, _ = tab.residuals(x)
    av = np.where(tab.arc >= 0, a[np.maximum(tab.arc, 0)], np.nan)
    v = (res - av) * LAM
    w = np.where(np.isfinite(v), 1.0 / np.maximum(tab.sigma_cyc * LAM, PHASE_FLOOR_M) ** 2, 0.0)
    num = np.nansum(np.where(np.isfinite(v), v, 0.0) * w, axis=1)
    den = np.sum(w, axis=1)
    return np.where(den > 0, num / np.maximum(den, 1e-300), 0.0)


def code_positions(tab: PhaseTable, start: FloatArray, iterations: int = 5) -> FloatArray:
    """Each epoch's position from the between-receiver code alone (metre level: the point the
    phase solution is linearised at). NaN where fewer than 5 satellites."""
    n_ep = tab.n_epochs
    x = np.broadcast_to(np.asarray(start, dtype=np.float64), (n_ep, 3)).copy()
    ok = np.zeros(n_ep, dtype=bool)
    for _ in range(iterations):
        rc = tab.code_residuals(x)
        _, los = tab.geometry(x)
        use = np.isfinite(rc) & np.all(np.isfinite(los), axis=2)
        w = np.where(use, 1.0 / np.maximum(tab.sigma_code_m, CODE_FLOOR_M) ** 2, 0.0)
        h = np.concatenate([-np.nan_to_num(los), np.ones((n_ep, los.shape[1], 1))], axis=2)
        normal = np.einsum("esi,esj,es->eij", h, h, w)
        rhs = np.einsum("esi,es->ei", h, w * np.where(use, rc, 0.0))
        ok = np.sum(use, axis=1) >= 5
        normal[~ok] = np.eye(4)
        rhs[~ok] = 0.0
        d = np.linalg.solve(normal, rhs[..., None])[..., 0]
        x = x + d[:, :3]
    x[~ok] = np.nan
    return x


def float_phase_residuals(tab: PhaseTable, system: EpochSystem, x: FloatArray,
                          fl: FloatArcs) -> FloatArray:
    """The whole-flight float solution's phase residuals [m] (NaN where no phase was used)."""
    a_slot = np.where(system.phase_used & (tab.arc >= 0),
                      np.nan_to_num(fl.a)[np.maximum(tab.arc, 0)], 0.0)
    inv = np.linalg.inv(system.nxx)
    dx = np.einsum("eij,ej->ei", inv, system.bx - np.einsum("eis,es->ei", system.nxa, a_slot))
    res, los = tab.residuals(x)
    h = np.concatenate([-np.nan_to_num(los), np.ones((*los.shape[:2], 1))], axis=2)
    e = (res - a_slot) * LAM - np.einsum("esi,ei->es", h, dx)
    return np.where(system.phase_used, e, np.nan)


def phase_variance_factor(tab: PhaseTable, e_m: FloatArray) -> float:
    """How much larger the phase's scatter is than :attr:`PhaseTable.sigma_cyc` says, from
    the float solution's residuals ``e_m``: the median of the squared standardised residuals
    over its value for a normal distribution (0.455), at least 1. Multipath and the base's
    age make a real antenna's phase noisier than its C/N0 alone (the simulator's is not)."""
    sp = np.maximum(tab.sigma_cyc * LAM, PHASE_FLOOR_M)
    z = (e_m / sp)[np.isfinite(e_m)]
    if z.size < 20:
        return 1.0
    return max(1.0, float(np.median(z * z)) / 0.455)


def time_correlation(t_ns: IntArray, e: FloatArray, max_lag_s: float = 120.0) -> float:
    """``1 + 2 sum(rho_k)`` of residuals ``e`` (epochs x satellites, NaN: none) over the lags
    where their autocorrelation stays positive (at most ``max_lag_s``): by how much averaging
    N epochs of them is worth fewer than N independent ones; 1 for white noise."""
    if t_ns.size < 3:
        return 1.0
    dt = float(np.median(np.diff(t_ns))) / 1e9
    have = np.isfinite(e)
    count = np.maximum(have.sum(axis=0), 1)
    r = np.where(have, e - (np.where(have, e, 0.0).sum(axis=0) / count)[None, :], np.nan)
    var = float(np.nanmean(r * r)) if have.any() else 0.0
    if not np.isfinite(var) or var <= 0:
        return 1.0
    total = 1.0
    max_k = max(1, int(max_lag_s / max(dt, 1e-3)))
    k = 1
    while k < min(max_k, t_ns.size - 1):
        rho = float(np.nanmean(r[k:] * r[:-k])) / var
        if not np.isfinite(rho) or rho < 0.05:
            break
        total += 2.0 * rho
        k = k + 1 if k < 10 else int(k * 1.25)
    return total
