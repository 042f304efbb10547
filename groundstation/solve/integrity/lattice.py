"""Integer resolution of the arcs' constants: decorrelation and partial bootstrapping.

What this module owns: from the float constants of the arcs and their covariance, which
integer combinations of them are sure enough to fix, and the constants and covariance that
follow when those are held.

Only differences of constants are integers (all arcs share one fractional part), so the
constants are taken relative to one reference arc. Those differences are strongly correlated
(arcs that lived at the same time move together with the position error), so they are first
decorrelated by the LAMBDA method's integer Z-transformation (Teunissen, 1995): an integer
unimodular ``Z`` such that ``Z' Q Z = L' diag(D) L`` has small, ordered conditional variances
``D``. Fixing is then integer bootstrapping from the most precise combination on: each is
rounded if its conditional standard deviation is below :data:`FIX_SIGMA` lattice steps (5 sigma
to the rounding boundary) and its value lies within :data:`FIX_DISTANCE` of the lattice, and the
ones after it are conditioned on it; the first that is not sure ends the fixing (partial
ambiguity resolution: what is fixed never rests on a guess).

A combination that is well determined but off the lattice is a sign that the model is wrong
somewhere (an unflagged slip): it and everything after it stay float.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

FIX_SIGMA = 0.1
"""Largest conditional standard deviation of a combination that is rounded, in lattice steps."""
FIX_DISTANCE = 0.25
"""A rounded combination must lie this close to the lattice, in lattice steps."""
MAX_LAMBDA = 60
"""Largest number of groups the decorrelating stage takes on (its cost grows as the cube)."""


def ldl(q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``q = L' diag(d) L`` with ``L`` unit lower triangular, factorised from the last row up
    (so ``d[i]`` is the variance of element ``i`` conditioned on the ones after it)."""
    a = np.array(q, dtype=np.float64, copy=True)
    n = a.shape[0]
    low = np.zeros((n, n))
    d = np.zeros(n)
    for i in range(n - 1, -1, -1):
        d[i] = a[i, i]
        if d[i] <= 0.0:
            raise np.linalg.LinAlgError("covariance not positive definite")
        row = a[i, : i + 1] / np.sqrt(d[i])
        a[:i, :i] -= np.outer(row[:i], row[:i])
        low[i, : i + 1] = row / row[i]
    return low, d


def decorrelate(q: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """LAMBDA reduction: an integer ``Z`` with ``Z' q Z = L' diag(D) L`` decorrelated.

    Returns:
        (Z, L, D).
    """
    n = q.shape[0]
    low, d = ldl(q)
    z = np.eye(n)
    if n < 2:
        return z, low, d
    j = k = n - 2
    while j >= 0:
        if j <= k:
            for i in range(j + 1, n):  # integer Gauss transformation of column j by row i
                mu = round(low[i, j])
                if mu:
                    low[i:, j] -= mu * low[i:, i]
                    z[:, j] -= mu * z[:, i]
        delta = d[j] + low[j + 1, j] ** 2 * d[j + 1]
        if delta + 1e-6 < d[j + 1]:  # swapping j and j+1 makes the later variance smaller
            eta = d[j] / delta
            lam = d[j + 1] * low[j + 1, j] / delta
            d[j] = eta * d[j + 1]
            d[j + 1] = delta
            for c in range(j):
                a0, a1 = low[j, c], low[j + 1, c]
                low[j, c] = -low[j + 1, j] * a0 + a1
                low[j + 1, c] = eta * a0 + lam * a1
            low[j + 1, j] = lam
            low[j + 2 :, [j, j + 1]] = low[j + 2 :, [j + 1, j]]
            z[:, [j, j + 1]] = z[:, [j + 1, j]]
            k = j
            j = n - 2
        else:
            j -= 1
    return z, low, d


def _lambda_stage(x: FloatArray, c: FloatArray, reps: list[int], step: float
                  ) -> tuple[FloatArray, FloatArray, int, str, float]:
    """Decorrelate the representatives' differences (to the first) and bootstrap them from the
    most precise combination on, until the first that is not sure or not on the lattice.

    Returns:
        (constants and covariance conditioned on what was fixed, how many combinations were
        fixed, why it stopped, the first float combination's deviation in steps).
    """
    n = x.size
    m = len(reps) - 1
    t = np.zeros((m, n))
    t[np.arange(m), reps[1:]] = 1.0
    t[:, reps[0]] = -1.0
    dd = t @ x / step
    qd = t @ c @ t.T / (step * step)
    qd = 0.5 * (qd + qd.T)
    try:
        z, low, dvar = decorrelate(qd)
    except np.linalg.LinAlgError:
        return x, c, 0, "sigma", float("inf")
    zh = z.T @ dd
    cond = zh.copy()
    fixed_vals = np.full(m, np.nan)
    k = 0
    why, sig = "sure", 0.0
    for i in range(m - 1, -1, -1):
        cond[i] = zh[i] - float(low[i + 1 :, i] @ (cond[i + 1 :] - fixed_vals[i + 1 :]))
        s = float(np.sqrt(max(dvar[i], 0.0)))
        r = round(cond[i])
        if s >= FIX_SIGMA:
            why, sig = "sigma", s
            break
        if abs(cond[i] - r) >= FIX_DISTANCE:
            why, sig = "off-lattice", s
            break
        fixed_vals[i] = r
        k += 1
    if k:
        g = (z[:, m - k :].T @ t) / step  # (k, n): the fixed combinations of the constants
        vals = fixed_vals[m - k :]
        mm = g @ c @ g.T
        gain = c @ g.T @ np.linalg.inv(mm)
        x = x - gain @ (g @ x - vals)
        c = c - gain @ g @ c
        c = 0.5 * (c + c.T)
    return x, c, k, why, sig


@dataclass(frozen=True, slots=True)
class Lattice:
    """The constants with the sure integer combinations held.

    Attributes:
        constants: (n_arcs,) conditional constants [cycles] (NaN: arc without information).
        cov: (n_arcs, n_arcs) their conditional covariance, relative to the reference arc (its
            row and column zero: a shift common to all arcs is absorbed by each epoch's clock).
        reference: the reference arc (-1 when there is none).
        fixed_combinations: how many integer combinations were fixed.
        combinations: how many there were.
        stopped_by: why fixing stopped: "sure" (all fixed), "sigma" or "off-lattice".
        ratio_to_lattice: the conditional standard deviation (lattice steps) of the first
            combination left float (0 when all were fixed).
        contradictions: how many sure differences (or, in the decorrelated stage, sure
            combinations) lay off the lattice: each is proof that the model is wrong somewhere
            (an unflagged slip) or that something fixed before it is.
    """

    constants: FloatArray
    cov: FloatArray
    reference: int
    fixed_combinations: int
    combinations: int
    stopped_by: str
    ratio_to_lattice: float
    contradictions: int = 0


def resolve_lattice(a: FloatArray, q: FloatArray, informed: BoolArray,
                    step_cyc: float, whole: BoolArray | None = None) -> Lattice:
    """Pairwise integer bootstrapping of the constants ``a`` (covariance ``q``) on a lattice
    of ``step_cyc`` cycles.

    Only differences of constants are integers, and what a position needs is the differences
    among the arcs it sees at once: those are the best determined (arcs that live together
    move together with the position error). So the difference fixed next is, among all pairs
    of arcs not yet tied together, the one with the smallest conditional standard deviation;
    it is rounded if that deviation is below :data:`FIX_SIGMA` lattice steps and its value
    within :data:`FIX_DISTANCE` of the lattice, every constant is conditioned on it, and the
    two arcs' groups are joined. A sure difference that lies off the lattice is not used (one
    of its arcs is wrong somewhere) and the next pair is tried; the first pair not sure enough
    ends the fixing. The pairs fixed form a spanning forest of the arcs: within a group every
    difference is known, between groups nothing is claimed.

    ``whole``: the arcs two of which differ by whole cycles on a half-cycle lattice
    (:attr:`~groundstation.solve.integrity.table.PhaseTable.arc_whole`); a pair of them is
    rounded on the whole-cycle lattice (a float half as sure will do, and half a cycle is no
    value), any other pair on ``step_cyc``. The decorrelated stage stays on ``step_cyc``.
    """
    na = a.size
    ok = np.flatnonzero(informed)
    if ok.size == 0:
        return Lattice(np.full(na, np.nan), np.zeros((na, na)), -1, 0, 0, "sure", 0.0)
    ref = int(ok[np.argmin(np.diag(q)[ok])])
    x = np.nan_to_num(a[ok]).copy()
    c = np.array(q[np.ix_(ok, ok)], dtype=np.float64, copy=True)
    n = ok.size
    w_ok = np.zeros(n, dtype=bool) if whole is None else np.asarray(whole, dtype=bool)[ok]
    pair_step = np.where(w_ok[:, None] & w_ok[None, :], 2.0 * step_cyc, step_cyc)
    group = np.arange(n)
    skip = np.zeros((n, n), dtype=bool)
    fixed_n = 0
    contradictions = 0
    stopped = "sure"
    first_float = 0.0
    for _ in range(4 * n):
        dg = np.diag(c)
        var = dg[:, None] + dg[None, :] - 2.0 * c
        same = group[:, None] == group[None, :]
        # in lattice steps of each pair: the surest next, whichever its lattice
        var = np.where(same | skip, np.inf, var) / (pair_step * pair_step)
        k = int(np.argmin(var))
        i, j = divmod(k, n)
        if not np.isfinite(var[i, j]):
            break
        step = float(pair_step[i, j])
        s = float(np.sqrt(max(var[i, j], 0.0)))
        if s >= FIX_SIGMA:
            stopped, first_float = "sigma", s
            break
        d = (x[i] - x[j]) / step
        r = round(d)
        if abs(d - r) >= FIX_DISTANCE:
            skip[i, j] = skip[j, i] = True
            contradictions += 1
            continue
        g = np.zeros(n)
        g[i], g[j] = 1.0, -1.0
        cg = c @ g
        den = float(g @ cg)
        gain = cg / den
        x = x + gain * (r * step - (x[i] - x[j]))
        c = c - np.outer(gain, cg)
        c = 0.5 * (c + c.T)
        gi, gj = group[i], group[j]
        group[group == gj] = gi
        fixed_n += 1
    # Stage 2: the groups left apart, as one small integer problem (their representatives'
    # differences), decorrelated by LAMBDA: combinations of several groups can be sure where
    # no single pair is.
    reps = sorted({int(np.flatnonzero(group == g)[0]) for g in set(group.tolist())})
    if len(reps) > 1 and len(reps) <= MAX_LAMBDA:
        x, c, more, why, sig = _lambda_stage(x, c, reps, step_cyc)
        fixed_n += more
        if more or why != "sure":
            stopped, first_float = why, sig
        contradictions += why == "off-lattice"
    const = np.full(na, np.nan)
    const[ok] = x
    cov = np.zeros((na, na))
    # relative to the reference: a shift common to all arcs goes to each epoch's clock
    t = np.eye(n)
    r_ok = int(np.flatnonzero(ok == ref)[0])
    t[:, r_ok] -= 1.0
    rel = t @ c @ t.T
    cov[np.ix_(ok, ok)] = 0.5 * (rel + rel.T)
    return Lattice(const, cov, ref, fixed_n, n - 1, stopped, first_float, contradictions)
