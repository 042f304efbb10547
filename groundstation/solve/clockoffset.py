"""The camera clock's offset to GPS time, before any photo is paired: the photos' capture times
on the camera clock (bursts spread over their EXIF second), one-to-one pairing at a given offset,
and the offset chosen by voting on every photo-mark difference, refined, and settled among
equally good pairings by the plausible clock settings (UTC, a whole-hour zone, GPS time).

Sans-I/O: photo times on the camera clock and mark times in GPS seconds in, values out. The
pairing with the chosen offset is :func:`groundstation.solve.photos.match`; the clock's drift
fitted on the pairs is :mod:`groundstation.solve.camclock`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.solve.exif import Photo

FloatArray = npt.NDArray[np.float64]

MAX_PAIR_S = 0.75
"""A photo and a mark further apart than this (after the clock offset) are never paired."""
TRUNCATION_MARGIN_S = 0.1
"""Slack beyond its EXIF second allowed for a whole-second photo (offset estimate, clock drift)."""
REFINE_STEP_S = 0.01
REFINE_HALF_WIDTH_S = 0.5
VOTE_BIN_S = 0.05
MAX_VOTE_BINS = 1 << 24

BURST_SPREAD_S: dict[int, tuple[float, ...]] = {
    1: (0.0,),
    2: (-0.25, 0.25),
    3: (-0.33, 0.0, 0.33),
    4: (-0.40, -0.15, 0.15, 0.40),
}
"""Offsets from the middle of the EXIF second for photos that share it, by file order
(several photos in one EXIF second: spread over it, not stacked on its start); larger bursts
are spread evenly."""



# -- times on the camera clock ------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PhotoTimes:
    """Estimated capture times of photos on the camera clock (GPS-scale seconds).

    Attributes:
        t_s: best estimate per photo (NaN when the photo has no usable time).
        spread_s: where in its EXIF second a whole-second photo was put, relative to the middle
            (0 for a single photo, ±0.25 ... in bursts); NaN for photos with sub-second times.
        precise: the photo has ``SubSecTimeOriginal``.
    """

    t_s: FloatArray
    spread_s: FloatArray
    precise: npt.NDArray[np.bool_]


def photo_times(photos: Sequence[Photo]) -> PhotoTimes:
    """Best capture time of each photo, in GPS-scale seconds of the camera clock.

    With ``SubSecTimeOriginal`` the time is exact to the camera clock. Without it, photos that
    share an EXIF second (consecutive in file order) are spread over it as
    :data:`BURST_SPREAD_S` says; a single photo sits in the middle of its second. UTC offsets the
    camera declared are removed and leap seconds added, so what is left between these times and
    GPS time is the camera clock's own error. Unusable photos give NaN.
    """
    out = np.full(len(photos), np.nan)
    spread_out = np.full(len(photos), np.nan)
    precise = np.zeros(len(photos), bool)
    i = 0
    while i < len(photos):
        ph = photos[i]
        if not ph.usable:
            i += 1
            continue
        base = gpstime.unix_to_gps_ns(ph.utc_second_ns)
        if ph.subsec_ns is not None:
            out[i] = base / 1e9 + ph.subsec_ns / 1e9
            precise[i] = True
            i += 1
            continue
        j = i + 1
        while (
            j < len(photos)
            and photos[j].usable
            and photos[j].subsec_ns is None
            and photos[j].utc_second_ns == ph.utc_second_ns
        ):
            j += 1
        n = j - i
        spread = BURST_SPREAD_S.get(n) or tuple((k + 0.5) / n - 0.5 for k in range(n))
        for k in range(n):
            out[i + k] = base / 1e9 + 0.5 + spread[k]
            spread_out[i + k] = spread[k]
        i = j
    return PhotoTimes(out, spread_out, precise)


# -- pairing at an offset -----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Pair:
    """A photo and its mark; ``residual_s`` = mark − (photo + offset)."""

    photo: int
    mark: int
    residual_s: float


def pair_windows(
    times: PhotoTimes, max_pair_s: float, tol_precise: float
) -> tuple[FloatArray, FloatArray]:
    """Per photo, how far below and above its time (plus the offset) its mark may be.

    Sub-second photos: ``±tol_precise``. Whole-second photos: the shot happened inside its EXIF
    second, so the residual lies in ``[-0.5 - spread, 0.5 - spread]`` (plus
    :data:`TRUNCATION_MARGIN_S` for the offset); without a known spread, ``±max_pair_s``.
    """
    exact = times.precise
    has_spread = np.isfinite(times.spread_s) & ~exact
    spread = np.nan_to_num(times.spread_s)
    lower = np.where(
        exact, tol_precise,
        np.where(has_spread, np.minimum(max_pair_s, 0.5 + spread + TRUNCATION_MARGIN_S),
                 max_pair_s),
    )
    upper = np.where(
        exact, tol_precise,
        np.where(has_spread, np.minimum(max_pair_s, 0.5 - spread + TRUNCATION_MARGIN_S),
                 max_pair_s),
    )
    return lower, upper


def greedy_pairs(
    photo_s: FloatArray,
    mark_s: FloatArray,
    offset_s: float,
    tolerance_s: float | FloatArray,
    upper_s: FloatArray | None = None,
) -> list[Pair]:
    """One-to-one pairs, closest first, each photo and mark used once, none outside the window.

    The window of residuals (mark − photo − offset) is ``±tolerance_s`` (one value or one per
    photo), or ``[-tolerance_s, upper_s]`` per photo when ``upper_s`` is given.
    """
    order = np.argsort(mark_s, kind="stable")
    ms = mark_s[order]
    shifted = photo_s + offset_s
    lower = np.broadcast_to(np.asarray(tolerance_s, dtype=np.float64), shifted.shape)
    upper = lower if upper_s is None else upper_s
    lo = np.searchsorted(ms, shifted - lower, side="left")
    hi = np.searchsorted(ms, shifted + upper, side="right")
    cnt = np.where(np.isfinite(shifted), hi - lo, 0)
    ph = np.repeat(np.arange(photo_s.size), cnt)
    starts = np.repeat(lo, cnt)
    within = np.arange(ph.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    mk = order[starts + within]
    res = mark_s[mk] - shifted[ph]
    cand = np.argsort(np.abs(res), kind="stable")
    used_p: set[int] = set()
    used_m: set[int] = set()
    pairs: list[Pair] = []
    for c in cand.tolist():
        p, m = int(ph[c]), int(mk[c])
        if p in used_p or m in used_m:
            continue
        used_p.add(p)
        used_m.add(m)
        pairs.append(Pair(p, m, float(res[c])))
    pairs.sort(key=lambda x: x.photo)
    return pairs



# -- clock offset -------------------------------------------------------------------------------


def _vote_offsets(photo_s: FloatArray, mark_s: FloatArray, window_s: float) -> list[float]:
    """Candidate offsets (mark − photo), best first, by voting on every pairwise difference.

    The histogram of all photo-mark differences is a cross-correlation of the two event
    trains; it is computed with an FFT in O(B log B) (B bins of :data:`VOTE_BIN_S`), then summed
    over ``±window_s``: the value at an offset is the number of pairs within the window.
    """
    p0, m0 = float(photo_s.min()), float(mark_s.min())
    span = float(photo_s.max() - p0) + float(mark_s.max() - m0)
    w = max(VOTE_BIN_S, span / MAX_VOTE_BINS)
    ip = np.round((photo_s - p0) / w).astype(np.int64)
    im = np.round((mark_s - m0) / w).astype(np.int64)
    lp, lm = int(ip.max()) + 1, int(im.max()) + 1
    size = 1 << int(math.ceil(math.log2(lp + lm)))
    a = np.bincount(im, minlength=lm).astype(np.float64)
    b = np.bincount(lp - 1 - ip, minlength=lp).astype(np.float64)  # reversed photo train
    corr = np.fft.irfft(np.fft.rfft(a, size) * np.fft.rfft(b, size), size)[: lp + lm - 1]
    corr = np.rint(corr)
    half = max(1, int(round(window_s / w)))
    csum = np.concatenate([[0.0], np.cumsum(corr)])
    idx = np.arange(corr.size)
    votes = csum[np.minimum(idx + half + 1, corr.size)] - csum[np.maximum(idx - half, 0)]
    # lag index k means mark bin - photo bin = k - (lp - 1)
    offsets = m0 - p0 + (idx - (lp - 1)) * w
    out: list[float] = []
    for k in np.argsort(-votes, kind="stable")[:2000].tolist():
        if votes[k] <= 0:
            break
        if all(abs(offsets[k] - o) > 2 * window_s for o in out):
            out.append(float(offsets[k]))
        if len(out) >= 8:
            break
    return out


def residual_sigma_s(residual_s: FloatArray) -> float:
    """Robust σ (1.4826 × median absolute deviation) of photo-to-mark residuals, seconds.

    The one measure of how well the photos' times fit their marks once the clock offset is
    applied: the solve's printout, the report and the pairing window all use it. NaN with fewer
    than 3 residuals (no spread to speak of).
    """
    r = np.asarray(residual_s, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size < 3:
        return math.nan
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def residual_sigma_text(sigma_s: float) -> str:
    """The residual σ as both the printout and the report give it: milliseconds, or why not."""
    if not math.isfinite(sigma_s):
        return "not computed (fewer than 3 pairs)"
    return f"{sigma_s * 1e3:.1f} ms (robust)"


def _residuals(shifted: FloatArray, mark_sorted: FloatArray) -> FloatArray:
    """Signed distance from each shifted photo time to its nearest mark."""
    j = np.searchsorted(mark_sorted, shifted)
    lo = mark_sorted[np.clip(j - 1, 0, mark_sorted.size - 1)]
    hi = mark_sorted[np.clip(j, 0, mark_sorted.size - 1)]
    r_lo, r_hi = lo - shifted, hi - shifted
    return np.where(np.abs(r_lo) <= np.abs(r_hi), r_lo, r_hi)


def _cost(photo_s: FloatArray, mark_sorted: FloatArray, offset: float, cap: float) -> float:
    r = _residuals(photo_s + offset, mark_sorted)
    return float(np.sum(np.minimum(np.abs(r), cap)))


def _refined_candidates(
    photo_s: FloatArray, mark_s: FloatArray, max_pair_s: float, extra: Sequence[float] = ()
) -> list[tuple[float, int, float]]:
    """(offset, photos paired within ±window, capped residual sum) of every candidate.

    Voting picks candidates (:func:`_vote_offsets`), ``extra`` adds some; each is refined to
    :data:`REFINE_STEP_S` within ±(window + one vote bin), at least ±:data:`REFINE_HALF_WIDTH_S`,
    by minimising the capped residual sum.
    """
    ph = photo_s[np.isfinite(photo_s)]
    mk = np.unique(mark_s[np.isfinite(mark_s)])
    if ph.size == 0 or mk.size == 0:
        return []
    # The vote is a box sum, flat over up to twice the window when marks are regular: search
    # the whole plateau, not just ±REFINE_HALF_WIDTH_S around its first bin.
    half = max(REFINE_HALF_WIDTH_S, max_pair_s + VOTE_BIN_S)
    steps = np.arange(-half, half + 1e-9, REFINE_STEP_S)
    out: list[tuple[float, int, float]] = []
    for cand in [*_vote_offsets(ph, mk, max_pair_s), *extra]:
        costs = [_cost(ph, mk, cand + s, max_pair_s) for s in steps.tolist()]
        k = int(np.argmin(costs))
        off = round((cand + float(steps[k])) / REFINE_STEP_S) * REFINE_STEP_S
        paired = int(np.sum(np.abs(_residuals(ph + off, mk)) <= max_pair_s))
        out.append((off, paired, costs[k]))
    return out


PRIOR_RADIUS_S = 1.5
"""How far (s) from a plausible clock setting (:func:`prior_offsets_s`) an offset may be for that
setting to pick it among equally good pairings: a camera clock set by hand to within a second,
its whole-second EXIF time put mid-second."""
MAX_ZONE_HOURS = 14
"""Whole-hour time zones a camera clock may be set to: UTC−14 h ... UTC+14 h."""


def prior_offsets_s(leap_s: int) -> dict[float, str]:
    """The offsets (UTC − camera, s) of a camera clock set to UTC or a whole-hour zone
    (k × 3600 s, |k| <= :data:`MAX_ZONE_HOURS`) or to GPS time (−leap seconds), with what each
    means. In GPS − camera terms: leap seconds + k × 3600 s, or 0."""
    out = {float(-k * 3600): "UTC" if k == 0 else f"UTC{k:+d} h"
           for k in range(-MAX_ZONE_HOURS, MAX_ZONE_HOURS + 1)}
    out[float(-leap_s)] = "GPS time"
    return out


@dataclass(frozen=True, slots=True)
class _Fit:
    offset_s: float
    paired: int
    cost: float
    sigma_s: float
    pairs: frozenset[tuple[int, int]]


@dataclass(frozen=True, slots=True)
class OffsetChoice:
    """The clock offset :func:`choose_offset` took, and what the surveyor must be told.

    Attributes:
        offset_s: UTC − camera, seconds.
        notes: how an ambiguity was settled by the plausible clock settings.
        warnings: an ambiguity nothing settled (the pairing may be shifted by whole marks).
    """

    offset_s: float
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


def _fit(
    times: PhotoTimes, marks: FloatArray, offset_s: float, max_pair_s: float, cost: float
) -> _Fit:
    """How one offset pairs the photos: count, spread of the residuals, which pairs."""
    lower, upper = pair_windows(times, max_pair_s, max_pair_s)
    pairs = greedy_pairs(times.t_s, marks, offset_s, lower, upper)
    res = np.array([p.residual_s for p in pairs if times.precise[p.photo]], dtype=np.float64)
    if res.size < 3:
        res = np.array([p.residual_s for p in pairs], dtype=np.float64)
    return _Fit(offset_s, len(pairs), cost, residual_sigma_s(res),
                frozenset((p.photo, p.mark) for p in pairs))


def _near_equal(other: _Fit, best: _Fit, precise: bool, max_pair_s: float) -> bool:
    """``other`` is a different pairing (an offset beyond the pairing window: photos moved to
    other marks, not a burst paired in another order) that fits about as well as ``best``.

    As many photos paired is required. Whole-second photos say nothing finer than their second,
    so that is all; sub-second photos must also fit about as tightly (a shifted pairing picks
    up the jitter of the mark intervals, tens of ms).
    """
    if (other.paired < best.paired or other.pairs == best.pairs
            or abs(other.offset_s - best.offset_s) <= max_pair_s):
        return False
    if not precise:
        return True
    if not (math.isfinite(other.sigma_s) and math.isfinite(best.sigma_s)):
        return True
    return other.sigma_s <= 2.0 * best.sigma_s + 0.002


def choose_offset(
    times: PhotoTimes, marks: FloatArray, leap_s: int, max_pair_s: float = MAX_PAIR_S
) -> OffsetChoice:
    """The camera clock offset (UTC − camera), never a silent pick among equal pairings.

    Marks at regular intervals (a camera on a timer) make offsets a whole number of intervals
    apart pair a subset of photos about equally well. The best fit (most photos paired, then
    the smallest capped residual sum; candidates from :func:`_refined_candidates`) is compared
    with every other candidate, including those at the plausible clock settings
    (:func:`prior_offsets_s`). When others fit about as well (:func:`_near_equal`), the only
    one within :data:`PRIOR_RADIUS_S` of UTC or a whole-hour zone (else of GPS time) is taken,
    with a note; when none or several are, the one nearest a plausible setting is taken with a
    warning.
    """
    ph = times.t_s[np.isfinite(times.t_s)]
    mk = np.unique(marks[np.isfinite(marks)])
    if ph.size == 0 or mk.size == 0:
        return OffsetChoice(0.0)
    priors = prior_offsets_s(leap_s)
    lo, hi = float(mk[0] - ph.max()) - 1.0, float(mk[-1] - ph.min()) + 1.0
    extra = [p + d for p in priors if lo <= p <= hi
             for d in np.arange(-PRIOR_RADIUS_S, PRIOR_RADIUS_S + 1e-9, max_pair_s).tolist()]
    usable = np.nan_to_num(marks, nan=-1e18)
    fits: dict[frozenset[tuple[int, int]], _Fit] = {}
    for off, _, cost in sorted(_refined_candidates(ph, mk, max_pair_s, extra),
                               key=lambda c: (-c[1], c[2])):
        f = _fit(times, usable, off, max_pair_s, cost)
        if f.pairs not in fits or cost < fits[f.pairs].cost:
            fits[f.pairs] = f
    if not fits:
        return OffsetChoice(0.0)
    best = max(fits.values(), key=lambda f: (f.paired, -f.cost))
    precise = int(np.sum(times.precise)) * 2 >= ph.size
    near = [f for f in fits.values() if _near_equal(f, best, precise, max_pair_s)]
    if not near or best.paired == 0:
        return OffsetChoice(best.offset_s)

    def prior_dist(f: _Fit, settings: dict[float, str]) -> tuple[float, str]:
        p = min(settings, key=lambda q: abs(f.offset_s - q))
        return abs(f.offset_s - p), settings[p]

    # Cameras are set to UTC or local time; GPS time only when neither fits.
    zones = {p: v for p, v in priors.items() if v != "GPS time"}
    gps_time = {float(-leap_s): "GPS time"}
    group = sorted([best, *near], key=lambda f: prior_dist(f, priors)[0])
    # Only the best-voted candidates and those near plausible settings are tried: there may
    # be more equal ones, hence "at least"; listed nearest a plausible setting first.
    gps = [f"{f.offset_s + leap_s:+.2f}" for f in group]
    shown = ", ".join(gps[:6]) + (f" and {len(gps) - 6} more" if len(gps) > 6 else "")
    what = (f"at least {len(group)} camera clock offsets pair the photos about equally well "
            f"({best.paired} paired each; marks at regular intervals): GPS - camera {shown} s")
    for settings in (zones, gps_time):
        fitting = [f for f in group if prior_dist(f, settings)[0] <= PRIOR_RADIUS_S]
        if len(fitting) > 1:
            break
        if len(fitting) == 1:
            chosen = fitting[0]
            setting = prior_dist(chosen, settings)[1]
            other = [f for f in group if f is not chosen
                     and prior_dist(f, gps_time)[0] <= PRIOR_RADIUS_S]
            also = (f" (a camera clock set to GPS time would give {other[0].offset_s + leap_s:+.2f}"
                    " s instead)" if other else "")
            return OffsetChoice(chosen.offset_s, notes=(
                (f"photo pairing: {what}; took {chosen.offset_s + leap_s:+.2f} s, the one of a "
                f"camera clock set to {setting} (within {PRIOR_RADIUS_S:g} s){also}. If the camera"
                " clock was set otherwise, the photos are paired with the wrong marks: pair them"
                " by hand."),))
    chosen = group[0]
    return OffsetChoice(chosen.offset_s, warnings=(
        (f"photo pairing ambiguous: {what}; no single one fits a camera clock set to UTC or a "
        f"whole-hour zone (within {PRIOR_RADIUS_S:g} s); took {chosen.offset_s + leap_s:+.2f} s, "
        "the nearest to such a setting: the photos may be paired with marks a whole number of "
        "intervals off. Check the pairing by hand (solve with all photos of the flight, or "
        "photos whose first and last shots bracket a gap in the marks)."),))
