"""Photos to time marks: EXIF capture times, burst spreading, clock offset, one-to-one pairing.

The matching core (:func:`match`) is sans-I/O: it takes photo times on the camera clock and mark
times in GPS seconds. EXIF reading (a bounded parser of its own: a crafted photo must not hang
the solver) and GPS tag writing (exiv2 through ``pyexiv2``: position and accuracy, EXIF and
XMP, the rest of the metadata kept) live here too, at the edge: :func:`read_photo`,
:func:`scan_photos`, :func:`write_gps_copy`, and :func:`make_jpeg` (test and demo photos, EXIF
by the ``exif`` library).
"""

from __future__ import annotations

import datetime as dt
import logging
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Literal

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.errors import InputError

FloatArray = npt.NDArray[np.float64]
log = logging.getLogger(__name__)

MAX_PAIR_S = 0.75
"""A photo and a mark further apart than this (after the clock offset) are never paired."""
MIN_PAIR_TOLERANCE_S = 0.1
"""Floor of the adaptive pairing tolerance (photos with sub-second times)."""
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

JPEG_SUFFIXES = (".jpg", ".jpeg", ".jpe")


@dataclass(frozen=True, slots=True)
class Photo:
    """One photo's capture time as the camera wrote it.

    Attributes:
        name: file name.
        path: full path.
        exif_second_ns: ``DateTimeOriginal`` as UNIX ns, read as UTC (whole seconds).
        subsec_ns: ``SubSecTimeOriginal`` in ns, or ``None`` when absent.
        utc_offset_s: ``OffsetTimeOriginal`` in seconds east of UTC, or ``None``.
        time_tag: which EXIF tag gave the time (``DateTimeOriginal`` or ``DateTime``).
        error: why the photo has no usable time (then the times are 0).
    """

    name: str
    path: str
    exif_second_ns: int
    subsec_ns: int | None = None
    utc_offset_s: int | None = None
    time_tag: str = "DateTimeOriginal"
    error: str = ""

    @property
    def usable(self) -> bool:
        return not self.error

    @property
    def utc_second_ns(self) -> int:
        """The EXIF second on the UTC scale when the camera stated its zone, else as written."""
        return self.exif_second_ns - (self.utc_offset_s or 0) * gpstime.NS_PER_S


def natural_key(name: str) -> tuple[tuple[int, int | str], ...]:
    """Sort key that orders ``IMG_9.JPG`` before ``IMG_10.JPG``."""
    return tuple(
        (0, int(part)) if part.isdigit() else (1, part.lower())
        for part in re.split(r"(\d+)", name)
        if part
    )


def parse_exif_datetime(text: str) -> dt.datetime:
    """``YYYY:MM:DD HH:MM:SS`` (EXIF) as a naive datetime."""
    return dt.datetime.strptime(text.strip().rstrip("\x00"), "%Y:%m:%d %H:%M:%S")


def parse_subsec(text: str) -> int | None:
    """``SubSecTimeOriginal`` (decimal fraction digits) as ns; ``None`` if empty or invalid."""
    digits = text.strip().rstrip("\x00").strip()
    if not digits.isdigit():
        return None
    return int((digits + "000000000")[:9])


def parse_utc_offset(text: str) -> int | None:
    """``OffsetTimeOriginal`` (``+02:00``) as seconds east of UTC."""
    m = re.fullmatch(r"\s*([+-])(\d\d):(\d\d)\s*\x00*", text)
    if not m:
        return None
    s = int(m.group(2)) * 3600 + int(m.group(3)) * 60
    return s if m.group(1) == "+" else -s


def _unix_ns(naive: dt.datetime) -> int:
    return int(naive.replace(tzinfo=dt.UTC).timestamp()) * gpstime.NS_PER_S


EXIF_MAX_SEGMENTS = 64
"""JPEG segments looked at for the EXIF block before giving up (it normally comes first); only
their 4-byte headers are read, and the EXIF body itself (at most 64 KiB)."""
EXIF_TIME_BUDGET_S = 0.5
"""Parsing one photo's EXIF stops after this long (a crafted file is skipped, never a hang)."""
EXIF_MAX_IFDS = 16
EXIF_MAX_ENTRIES = 2000

_TAG_DATETIME, _TAG_EXIF_IFD, _TAG_GPS_IFD = 0x0132, 0x8769, 0x8825
_TAG_ORIGINAL, _TAG_OFFSET_ORIGINAL, _TAG_SUBSEC_ORIGINAL = 0x9003, 0x9011, 0x9291
_TAG_INTEROP_IFD = 0xA005


class ExifError(ValueError):
    """A photo's EXIF block cannot be used (damaged, looping, over budget)."""


def _tiff_reader(tiff: bytes) -> tuple[Literal["little", "big"], Callable[[int, int], int]]:
    """A TIFF block's byte order and a bounds-checked reader of its unsigned integers.

    Raises:
        ExifError: not a TIFF header.
    """
    if len(tiff) < 8 or tiff[:4] not in (b"II*\x00", b"MM\x00*"):
        raise ExifError("bad TIFF header in EXIF")
    order: Literal["little", "big"] = "little" if tiff[:2] == b"II" else "big"

    def u(off: int, n: int) -> int:
        if off < 0 or off + n > len(tiff):
            raise ExifError(f"EXIF offset {off} outside the {len(tiff)}-byte block")
        return int.from_bytes(tiff[off : off + n], order)

    return order, u


def _exif_block(f: BinaryIO) -> bytes | None:
    """The TIFF data of a JPEG's ``Exif`` APP1 segment (``None``: the JPEG has none), found by
    walking the segment headers (seeking over their bodies).

    Raises:
        ExifError: not a JPEG, a damaged segment, or no EXIF within the first
            :data:`EXIF_MAX_SEGMENTS` segments.
    """
    if f.read(2) != b"\xff\xd8":
        raise ExifError("not a JPEG")
    for _ in range(EXIF_MAX_SEGMENTS):
        head = f.read(2)
        while head[:1] == b"\xff" and head[1:2] == b"\xff":  # fill bytes
            head = head[1:] + f.read(1)
        if len(head) < 2:
            return None  # ends before any image data: no EXIF
        if head[0] != 0xFF:
            raise ExifError(f"damaged JPEG segment at byte {f.tell() - 2}")
        marker = head[1]
        if marker in (0xD9, 0xDA):  # end of image, start of scan: no EXIF after this
            return None
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:  # standalone markers
            continue
        raw = f.read(2)
        length = int.from_bytes(raw, "big")
        if len(raw) < 2 or length < 2:
            raise ExifError(f"damaged JPEG segment length at byte {f.tell() - 2}")
        if marker == 0xE1:
            body = f.read(length - 2)
            if len(body) < length - 2:
                raise ExifError("EXIF segment cut short")
            if body.startswith(b"Exif\x00\x00"):
                return body[6:]
            continue
        f.seek(length - 2, 1)
    raise ExifError(f"no EXIF within the first {EXIF_MAX_SEGMENTS} JPEG segments")


def _exif_tags(tiff: bytes, deadline: float) -> dict[int, str]:
    """The ASCII tags of IFD0 and the Exif IFD, with every IFD pointer checked: in bounds,
    visited once (a looping chain is an error), at most :data:`EXIF_MAX_IFDS` IFDs.

    Raises:
        ExifError: damaged, looping or over the time budget.
    """
    import time

    order, u = _tiff_reader(tiff)

    tags: dict[int, str] = {}
    seen: set[int] = set()
    todo: list[tuple[int, bool]] = [(u(4, 4), True)]  # (offset, follow the next-IFD chain)
    while todo:
        off, chain = todo.pop()
        if off == 0:
            continue
        if off in seen:
            raise ExifError(f"looping EXIF IFD chain (offset {off} visited twice)")
        if len(seen) >= EXIF_MAX_IFDS:
            raise ExifError(f"more than {EXIF_MAX_IFDS} EXIF IFDs")
        if time.monotonic() > deadline:
            raise ExifError(f"EXIF parsing over its {EXIF_TIME_BUDGET_S} s budget")
        seen.add(off)
        count = u(off, 2)
        if count > EXIF_MAX_ENTRIES:
            raise ExifError(f"EXIF IFD with {count} entries")
        for k in range(count):
            e = off + 2 + 12 * k
            tag, kind, n = u(e, 2), u(e + 2, 2), u(e + 4, 4)
            if tag in (_TAG_EXIF_IFD, _TAG_GPS_IFD, _TAG_INTEROP_IFD):
                todo.append((u(e + 8, 4), False))
            elif kind == 2 and tag in (_TAG_DATETIME, _TAG_ORIGINAL, _TAG_OFFSET_ORIGINAL,
                                       _TAG_SUBSEC_ORIGINAL):
                start = e + 8 if n <= 4 else u(e + 8, 4)
                if n > 256 or start + n > len(tiff):
                    raise ExifError(f"EXIF tag 0x{tag:04x} runs outside the block")
                tags.setdefault(tag, tiff[start : start + n].split(b"\x00")[0]
                                .decode("ascii", "replace"))
        if chain:
            todo.append((u(off + 2 + 12 * count, 4), True))
    return tags


def read_exif_times(path: Path) -> dict[int, str]:
    """The capture-time tags of one JPEG, read within a size and time budget.

    Raises:
        OSError: the file cannot be read.
        ExifError: no usable EXIF block (damaged, looping, over budget).
    """
    import time

    with path.open("rb") as f:
        tiff = _exif_block(f)
    if tiff is None:
        return {}
    return _exif_tags(tiff, time.monotonic() + EXIF_TIME_BUDGET_S)


def read_photo(path: str | Path) -> Photo:
    """The EXIF capture time of one JPEG (never raises for bad photos: see ``Photo.error``).

    The EXIF block is parsed here, within a budget (:data:`EXIF_MAX_SEGMENTS` segment headers,
    the EXIF body of at most 64 KiB, :data:`EXIF_TIME_BUDGET_S`, every IFD visited once): a
    damaged or crafted photo (a looping IFD chain) is skipped with its reason, never a hang.
    """
    p = Path(path)
    try:
        tags = read_exif_times(p)
    except OSError as err:
        return Photo(p.name, str(p), 0, error=f"cannot read: {err.strerror or err}")
    except ExifError as err:
        return Photo(p.name, str(p), 0, error=f"no readable EXIF: {err}")
    if not tags:
        return Photo(p.name, str(p), 0, error="no EXIF")
    tag = "DateTimeOriginal"
    text = tags.get(_TAG_ORIGINAL, "")
    if not text:
        tag, text = "DateTime", tags.get(_TAG_DATETIME, "")
    if not text:
        return Photo(p.name, str(p), 0, error="no DateTimeOriginal")
    try:
        second = _unix_ns(parse_exif_datetime(text))
    except ValueError:
        return Photo(p.name, str(p), 0, error=f"bad {tag} {text!r}")
    sub = tags.get(_TAG_SUBSEC_ORIGINAL, "")
    off = tags.get(_TAG_OFFSET_ORIGINAL, "")
    return Photo(
        p.name, str(p), second,
        parse_subsec(sub) if sub else None,
        parse_utc_offset(off) if off else None,
        tag,
    )


def scan_photos(directory: str | Path) -> list[Photo]:
    """Every JPEG in ``directory`` (not recursive), in natural file-name order."""
    d = Path(directory)
    if not d.is_dir():
        raise InputError(f"{d}: not a directory")
    files = sorted(
        (p for p in d.iterdir() if p.suffix.lower() in JPEG_SUFFIXES and p.is_file()),
        key=lambda p: natural_key(p.name),
    )
    return [read_photo(p) for p in files]


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


def _windows(
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


def _fit(
    times: PhotoTimes, marks: FloatArray, offset_s: float, max_pair_s: float, cost: float
) -> _Fit:
    """How one offset pairs the photos: count, spread of the residuals, which pairs."""
    lower, upper = _windows(times, max_pair_s, max_pair_s)
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


# -- pairing ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Pair:
    """A photo and its mark; ``residual_s`` = mark − (photo + offset)."""

    photo: int
    mark: int
    residual_s: float


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
    lower, upper = _windows(times, max_pair_s, tol_precise)
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
    from groundstation.errors import ConfigError
    from groundstation.rules.plausible import span_text

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


# -- writing ------------------------------------------------------------------------------------


def make_jpeg(
    datetime_original: dt.datetime | None,
    *,
    subsec: str | None = None,
    offset_time: str | None = None,
) -> bytes:
    """A valid 8×8 grey baseline JPEG with the given EXIF capture time (tests and the demo).

    The image is hand-made (one DC-only block, one-symbol Huffman tables) so no imaging library
    is needed; the EXIF block is written by the ``exif`` library like any camera's.
    """
    from exif import Image

    dqt = b"\xff\xdb\x00\x43\x00" + bytes([1] * 64)
    sof = b"\xff\xc0\x00\x0b\x08\x00\x08\x00\x08\x01\x01\x11\x00"
    # DC table 0 and AC table 0: one code of length 1 each (DC category 0, AC end of block).
    dht = (
        b"\xff\xc4\x00\x14\x00" + bytes([1] + [0] * 15) + b"\x00"
        + b"\xff\xc4\x00\x14\x10" + bytes([1] + [0] * 15) + b"\x00"
    )
    sos = b"\xff\xda\x00\x08\x01\x01\x00\x00\x3f\x00"
    # DC diff 0 (code '0') then EOB (code '0'), padded with ones: a mid-grey block.
    scan = b"\x3f"
    app0 = b"\xff\xe0\x00\x10JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00"
    jpeg = b"\xff\xd8" + app0 + dqt + sof + dht + sos + scan + b"\xff\xd9"
    if datetime_original is None:
        return jpeg
    img = Image(jpeg)
    img.datetime_original = datetime_original.strftime("%Y:%m:%d %H:%M:%S")
    if subsec is not None:
        img.subsec_time_original = subsec
    if offset_time is not None:
        img.offset_time_original = offset_time
    return bytes(img.get_file())


def _dms(value: float) -> str:
    """Degrees as EXIF rationals: ``53/1 16/1 496192/10000``."""
    v = abs(value)
    d = math.floor(v)
    m = math.floor((v - d) * 60)
    s = (v - d - m / 60) * 3600
    return f"{d}/1 {m}/1 {round(s * 1_000_000)}/1000000"


PIX4D_CAMERA_NS = "http://pix4d.com/camera/1.0/"
"""The XMP namespace (prefix ``Camera``) whose ``GPSXYAccuracy`` and ``GPSZAccuracy`` Pix4D
reads for each image's position accuracy."""


def write_gps_copy(src: Path, dst: Path, lat_deg: float, lon_deg: float, h_m: float,
                   sd_h_m: float = math.nan, sd_v_m: float = math.nan) -> bool:
    """Copy a photo to ``dst`` with its position in the EXIF GPS tags (WGS-84) and its
    accuracy where photogrammetry tools look for it (EXIF ``GPSHPositioningError``, XMP
    ``Camera:GPSXYAccuracy`` / ``Camera:GPSZAccuracy``); ``src`` is only read. Written by
    exiv2 (``pyexiv2``), which keeps the rest of the metadata (maker notes, thumbnail, XMP)
    as it was.

    Returns:
        Whether the copy was written; a photo whose metadata cannot take the tags (damaged)
        is skipped with one warning line naming it.

    Raises:
        InputError: ``dst`` is ``src``.
    """
    import shutil

    import pyexiv2

    if src.resolve() == dst.resolve():
        raise InputError(f"{dst}: refusing to overwrite the original photo")
    exif = {
        "Exif.GPSInfo.GPSVersionID": "2 3 0 0",
        "Exif.GPSInfo.GPSLatitudeRef": "N" if lat_deg >= 0 else "S",
        "Exif.GPSInfo.GPSLatitude": _dms(lat_deg),
        "Exif.GPSInfo.GPSLongitudeRef": "E" if lon_deg >= 0 else "W",
        "Exif.GPSInfo.GPSLongitude": _dms(lon_deg),
        "Exif.GPSInfo.GPSAltitudeRef": "0" if h_m >= 0 else "1",
        "Exif.GPSInfo.GPSAltitude": f"{round(abs(h_m) * 1000)}/1000",
        "Exif.GPSInfo.GPSMapDatum": "WGS-84",
    }
    xmp = {}
    if math.isfinite(sd_h_m):
        exif["Exif.GPSInfo.GPSHPositioningError"] = f"{round(sd_h_m * 1000)}/1000"
        xmp["Xmp.Camera.GPSXYAccuracy"] = f"{sd_h_m:.3f}"
    if math.isfinite(sd_v_m):
        xmp["Xmp.Camera.GPSZAccuracy"] = f"{sd_v_m:.3f}"
    part = dst.with_name(f".{dst.name}.part")
    try:
        shutil.copyfile(src, part)
        pyexiv2.registerNs(PIX4D_CAMERA_NS, "Camera")
        with pyexiv2.Image(str(part)) as img:
            img.modify_exif(exif)
            if xmp:
                img.modify_xmp(xmp)
    except (RuntimeError, ValueError, KeyError) as err:  # exiv2's errors on damaged metadata
        part.unlink(missing_ok=True)
        log.warning("%s: no copy with GPS tags written: %s", src.name, err)
        return False
    part.replace(dst)
    return True
