"""Photos to time marks: one-to-one pairing with the camera clock's offset, what is left over on
each side, the check that the photos belong to the flight, and the reconciliation in words.

The matching core (:func:`match`) is sans-I/O: it takes photo times on the camera clock
(:func:`groundstation.solve.clockoffset.photo_times`) and mark times in GPS seconds. Reading the
photos' EXIF and writing geotagged copies is :mod:`groundstation.solve.exif`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.errors import ConfigError
from groundstation.rules.plausible import span_text
from groundstation.solve.clockoffset import (
    MAX_PAIR_S,
    OffsetChoice,
    Pair,
    PhotoTimes,
    choose_offset,
    greedy_pairs,
    pair_windows,
    residual_sigma_s,
    residual_sigma_text,
)
from groundstation.solve.exif import Photo

FloatArray = npt.NDArray[np.float64]

MIN_PAIR_TOLERANCE_S = 0.1
"""Floor of the adaptive pairing tolerance (photos with sub-second times)."""


@dataclass(frozen=True, slots=True)
class MatchResult:
    """Photos paired with marks, and what is left over on each side.

    Attributes:
        offset_s: camera clock error, UTC − camera (after the camera's declared UTC offset):
            add it to a photo's time (:func:`photo_times`, already on the GPS scale: leap
            seconds added) to get the mark's GPS time.
        tolerance_s: the pairing window used (adaptive, at most :data:`MAX_PAIR_S`).
        pairs: one-to-one pairs, in photo order.
        unmatched_photos: photo indices with no mark (including photos without a usable time).
        orphan_marks: mark indices with no photo.
        duplicate_marks: mark indices dropped because an earlier mark has the same time.
        photo_s: the estimated capture time of each photo on the camera clock (GPS-scale s).
        residual_sigma_s: robust σ of the final pairs' residuals (:func:`residual_sigma_s`;
            NaN with fewer than 3 pairs).
        leap_s: GPS − UTC leap seconds at the marks.
        notes: how the offset was chosen among equally good pairings (:func:`choose_offset`).
        warnings: an ambiguous pairing nothing settled: the surveyor must check it.
    """

    offset_s: float
    tolerance_s: float
    pairs: tuple[Pair, ...]
    unmatched_photos: tuple[int, ...]
    orphan_marks: tuple[int, ...]
    duplicate_marks: tuple[int, ...]
    photo_s: FloatArray
    residual_sigma_s: float
    leap_s: int = 0
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    photo_precise: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    """Per photo: its time has sub-second digits (:attr:`PhotoTimes.precise`)."""

    @property
    def gps_minus_camera_s(self) -> float:
        """GPS time − camera time (EXIF read as UTC after its declared zone): leap seconds plus
        :attr:`offset_s`."""
        return self.leap_s + self.offset_s

    def mark_of_photo(self) -> dict[int, int]:
        return {p.photo: p.mark for p in self.pairs}



def match(
    photo_s: FloatArray | PhotoTimes,
    mark_t_gps_ns: Sequence[int | None],
    *,
    max_pair_s: float = MAX_PAIR_S,
    offset_s: float | None = None,
) -> MatchResult:
    """Pair photos (camera-clock times, best from :func:`photo_times`) with marks (GPS ns).

    Duplicate marks (same time as an earlier one) are set aside. The clock offset is estimated
    (:func:`choose_offset`) unless given. The pairing window is at most ``±max_pair_s`` and
    narrower where the photo's timing says so:

    - photos with sub-second times: 5 robust σ of their first-pass residuals, at least
      :data:`MIN_PAIR_TOLERANCE_S`, so they do not grab a stray mark;
    - whole-second photos: the shot happened inside its EXIF second, so the residual lies in
      ``[-0.5 - spread, 0.5 - spread]`` (plus :data:`TRUNCATION_MARGIN_S` for the offset).

    Plain arrays of times are treated as whole-second photos of unknown spread (``±max_pair_s``).
    """
    if isinstance(photo_s, PhotoTimes):
        times = photo_s
    else:
        n = photo_s.size
        times = PhotoTimes(photo_s, np.full(n, np.nan), np.zeros(n, bool))
    photo_s = times.t_s
    exact = times.precise
    mark_s = np.array(
        [t / 1e9 if t is not None else np.nan for t in mark_t_gps_ns], dtype=np.float64
    )
    seen: set[float] = set()
    dups: list[int] = []
    for i, t in enumerate(mark_s.tolist()):
        if math.isnan(t):
            continue
        if t in seen:
            dups.append(i)
        seen.add(t)
    valid_marks = mark_s.copy()
    valid_marks[dups] = np.nan
    finite = valid_marks[np.isfinite(valid_marks)]
    leap_s = gpstime.leap_seconds_at_gps(int(finite[0] * 1e9)) if finite.size else 0
    choice = OffsetChoice(offset_s) if offset_s is not None else choose_offset(
        times, valid_marks, leap_s, max_pair_s)
    offset_s = choice.offset_s
    usable_marks = np.nan_to_num(valid_marks, nan=-1e18)
    first = greedy_pairs(photo_s, usable_marks, offset_s, max_pair_s)
    # The window for sub-second photos comes from their own first-pass spread; without 3 of
    # them there is no spread to go by and the full window applies.
    first_sigma = residual_sigma_s(np.array([p.residual_s for p in first if exact[p.photo]]))
    if math.isnan(first_sigma):
        first_sigma = max_pair_s
    tol_precise = min(max_pair_s, max(MIN_PAIR_TOLERANCE_S, 5.0 * first_sigma))
    lower, upper = pair_windows(times, max_pair_s, tol_precise)
    tol = np.maximum(lower, upper)
    pairs = greedy_pairs(photo_s, usable_marks, offset_s, lower, upper)
    paired_p = {p.photo for p in pairs}
    paired_m = {p.mark for p in pairs}
    dup_set = set(dups)
    unmatched = tuple(i for i in range(photo_s.size) if i not in paired_p)
    orphans = tuple(
        i for i in range(mark_s.size)
        if i not in paired_m and i not in dup_set and not math.isnan(mark_s[i])
    )
    return MatchResult(
        offset_s, float(tol.max()) if tol.size else max_pair_s, tuple(pairs), unmatched,
        orphans, tuple(dups), photo_s,
        residual_sigma_s(np.array([p.residual_s for p in pairs], dtype=np.float64)),
        leap_s, choice.notes, choice.warnings, exact.astype(bool),
    )


MAX_CLOCK_ERROR_S = 86_400.0
"""A camera clock further than this from UTC (after its declared zone and whole-hour zones) is
not a clock error: the photos belong to another flight (a camera loses its time after a flat
battery, but then shows its reset date, years off, which this refuses too)."""
SPAN_MARGIN_S = 120.0
"""Photos may lie this far outside the marks' span (shots on the ground before and after)."""


def check_belongs(result: MatchResult, mark_t_gps_ns: Sequence[int | None]) -> None:
    """Refuse photos that cannot be this flight's: a camera clock error beyond
    :data:`MAX_CLOCK_ERROR_S`, or most photos outside the marks' span after the offset.

    Raises:
        ConfigError: naming ``--photos``, saying by how much they miss the flight.
    """
    marks = np.array([t / 1e9 for t in mark_t_gps_ns if t is not None], dtype=np.float64)
    timed = result.photo_s[np.isfinite(result.photo_s)]
    if marks.size == 0 or timed.size == 0:
        return
    zone_free = (result.offset_s + 1800.0) % 3600.0 - 1800.0  # what a whole-hour zone leaves
    if abs(result.offset_s) > MAX_CLOCK_ERROR_S:
        raise ConfigError("--photos", (
            f"the photos' clock is {span_text(round(result.offset_s * 1e9), signed=False)} off "
            "the flight's "
            f"time marks (GPS - camera {result.gps_minus_camera_s:+.0f} s; a camera clock error "
            f"is seconds, a time zone whole hours): photos of another flight? (a camera whose "
            "clock really is that far off: shift the photos' times, e.g. exiftool -AllDates)"))
    shifted = timed + result.offset_s
    lo, hi = marks.min() - SPAN_MARGIN_S, marks.max() + SPAN_MARGIN_S
    inside = int(np.count_nonzero((shifted >= lo) & (shifted <= hi)))
    if inside * 2 < timed.size:
        raise ConfigError("--photos", (
            f"{timed.size - inside} of {timed.size} photos lie outside the flight's marks "
            f"(photos span {span_text(round(np.ptp(shifted) * 1e9), signed=False)}, marks "
            f"{span_text(round(np.ptp(marks) * 1e9), signed=False)}; camera clock "
            f"{zone_free:+.1f} s off a whole-hour zone): photos of another flight?"))


def reconciliation_lines(
    result: MatchResult, photos: Sequence[Photo], mark_t_gps_ns: Sequence[int | None]
) -> list[str]:
    """Human-readable reconciliation: offset, counts, every unmatched photo and orphan mark."""
    lines = [
        clock_offset_text(result),
        (f"pairing window +/-{result.tolerance_s * 1e3:.0f} ms, timing residual sigma "
         f"{residual_sigma_text(result.residual_sigma_s)}"),
        (f"photos {len(photos)}, marks {len(mark_t_gps_ns)}: {len(result.pairs)} paired, "
        f"{len(result.unmatched_photos)} photos without mark, {len(result.orphan_marks)} marks "
        f"without photo, {len(result.duplicate_marks)} duplicate marks dropped"
        + _skipped(photos)),
    ]
    for i in result.unmatched_photos:
        ph = photos[i]
        why = ph.error or "no mark within the window"
        t = result.photo_s[i] + result.offset_s
        when = "" if math.isnan(t) else f" (would be {gpstime.format_gps(int(t * 1e9))})"
        lines.append(f"  photo without mark: {ph.name}: {why}{when}")
    for i in result.orphan_marks:
        t = mark_t_gps_ns[i]
        lines.append(f"  mark without photo: #{i} at {gpstime.format_gps(t) if t else '?'}")
    return lines


def clock_offset_text(result: MatchResult) -> str:
    """The camera clock offset as the printout and the report give it: GPS − camera, and what
    it is made of (leap seconds GPS − UTC, the camera clock's error UTC − camera)."""
    return (f"camera clock offset (GPS - camera): {result.gps_minus_camera_s:+.2f} s "
            f"({_hms(result.gps_minus_camera_s)}) = {result.leap_s} s leap seconds (GPS - UTC) "
            f"{result.offset_s:+.2f} s (UTC - camera)")


def _skipped(photos: Sequence[Photo]) -> str:
    n = sum(1 for ph in photos if not ph.usable)
    return f", {n} photos skipped (no usable EXIF time)" if n else ""


def _hms(seconds: float) -> str:
    sign = "-" if seconds < 0 else "+"
    s = abs(seconds)
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{sign}{int(h)}h{int(m):02d}m{sec:05.2f}s"


