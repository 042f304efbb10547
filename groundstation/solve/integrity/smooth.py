"""A Kalman smoother over the fixed epochs, its motion noise estimated from the flight itself.

What this module owns: turning each epoch's own fixed position (millimetres horizontally,
centimetres vertically with six satellites, each epoch on its own) into a trajectory that
uses its neighbours: a constant-acceleration model per local axis (east, north, up) with white
jerk, filtered forward and smoothed backward (Rauch-Tung-Striebel) over each run of
consecutive fixed epochs.

The jerk's spectral density is not a constant of ours: for each of the horizontal and
vertical axes, and for each window of :data:`LIKELIHOOD_WINDOW_S` of the flight, it is the
value on a grid of powers of two under which that window's positions are most likely (the
filter's innovation likelihood); the flight is smoothed with the :data:`WINDOW_QUANTILE`
quantile of those, so that the model follows the flight's quick manoeuvres, not its average
straight line. Where the smoothed trajectory still does not fit the epochs' own positions
(:func:`_misfit`), the epochs keep their own positions and covariances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

JERK_GRID = tuple(2.0**k for k in range(-12, 9))
"""Jerk spectral densities tried [m^2/s^5]: 0.00024 (a glide) to 256 (a crash landing)."""
MAX_GAP_S = 5.0
"""A gap longer than this between fixed epochs ends a run (the model is not trusted across)."""
LIKELIHOOD_WINDOW_S = 20.0
"""Length of the windows the jerk density is chosen on (a turn or a climb fits in one)."""
WINDOW_QUANTILE = 1.0
"""The windows' most likely densities are summarised by this quantile: all but the tenth of
the flight with the quickest manoeuvres are smoothed no looser than they need."""
CHECK_WINDOW_S = 2.0
"""The smoothed trajectory is checked against the epochs' own positions over windows of this
length (+- half of it): long enough to see a manoeuvre, short enough to keep it local."""
CHECK_LEVEL = 1e-3
"""False-alarm probability of a window's check (chi-square of the standardised residuals)."""


def _transition(dt: float) -> tuple[FloatArray, FloatArray]:
    """Constant-acceleration transition and the process noise per unit jerk density."""
    f = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    q = np.array([
        [dt**5 / 20, dt**4 / 8, dt**3 / 6],
        [dt**4 / 8, dt**3 / 3, dt**2 / 2],
        [dt**3 / 6, dt**2 / 2, dt],
    ])
    return f, q


def _runs(t_s: FloatArray, ok: BoolArray) -> list[npt.NDArray[np.int64]]:
    """Index arrays of the runs of ``ok`` epochs without a gap over :data:`MAX_GAP_S`."""
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return []
    cut = np.flatnonzero(np.diff(t_s[idx]) > MAX_GAP_S) + 1
    return [r for r in np.split(idx, cut) if r.size]


def _filter(t_s: FloatArray, z: FloatArray, r: FloatArray, q: FloatArray, keep: bool
            ) -> tuple[FloatArray, list[FloatArray] | None]:
    """Forward filter of K independent 1-D constant-acceleration models over one run.

    Args:
        t_s: (n,) times; z: (n, K) positions; r: (n, K) their variances; q: (K,) jerk density.
        keep: keep what the smoother needs.

    Returns:
        (log-likelihood of each epoch's innovation per model (n, K), [x_pred, p_pred,
        x_filt, p_filt, F] or None).
    """
    n, k = z.shape
    steps = np.zeros((n, k))
    x = np.zeros((k, 3))
    x[:, 0] = z[0]
    p = np.zeros((k, 3, 3))
    p[:, 0, 0] = r[0]
    p[:, 1, 1] = 25.0  # 5 m/s: any multicopter's speed
    p[:, 2, 2] = 25.0  # 5 m/s^2
    store: list[FloatArray] | None = None
    if keep:
        xp = np.zeros((n, k, 3))
        pp = np.zeros((n, k, 3, 3))
        xf = np.zeros((n, k, 3))
        pf = np.zeros((n, k, 3, 3))
        fs = np.zeros((n, 3, 3))
    for i in range(n):
        if i:
            f, q1 = _transition(float(t_s[i] - t_s[i - 1]))
            x = x @ f.T
            p = f @ p @ f.T + q[:, None, None] * q1
        else:
            f = np.eye(3)
        if keep:
            xp[i], pp[i], fs[i] = x, p, f
        if i:
            s = p[:, 0, 0] + r[i]
            gain = p[:, :, 0] / s[:, None]
            v = z[i] - x[:, 0]
            x = x + gain * v[:, None]
            p = p - gain[:, :, None] * p[:, 0, None, :]
            steps[i] = -0.5 * (np.log(2 * np.pi * s) + v * v / s)
        if keep:
            xf[i], pf[i] = x, p
    if keep:
        store = [xp, pp, xf, pf, fs]
    return steps, store


def _smooth(store: list[FloatArray]) -> tuple[FloatArray, FloatArray]:
    """Rauch-Tung-Striebel pass over a forward run: smoothed positions and variances (n, K)."""
    xp, pp, xf, pf, fs = store
    n = xf.shape[0]
    xs = xf.copy()
    ps = pf.copy()
    for i in range(n - 2, -1, -1):
        f = fs[i + 1]
        c = pf[i] @ f.T @ np.linalg.inv(pp[i + 1])
        xs[i] = xf[i] + np.einsum("kij,kj->ki", c, xs[i + 1] - xp[i + 1])
        ps[i] = pf[i] + c @ (ps[i + 1] - pp[i + 1]) @ np.transpose(c, (0, 2, 1))
    return xs[:, :, 0], ps[:, :, 0, 0]


@dataclass(frozen=True, slots=True)
class Smoothed:
    """The smoothed fixed epochs.

    Attributes:
        enu: (n, 3) smoothed positions, local east/north/up (NaN where not smoothed).
        var: (n, 3) their variances.
        jerk_h, jerk_v: the jerk densities chosen [m^2/s^5].
        runs: runs smoothed.
        rejected: epochs where the smoothed trajectory does not fit the epochs' own positions
            (a manoeuvre too quick for the model): left unsmoothed (NaN in ``enu``).
    """

    enu: FloatArray
    var: FloatArray
    jerk_h: float
    jerk_v: float
    runs: int
    rejected: int


def smooth(t_s: FloatArray, enu: FloatArray, var: FloatArray, ok: BoolArray) -> Smoothed:
    """Smooth the epochs ``ok`` (positions ``enu``, variances ``var``, both (n, 3)).

    The jerk density is chosen per horizontal (east and north together) and vertical axis by
    the summed innovation likelihood over all runs.
    """
    n = t_s.size
    out = np.full((n, 3), np.nan)
    out_var = np.full((n, 3), np.nan)
    runs = [r for r in _runs(t_s, ok) if r.size >= 3]
    if not runs:
        return Smoothed(out, out_var, float("nan"), float("nan"), 0, 0)
    grid = np.asarray(JERK_GRID)
    g = grid.size
    picks_h: list[float] = []
    picks_v: list[float] = []
    for r in runs:
        z = np.repeat(enu[r], g, axis=1)  # (n, 3*g): axis-major blocks of the grid
        rv = np.repeat(var[r], g, axis=1)
        q = np.tile(grid, 3)
        lik, _ = _filter(t_s[r], z, rv, q, keep=False)
        lik = lik.reshape(-1, 3, g)
        win = np.floor((t_s[r] - t_s[r[0]]) / LIKELIHOOD_WINDOW_S).astype(np.int64)
        for w in np.unique(win).tolist():
            sel = win == w
            if sel.sum() < 3:
                continue
            ll = lik[sel].sum(axis=0)
            picks_h.append(float(grid[int(np.argmax(ll[0] + ll[1]))]))
            picks_v.append(float(grid[int(np.argmax(ll[2]))]))
    if not picks_h:
        return Smoothed(out, out_var, float("nan"), float("nan"), 0, 0)
    best_h = float(np.quantile(picks_h, WINDOW_QUANTILE, method="higher"))
    best_v = float(np.quantile(picks_v, WINDOW_QUANTILE, method="higher"))
    qv = np.array([best_h, best_h, best_v])
    for r in runs:
        _, store = _filter(t_s[r], enu[r], var[r], qv, keep=True)
        assert store is not None
        xs, ps = _smooth(store)
        out[r] = xs
        out_var[r] = ps
    bad = _misfit(t_s, enu, var, out, ok)
    out[bad] = np.nan
    out_var[bad] = np.nan
    return Smoothed(out, out_var, best_h, best_v, len(runs), int(bad.sum()))


def _misfit(t_s: FloatArray, enu: FloatArray, var: FloatArray, sm: FloatArray,
            ok: BoolArray) -> BoolArray:
    """Epochs inside a window of :data:`CHECK_WINDOW_S` where the smoothed positions do not
    fit the epochs' own (chi-square of the standardised differences over the window's epochs
    and three axes, at :data:`CHECK_LEVEL`)."""
    from scipy import special

    n = t_s.size
    use = ok & np.all(np.isfinite(sm), axis=1)
    z2 = np.where(use[:, None], (enu - sm) ** 2 / var, 0.0).sum(axis=1)
    c = np.concatenate([[0.0], np.cumsum(z2)])
    cn = np.concatenate([[0], np.cumsum(use)])
    half = CHECK_WINDOW_S / 2
    lo = np.searchsorted(t_s, t_s - half, side="left")
    hi = np.searchsorted(t_s, t_s + half, side="right")
    s = c[hi] - c[lo]
    k = (cn[hi] - cn[lo]) * 3
    limit = special.chdtri(np.maximum(k, 1), CHECK_LEVEL)
    fail = use & (k > 0) & (s > limit)
    bad = np.zeros(n, dtype=bool)
    for i in np.flatnonzero(fail).tolist():
        bad[lo[i]:hi[i]] = True
    return np.asarray(bad & use, dtype=bool)
