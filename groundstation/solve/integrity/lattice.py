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
    """

    constants: FloatArray
    cov: FloatArray
    reference: int
    fixed_combinations: int
    combinations: int
    stopped_by: str
    ratio_to_lattice: float


def resolve_lattice(a: FloatArray, q: FloatArray, informed: BoolArray,
                    step_cyc: float) -> Lattice:
    """Decorrelate and bootstrap the differences of the constants ``a`` (covariance ``q``)
    on a lattice of ``step_cyc`` cycles (see the module doc)."""
    na = a.size
    ok = np.flatnonzero(informed)
    if ok.size == 0:
        return Lattice(np.full(na, np.nan), np.zeros((na, na)), -1, 0, 0, "sure", 0.0)
    ref = int(ok[np.argmin(np.diag(q)[ok])])
    idx = ok[ok != ref]
    t = np.zeros((idx.size, na))
    t[np.arange(idx.size), idx] = 1.0
    t[:, ref] = -1.0
    an = np.nan_to_num(a)
    dd = t @ an / step_cyc
    qd = t @ q @ t.T / (step_cyc * step_cyc)
    qd = 0.5 * (qd + qd.T)
    n = idx.size
    fixed_n = 0
    stopped = "sure"
    first_float = 0.0
    if n:
        try:
            z, low, dvar = decorrelate(qd)
        except np.linalg.LinAlgError:
            z, low, dvar = np.eye(n), np.eye(n), np.full(n, np.inf)
        zh = z.T @ dd
        cond = zh.copy()
        fixed_vals = np.full(n, np.nan)
        for i in range(n - 1, -1, -1):
            # conditional value given the ones already fixed (after i)
            cond[i] = zh[i] - float(low[i + 1 :, i] @ (cond[i + 1 :] - fixed_vals[i + 1 :]))
            s = float(np.sqrt(max(dvar[i], 0.0)))
            r = round(cond[i])
            if s >= FIX_SIGMA:
                stopped, first_float = "sigma", s
                break
            if abs(cond[i] - r) >= FIX_DISTANCE:
                stopped, first_float = "off-lattice", s
                break
            fixed_vals[i] = r
            fixed_n += 1
        if fixed_n:
            zk = z[:, n - fixed_n :]
            vals = fixed_vals[n - fixed_n :]
            m = zk.T @ qd @ zk
            gain = qd @ zk @ np.linalg.inv(m)
            dd = dd - gain @ (zk.T @ dd - vals)
            qd = qd - gain @ zk.T @ qd
            qd = 0.5 * (qd + qd.T)
    const = np.full(na, np.nan)
    const[ref] = a[ref]
    const[idx] = a[ref] + dd * step_cyc
    cov = np.zeros((na, na))
    cov[np.ix_(idx, idx)] = qd * step_cyc * step_cyc
    return Lattice(const, cov, ref, fixed_n, n, stopped, first_float)
