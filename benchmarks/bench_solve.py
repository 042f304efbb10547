"""Solver core timing: interpolation at 1000 marks and photo matching of 5000 photos.

Run: python benchmarks/bench_solve.py [--marks 1000] [--photos 5000] [--repeat 3]
Each method is timed against a naive reference in the same process, so the ratios hold across
machines: linear = a Python loop with bisect per mark; spline = scipy's CubicSpline (natural) if
scipy is installed; smoother = three per-axis 3-state filterpy filters + RTS; matching = the
offset vote over every photo-mark difference one photo at a time, then nearest-mark pairing by
a full scan per photo. Results are checked to agree with the reference.
"""

from __future__ import annotations

import argparse
import bisect
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation.geodesy import enu_rotation, llh_to_ecef
from groundstation.solve import clockoffset, photos
from groundstation.solve import interpolate as ip
from groundstation.solve.photosim import photo_scenario
from groundstation.solve.trajectory import Trajectory, make_trajectory

FloatArray = npt.NDArray[np.float64]
T0 = 2022 * 604_800 * 10**9


def best_of(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def flight(n_marks: int) -> tuple[Trajectory, list[int | None], FloatArray]:
    rng = np.random.default_rng(0)
    span = n_marks * 1.5 + 10
    t = np.arange(0.0, span, 0.2)
    enu = np.column_stack([20 * np.sin(0.1 * t), 15 * np.sin(0.07 * t), 30 + np.sin(0.05 * t)])
    enu += rng.normal(0, 0.01, enu.shape)
    org = np.array(llh_to_ecef(53.28, -9.06, 60.0))
    rot = np.array(enu_rotation(53.28, -9.06))
    traj = make_trajectory(T0 + np.round(t * 1e9).astype(np.int64), org + enu @ rot,
                           np.ones(t.size, np.int64), sd_enu_m=np.full((t.size, 3), 0.01))
    tm = np.sort(rng.uniform(1.0, span - 1.0, n_marks))
    return traj, [int(T0 + round(x * 1e9)) for x in tm], t


def naive_linear(traj: Trajectory, times: list[int | None]) -> FloatArray:
    tt = traj.t_gps_ns.tolist()
    out = np.empty((len(times), 3))
    for k, tm in enumerate(times):
        assert tm is not None
        i = bisect.bisect_right(tt, tm)
        a, b = tt[i - 1], tt[i]
        w = (tm - a) / (b - a)
        out[k] = traj.ecef_m[i - 1] * (1 - w) + traj.ecef_m[i] * w
    return out


def scipy_spline(traj: Trajectory, times: list[int | None]) -> FloatArray | None:
    try:
        from scipy.interpolate import CubicSpline  # type: ignore[import-untyped,unused-ignore]
    except ImportError:
        return None
    t = (traj.t_gps_ns - traj.t_gps_ns[0]) / 1e9
    origin = traj.ecef_m[0]
    cs = CubicSpline(t, traj.ecef_m - origin, bc_type="natural")
    q = (np.array(times, dtype=np.int64) - traj.t_gps_ns[0]) / 1e9
    return np.asarray(cs(q) + origin)


def per_axis_smoother(traj: Trajectory, times: list[int | None]) -> FloatArray:
    from filterpy.common import Q_continuous_white_noise
    from filterpy.kalman import KalmanFilter

    t_ep = (traj.t_gps_ns - traj.t_gps_ns[0]) / 1e9
    t_mk = (np.array(times, dtype=np.int64) - traj.t_gps_ns[0]) / 1e9
    allt = np.concatenate([t_ep, t_mk])
    is_mark = np.concatenate([np.zeros(t_ep.size, bool), np.ones(t_mk.size, bool)])
    order = np.lexsort((is_mark, allt))
    origin = traj.ecef_m[0]
    out = np.empty((t_mk.size, 3))
    for axis in range(3):
        kf = KalmanFilter(dim_x=3, dim_z=1)
        kf.x = np.array([[traj.ecef_m[0, axis] - origin[axis]], [0.0], [0.0]])
        kf.P = np.diag([1e-4, 25.0, 4.0])
        kf.H = np.array([[1.0, 0.0, 0.0]])
        zs, fs, qs = [], [], []
        prev = allt[order[0]]
        for j in order.tolist():
            dt = allt[j] - prev
            prev = allt[j]
            fs.append(np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]]))
            qs.append(Q_continuous_white_noise(3, dt, 1.0))
            zs.append(None if is_mark[j] else traj.ecef_m[j, axis] - origin[axis])
        xs, ps, _, _ = kf.batch_filter(zs, Fs=fs, Qs=qs, Rs=[1e-4] * len(zs))
        xs, _, _, _ = kf.rts_smoother(xs, ps, Fs=fs, Qs=qs)
        rows = [k for k, j in enumerate(order.tolist()) if is_mark[j]]
        marks = [j - t_ep.size for j in order.tolist() if is_mark[j]]
        out[marks, axis] = np.asarray(xs)[rows, 0, 0] + origin[axis]
    return out


def naive_match(photo_s: FloatArray, mark_s: FloatArray) -> tuple[float, list[tuple[int, int]]]:
    """Vote over every difference photo by photo, refine, pair each photo with its nearest."""
    w = clockoffset.VOTE_BIN_S
    base = float(mark_s.min() - photo_s.max()) - 1.0
    size = int((mark_s.max() - photo_s.min() - base) / w) + 2
    votes = np.zeros(size)
    for p in photo_s.tolist():
        np.add.at(votes, np.round((mark_s - p - base) / w).astype(np.int64), 1.0)
    half = int(round(clockoffset.MAX_PAIR_S / w))
    box = np.convolve(votes, np.ones(2 * half + 1), mode="same")
    coarse = base + int(np.argmax(box)) * w
    steps = np.arange(-0.8, 0.8 + 1e-9, 0.01)
    costs = []
    for s in steps.tolist():
        r = np.array([np.min(np.abs(mark_s - (p + coarse + s))) for p in photo_s.tolist()])
        costs.append(np.sum(np.minimum(r, clockoffset.MAX_PAIR_S)))
    off = coarse + float(steps[int(np.argmin(costs))])
    pairs = []
    for i, p in enumerate(photo_s.tolist()):
        r = np.abs(mark_s - (p + off))
        j = int(np.argmin(r))
        if r[j] <= clockoffset.MAX_PAIR_S:
            pairs.append((i, j))
    return off, pairs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--marks", type=int, default=1000)
    ap.add_argument("--photos", type=int, default=5000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    traj, times, _ = flight(a.marks)
    print(f"interpolation: {a.marks} marks on a 5 Hz trajectory of {len(traj)} epochs")
    print("| method | ours | reference | reference / ours | max difference |")
    print("|---|---:|---:|---:|---:|")
    refs: dict[str, Callable[[], FloatArray | None]] = {
        "linear": lambda: naive_linear(traj, times),
        "spline": lambda: scipy_spline(traj, times),
        "smoother": lambda: per_axis_smoother(traj, times),
    }
    for method, ref_fn in refs.items():
        reps = 1 if method == "smoother" else a.repeat
        t_ours, mp = best_of(lambda m=method: ip.interpolate(traj, times, m), reps)  # type: ignore[misc]
        t_ref, ref = best_of(ref_fn, reps)
        if ref is None:
            print(f"| {method} | {t_ours * 1e3:.1f} ms | (scipy missing) | | |")
            continue
        diff = float(np.max(np.linalg.norm(mp.ecef_m - ref, axis=1)))
        print(f"| {method} | {t_ours * 1e3:.1f} ms | {t_ref * 1e3:.1f} ms | "
              f"{t_ref / t_ours:.1f} | {diff * 1e3:.3f} mm |")
    sc = photo_scenario(a.photos, subsec=True, seed=1)
    import datetime as dt

    from groundstation.solve.exif import Photo

    ph = [Photo(p.name, "", int(p.exif_datetime.replace(tzinfo=dt.UTC).timestamp()) * 10**9,
                int(p.subsec or "0") * 10_000_000) for p in sc.photos]
    pt = clockoffset.photo_times(ph)
    marks: list[int | None] = list(sc.mark_t_gps_ns)
    t_ours, res = best_of(lambda: photos.match(pt, marks), a.repeat)
    mark_s = np.array(sc.mark_t_gps_ns, dtype=np.float64) / 1e9
    t_ref, (off_ref, pairs_ref) = best_of(lambda: naive_match(pt.t_s, mark_s), 1)
    correct = sum(1 for p in res.pairs if sc.truth[p.photo] == p.mark)
    ref_correct = sum(1 for i, j in pairs_ref if sc.truth[i] == j)
    print(f"\nmatching: {a.photos} photos, {len(marks)} marks (5 % lost, 5 % extra, bursts of 4)")
    print("| | time | offset | correct pairs |")
    print("|---|---:|---:|---:|")
    print(f"| ours (FFT vote, O(n log n)) | {t_ours * 1e3:.1f} ms | {res.offset_s:+.2f} s | "
          f"{correct} / {a.photos - sc.truth.count(-1)} |")
    print(f"| naive (every difference, full scans) | {t_ref * 1e3:.1f} ms | {off_ref:+.2f} s | "
          f"{ref_correct} / {a.photos - sc.truth.count(-1)} |")
    print(f"| ratio naive / ours | **{t_ref / t_ours:.1f}** | | |")


if __name__ == "__main__":
    main()
