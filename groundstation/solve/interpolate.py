"""Antenna positions at time marks: linear, natural cubic spline, Kalman RTS smoother (sans-I/O).

All methods work in a local east/north/up frame at the first epoch (so the smoother's per-axis
noise is east/north/up) and return ECEF. Marks are never bridged silently across a data gap:
a mark whose bracketing epochs are more than ``max_gap_s`` apart carries :data:`FLAG_GAP`.
Quality per mark is RTKLIB's rule: the worse (larger Q) of the two bracketing epochs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from groundstation.errors import ConfigError, InputError
from groundstation.geodesy import ecef_to_llh, enu_rotation
from groundstation.rules.marks import edge_time_ns
from groundstation.solve.arrays import read_npz, write_npz
from groundstation.solve.integrity import grade as gr
from groundstation.solve.trajectory import Q_FIX, Q_FLOAT, Q_SINGLE, Trajectory

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

Edge = Literal["falling", "rising", "mid"]
EDGES: tuple[Edge, ...] = ("falling", "rising", "mid")
Method = Literal["linear", "spline", "smoother"]

FLAG_GAP = 1
"""The bracketing epochs are more than ``max_gap_s`` apart: the position bridges a data gap."""
FLAG_OUTSIDE = 2
"""The mark lies before the first or after the last epoch: no position."""
FLAG_NO_EDGE = 4
"""The mark lacks the chosen edge (e.g. ``mid`` without a rising edge): no position."""
FLAG_METRE_LEVEL = 8
"""The trajectory is the receiver's own fix, metre level."""
FLAG_NOT_FIXED = 16
"""At least one bracketing epoch is not an ambiguity-fixed solution."""
FLAG_DUPLICATE = 32
"""Same time as an earlier mark."""
FLAG_CAMERA_CLOCK = 64
"""A photo without a received mark, timed by the camera clock fitted on the paired photos."""

FLAG_NAMES: dict[int, str] = {
    FLAG_GAP: "gap",
    FLAG_OUTSIDE: "outside",
    FLAG_NO_EDGE: "no_edge",
    FLAG_METRE_LEVEL: "metre_level",
    FLAG_NOT_FIXED: "not_fixed",
    FLAG_DUPLICATE: "duplicate",
    FLAG_CAMERA_CLOCK: "camera_clock",
}

DEFAULT_MAX_GAP_S = 1.0
DEFAULT_SIGMA_BY_Q_M = {Q_FIX: 0.02, Q_FLOAT: 0.3, Q_SINGLE: 3.0}
"""σ assumed per axis by the smoother when a solution carries no standard deviations."""


def flag_names(mask: int) -> list[str]:
    """Names of the bits set in a flag mask, in bit order."""
    return [name for bit, name in FLAG_NAMES.items() if mask & bit]


def mark_time_ns(
    falling_t_gps_ns: int | None,
    rising_t_gps_ns: int | None,
    edge: Edge,
    shutter_delay_ms: float = 0.0,
) -> int | None:
    """The instant a mark stands for: the chosen edge (or their midpoint) plus the shutter delay
    (the rule of :func:`groundstation.rules.marks.edge_time_ns`)."""
    if edge not in EDGES:
        raise ConfigError("--edge", f"unknown edge {edge!r} (falling, rising, mid)")
    return edge_time_ns(falling_t_gps_ns, rising_t_gps_ns, edge, round(shutter_delay_ms * 1e6))


@dataclass(frozen=True, slots=True)
class MarkPositions:
    """Antenna positions at the marks, in the marks' order.

    Attributes:
        t_gps_ns: the instants interpolated at (-1 where the mark has no usable time).
        ecef_m: (m, 3) positions, NaN where there is none.
        sd_enu_m: (m, 3) σ east, north, up.
        quality: RTKLIB Q, the worse of the bracketing epochs (0 when no position).
        bracket_s: seconds between the bracketing epochs (0 on an epoch, NaN outside).
        flags: bit mask per mark (``FLAG_*``).
        method: interpolation method name.
        grade: grade code (``integrity.grade.GRADE_NAMES``), the worse of the bracketing
            epochs', and float where the mark's own sigma is not a centimetre one.
        check: the check that decided the grade (``integrity.grade.CHECK_NAMES``).
    """

    t_gps_ns: IntArray
    ecef_m: FloatArray
    sd_enu_m: FloatArray
    quality: IntArray
    bracket_s: FloatArray
    flags: IntArray
    method: str
    grade: IntArray
    check: IntArray

    def __len__(self) -> int:
        return int(self.t_gps_ns.size)

    @property
    def positioned(self) -> int:
        return int(np.sum(np.isfinite(self.ecef_m[:, 0])))


_SAVED = ("t_gps_ns", "ecef_m", "sd_enu_m", "quality", "bracket_s", "flags", "grade", "check")


def save_npz(positions: Sequence[MarkPositions], path: Path) -> None:
    """Write several sets of positions as one NumPy ``.npz`` (plain arrays, no pickled
    objects: :func:`load_npz`)."""
    arrays: dict[str, Any] = {"count": np.array(len(positions))}
    for i, mp in enumerate(positions):
        arrays[f"{i}_method"] = np.array(mp.method)
        arrays.update({f"{i}_{k}": getattr(mp, k) for k in _SAVED})
    write_npz(path, arrays)


def load_npz(path: Path) -> list[MarkPositions]:
    """The sets of positions :func:`save_npz` wrote.

    Raises:
        InputError: unreadable, or not what :func:`save_npz` writes.
    """
    a = read_npz(path, "positions")
    try:
        out = []
        for i in range(int(a["count"])):
            n = int(a[f"{i}_t_gps_ns"].size)

            def col(k: str, shape: tuple[int, ...], dtype: type, i: int = i) -> Any:
                return a[f"{i}_{k}"].astype(dtype).reshape(shape)

            out.append(MarkPositions(
                t_gps_ns=col("t_gps_ns", (n,), np.int64),
                ecef_m=col("ecef_m", (n, 3), np.float64),
                sd_enu_m=col("sd_enu_m", (n, 3), np.float64),
                quality=col("quality", (n,), np.int64),
                bracket_s=col("bracket_s", (n,), np.float64),
                flags=col("flags", (n,), np.int64), method=str(a[f"{i}_method"]),
                grade=col("grade", (n,), np.int64), check=col("check", (n,), np.int64)))
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"{path}: not positions this program wrote ({err!r})") from err
    return out


@dataclass(frozen=True, slots=True)
class _Local:
    origin: FloatArray
    rot: FloatArray  # ECEF -> ENU rows
    t0_ns: int
    t_s: FloatArray
    enu: FloatArray

    def to_ecef(self, enu: FloatArray) -> FloatArray:
        return np.asarray(self.origin + enu @ self.rot, dtype=np.float64)


def _local(traj: Trajectory) -> _Local:
    origin = traj.ecef_m[0].copy()
    lat, lon, _ = ecef_to_llh(*origin)
    rot = np.array(enu_rotation(lat, lon))
    t0 = int(traj.t_gps_ns[0])
    t_s = (traj.t_gps_ns - t0).astype(np.float64) / 1e9
    enu = (traj.ecef_m - origin) @ rot.T
    return _Local(origin, rot, t0, t_s, enu)


@dataclass(frozen=True, slots=True)
class _Brackets:
    valid: npt.NDArray[np.bool_]  # has a usable time inside the trajectory
    lo: IntArray
    hi: IntArray
    w: FloatArray  # weight of hi
    tm_s: FloatArray
    bracket_s: FloatArray
    flags: IntArray
    quality: IntArray
    grade: IntArray
    check: IntArray


def _brackets(
    traj: Trajectory, loc: _Local, times: Sequence[int | None], max_gap_s: float
) -> _Brackets:
    m = len(times)
    has_t = np.array([t is not None for t in times], bool)
    t_ns = np.array([t if t is not None else -1 for t in times], np.int64)
    flags = np.where(has_t, 0, FLAG_NO_EDGE).astype(np.int64)
    tt = traj.t_gps_ns
    inside = has_t & (t_ns >= tt[0]) & (t_ns <= tt[-1])
    flags |= np.where(has_t & ~inside, FLAG_OUTSIDE, 0)
    # Duplicate marks: same instant as an earlier one.
    order = np.argsort(t_ns, kind="stable")
    dup = np.zeros(m, bool)
    if m > 1:
        same = (np.diff(t_ns[order]) == 0) & has_t[order][1:]
        dup[order[1:][same]] = True
    flags |= np.where(dup, FLAG_DUPLICATE, 0)
    hi = np.clip(np.searchsorted(tt, t_ns, side="right"), 1, len(tt) - 1) if len(tt) > 1 else (
        np.zeros(m, np.int64))
    lo = np.maximum(hi - 1, 0)
    tm_s = (t_ns - loc.t0_ns).astype(np.float64) / 1e9
    span = loc.t_s[hi] - loc.t_s[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(span > 0, (tm_s - loc.t_s[lo]) / span, 0.0)
    on_epoch = t_ns == tt[lo]
    on_last = t_ns == tt[hi]
    w = np.where(on_epoch, 0.0, np.where(on_last, 1.0, w))
    bracket = np.where(on_epoch | on_last, 0.0, span)
    flags |= np.where(inside & (bracket > max_gap_s), FLAG_GAP, 0)
    q = traj.quality
    ql = np.where(w < 1.0, q[lo], 0)
    qh = np.where(w > 0.0, q[hi], 0)
    quality = np.where(inside, np.maximum(ql, qh), 0)
    flags |= np.where(inside & (quality != Q_FIX), FLAG_NOT_FIXED, 0)
    if traj.metre_level:
        flags |= np.where(inside, FLAG_METRE_LEVEL, 0)
    g, c = traj.grades(), traj.checks()
    gl = np.where(w < 1.0, g[lo], 0)
    gh = np.where(w > 0.0, g[hi], 0)
    grade = np.where(inside, np.maximum(gl, gh), gr.NONE)
    check = np.where(inside, np.where(gh > gl, c[hi], c[lo]), 0)
    return _Brackets(
        inside, lo.astype(np.int64), hi.astype(np.int64), w, tm_s,
        np.where(inside, bracket, np.nan), flags.astype(np.int64), quality.astype(np.int64),
        grade.astype(np.int64), check.astype(np.int64),
    )


def _linear_enu(loc: _Local, b: _Brackets) -> FloatArray:
    w = b.w[:, None]
    return np.asarray(loc.enu[b.lo] * (1.0 - w) + loc.enu[b.hi] * w, dtype=np.float64)


def _bracket_sd(traj: Trajectory, b: _Brackets) -> FloatArray:
    sd_lo = traj.sd_enu_m[b.lo]
    sd_hi = traj.sd_enu_m[b.hi]
    w = b.w[:, None]
    sd = np.where(w <= 0.0, sd_lo, np.where(w >= 1.0, sd_hi, np.fmax(sd_lo, sd_hi)))
    return np.asarray(sd, dtype=np.float64)


def _interpolation_sd(traj: Trajectory, b: _Brackets) -> FloatArray:
    """What a straight line through the two bracketing epochs misses the antenna by:
    ``a w (1 - w) h^2 / 2`` (``h^2 a / 8`` at mid-bracket) with ``h`` the bracket, ``w`` the
    mark's place in it and ``a`` the larger acceleration measured at either epoch (over +-1 s:
    a vehicle's acceleration changes over seconds, so across a radio gap it is the one on
    either side); where neither can be measured, the largest the flight shows."""
    from groundstation.solve.engine.dynamics import local_acceleration

    acc = local_acceleration(traj.t_gps_ns, traj.ecef_m)
    peak = float(np.nanmax(acc)) if np.isfinite(acc).any() else 0.0
    a = np.fmax(acc[b.lo], acc[b.hi])
    a = np.where(np.isfinite(a), a, peak)
    h = np.nan_to_num(b.bracket_s)
    w = np.clip(b.w, 0.0, 1.0)
    return np.asarray(a * w * (1.0 - w) * h * h / 2.0, dtype=np.float64)


def _finish(
    traj: Trajectory, loc: _Local, b: _Brackets, enu: FloatArray, sd: FloatArray,
    times: Sequence[int | None], method: str, interpolation_sd: FloatArray | None = None,
) -> MarkPositions:
    ecef = loc.to_ecef(enu)
    ecef[~b.valid] = np.nan
    sd = sd.copy()
    if interpolation_sd is not None:
        sd = np.sqrt(sd * sd + interpolation_sd[:, None] ** 2)
    sd[~b.valid] = np.nan
    t_ns = np.array([t if t is not None else -1 for t in times], np.int64)
    grade, check = b.grade.copy(), b.check.copy()
    # A mark between two fixed epochs is itself a centimetre position only if its own sigma
    # says so (a gap bridged, a quick manoeuvre between 5 Hz epochs).
    loose = (grade == gr.FIXED) & ~np.all(sd <= gr.FIXED_MAX_SIGMA_M, axis=1)
    grade[loose] = gr.FLOAT
    check[loose] = gr.C_DEM_INTERP
    quality = np.where(loose, Q_FLOAT, b.quality)
    flags = np.where(loose, b.flags | FLAG_NOT_FIXED, b.flags)
    return MarkPositions(t_ns, ecef, sd, quality, b.bracket_s, flags, method, grade, check)


def _check(traj: Trajectory) -> None:
    if len(traj) == 0:
        from groundstation.errors import InputError

        raise InputError(f"{traj.source or 'trajectory'}: no epochs to interpolate between")


def interpolate_linear(
    traj: Trajectory, times: Sequence[int | None], max_gap_s: float = DEFAULT_MAX_GAP_S
) -> MarkPositions:
    """Straight line between the two bracketing epochs (what RTKLIB does for events)."""
    _check(traj)
    loc = _local(traj)
    b = _brackets(traj, loc, times, max_gap_s)
    return _finish(traj, loc, b, _linear_enu(loc, b), _bracket_sd(traj, b), times, "linear",
                   _interpolation_sd(traj, b))


def _segments(t_s: FloatArray, max_gap_s: float) -> list[tuple[int, int]]:
    """[start, end) index ranges of runs without a gap longer than ``max_gap_s``."""
    cuts = np.flatnonzero(np.diff(t_s) > max_gap_s) + 1
    bounds = [0, *cuts.tolist(), t_s.size]
    return [(a, b) for a, b in zip(bounds, bounds[1:], strict=False) if b > a]


def natural_spline_m2(x: FloatArray, y: FloatArray) -> FloatArray:
    """Second derivatives of the natural cubic spline through (x, y[:, k]) for every column k.

    Solves the tridiagonal system with the Thomas algorithm (zero curvature at both ends).
    """
    n = x.size
    m2 = np.zeros_like(y)
    if n < 3:
        return m2
    h = np.diff(x)
    rhs = 6.0 * (np.diff(y[1:], axis=0) / h[1:, None] - np.diff(y[:-1], axis=0) / h[:-1, None])
    diag = (2.0 * (h[:-1] + h[1:])).tolist()
    sub = h[1:-1].tolist()  # sub- and super-diagonal are the same (symmetric)
    k = n - 2
    # Thomas algorithm on Python floats (numpy scalars are ~10x slower in a loop).
    cols = [rhs[:, j].tolist() for j in range(y.shape[1])]
    c = [0.0] * k
    dd = [[0.0] * k for _ in cols]
    den = diag[0]
    c[0] = sub[0] / den if k > 1 else 0.0
    for j, col in enumerate(cols):
        dd[j][0] = col[0] / den
    for i in range(1, k):
        s_prev = sub[i - 1]
        den = diag[i] - s_prev * c[i - 1]
        c[i] = sub[i] / den if i < k - 1 else 0.0
        for j, col in enumerate(cols):
            dj = dd[j]
            dj[i] = (col[i] - s_prev * dj[i - 1]) / den
    for i in range(k - 2, -1, -1):
        ci = c[i]
        for dj in dd:
            dj[i] -= ci * dj[i + 1]
    d = np.array(dd).T
    m2[1:-1] = d
    return m2


def interpolate_spline(
    traj: Trajectory, times: Sequence[int | None], max_gap_s: float = DEFAULT_MAX_GAP_S
) -> MarkPositions:
    """Natural cubic spline through the epochs of each gap-free segment.

    Marks inside a gap fall back to the straight line across it (and carry :data:`FLAG_GAP`).
    """
    _check(traj)
    loc = _local(traj)
    b = _brackets(traj, loc, times, max_gap_s)
    enu = _linear_enu(loc, b)
    for a, e in _segments(loc.t_s, max_gap_s):
        if e - a < 3:
            continue
        x, y = loc.t_s[a:e], loc.enu[a:e]
        m2 = natural_spline_m2(x, y)
        sel = b.valid & (b.lo >= a) & (b.hi < e) & ((b.flags & FLAG_GAP) == 0)
        lo = b.lo[sel] - a
        hi = lo + 1
        h = x[hi] - x[lo]
        t = b.tm_s[sel]
        A = ((x[hi] - t) / h)[:, None]
        B = ((t - x[lo]) / h)[:, None]
        hh = (h * h / 6.0)[:, None]
        enu[sel] = (
            A * y[lo] + B * y[hi] + ((A**3 - A) * m2[lo] + (B**3 - B) * m2[hi]) * hh
        )
    return _finish(traj, loc, b, enu, _bracket_sd(traj, b), times, "spline",
                   _interpolation_sd(traj, b))


def _ca_matrices(dt: float, q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Transition and process noise of a constant-acceleration model, 3 axes, white jerk ``q``."""
    f1 = np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    q1 = np.array(
        [
            [dt**5 / 20, dt**4 / 8, dt**3 / 6],
            [dt**4 / 8, dt**3 / 3, dt**2 / 2],
            [dt**3 / 6, dt**2 / 2, dt],
        ]
    )
    F = np.zeros((9, 9))
    Q = np.zeros((9, 9))
    for k in range(3):
        s = slice(3 * k, 3 * k + 3)
        F[s, s] = f1
        Q[s, s] = q1 * q[k]
    return F, Q


def interpolate_smoother(
    traj: Trajectory,
    times: Sequence[int | None],
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    *,
    jerk_psd_m2_s5: tuple[float, float, float] = (1.0, 1.0, 0.5),
) -> MarkPositions:
    """Kalman filter + Rauch-Tung-Striebel smoother, constant acceleration per axis (filterpy).

    Each mark is inserted in the epoch sequence as a prediction-only step (no measurement), so
    the smoothed state and covariance *at the mark* come out of the smoother directly; σ is the
    square root of the smoothed position variance. Measurement noise is each epoch's own σ
    (or :data:`DEFAULT_SIGMA_BY_Q_M` when the solution has none).

    Args:
        traj: the antenna trajectory.
        times: mark instants (GPS ns), ``None`` for marks without one.
        max_gap_s: longer brackets are flagged (the smoother still bridges them, flagged).
        jerk_psd_m2_s5: white-jerk spectral density east, north, up.
    """
    from filterpy.kalman import KalmanFilter  # the one module that owns filterpy

    _check(traj)
    loc = _local(traj)
    b = _brackets(traj, loc, times, max_gap_s)
    n = len(traj)
    sd = traj.sd_enu_m.copy()
    fallback = np.array([DEFAULT_SIGMA_BY_Q_M.get(int(q), 1.0) for q in traj.quality])
    sd = np.where(np.isfinite(sd) & (sd > 0), sd, fallback[:, None])
    sd = np.maximum(sd, 1e-3)
    mark_idx = np.flatnonzero(b.valid)
    # Merge epochs and marks by time; at equal times the epoch comes first.
    t_all = np.concatenate([loc.t_s, b.tm_s[mark_idx]])
    is_mark = np.concatenate([np.zeros(n, bool), np.ones(mark_idx.size, bool)])
    src = np.concatenate([np.arange(n), mark_idx])
    order = np.lexsort((is_mark, t_all))
    t_all, is_mark, src = t_all[order], is_mark[order], src[order]
    q = np.asarray(jerk_psd_m2_s5, dtype=np.float64)
    H = np.zeros((3, 9))
    H[0, 0] = H[1, 3] = H[2, 6] = 1.0
    kf = KalmanFilter(dim_x=9, dim_z=3)
    kf.x = np.zeros((9, 1))
    kf.x[[0, 3, 6], 0] = loc.enu[0]
    kf.P = np.diag([sd[0, 0] ** 2, 25.0, 4.0, sd[0, 1] ** 2, 25.0, 4.0, sd[0, 2] ** 2, 9.0, 4.0])
    kf.H = H
    zs: list[FloatArray | None] = []
    Fs, Qs, Rs = [], [], []
    prev = t_all[0]
    for t, mk, s in zip(t_all.tolist(), is_mark.tolist(), src.tolist(), strict=True):
        F, Q = _ca_matrices(t - prev, q)
        prev = t
        Fs.append(F)
        Qs.append(Q)
        if mk:
            zs.append(None)
            Rs.append(np.eye(3))
        else:
            zs.append(loc.enu[s].reshape(3, 1))
            Rs.append(np.diag(sd[s] ** 2))
    # The first step predicts over dt = 0 from the prior set above.
    xs, ps, _, _ = kf.batch_filter(zs, Fs=Fs, Qs=Qs, Rs=Rs, Hs=[H] * len(zs))
    xs_s, ps_s, _, _ = kf.rts_smoother(xs, ps, Fs=Fs, Qs=Qs)
    enu = _linear_enu(loc, b)
    sd_out = _bracket_sd(traj, b)
    straight = _interpolation_sd(traj, b)
    rows = np.flatnonzero(is_mark)
    targets = src[rows]
    xs_s = np.asarray(xs_s).reshape(len(zs), 9)
    var = np.asarray(ps_s)[rows][:, [0, 3, 6], [0, 3, 6]]
    # The smoother's position and sigma only between two fixed epochs, and never tighter than
    # their own sigma: it takes every epoch's error as independent of the next one's and
    # averages them down, where errors last for seconds (multipath) to tens of seconds (a
    # float solution). Float marks keep the straight line and its sigma (on the real
    # 2018-10-09 flight as a LEA-6T through the seed link, fault seed 2, the smoother's float
    # positions put 23 camera positions beyond 3 sigma, 17 with its sigma floored at the
    # epochs', 1 with the straight line, as before).
    on_fixed = b.quality[targets] == Q_FIX
    smooth_sd = np.fmax(np.sqrt(np.clip(var, 0.0, None)), sd_out[targets])
    enu[targets[on_fixed]] = xs_s[rows[on_fixed]][:, [0, 3, 6]]
    sd_out[targets[on_fixed]] = smooth_sd[on_fixed]
    straight[targets[on_fixed]] = 0.0
    return _finish(traj, loc, b, enu, sd_out, times, "smoother", straight)


DEFAULT_METHOD = "smoother"
"""What ``solve`` and the solver service interpolate with unless told: between two fixed
epochs the smoother bridges a radio gap with a sigma that stays centimetric where the straight
line's ``a w (1 - w) h^2 / 2`` does not (measured: ``benchmarks/RESULTS.md``, "Camera positions
across radio gaps"); elsewhere it is the straight line."""

INTERPOLATORS: dict[str, Callable[[Trajectory, Sequence[int | None], float], MarkPositions]] = {
    "linear": interpolate_linear,
    "spline": interpolate_spline,
    "smoother": interpolate_smoother,
}
"""Method name -> function(trajectory, mark times, max_gap_s)."""
METHOD_TEXT: dict[str, str] = {
    "linear": "straight line between the epochs around each mark",
    "spline": "cubic spline through the epochs of each stretch without a gap",
    "smoother": "smoothed trajectory between fixed epochs, straight line elsewhere",
}
"""Method name -> what it does, in the words the printout and the report use."""


def interpolate(
    traj: Trajectory,
    times: Sequence[int | None],
    method: str = DEFAULT_METHOD,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
) -> MarkPositions:
    """Positions at ``times`` with the named method (see :data:`INTERPOLATORS`)."""
    try:
        fn = INTERPOLATORS[method]
    except KeyError as err:
        raise ConfigError(
            "--interp", f"unknown method {method!r} (known: {', '.join(INTERPOLATORS)})"
        ) from err
    if not max_gap_s > 0:
        raise ConfigError("--max-gap", f"must be positive, got {max_gap_s}")
    return fn(traj, times, max_gap_s)
