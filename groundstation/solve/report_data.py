"""What the report shows, as one typed value: :class:`ReportInput`, filled by the pipeline from
the solve's results (the camera rows ``cameras.csv`` is written from, the trajectory, the
flight's satellites and station events, the engine and its options, the base and its check);
and what is derived from that value alone, in numbers and words: the counts, the warnings, the
accuracy and grades, times in UTC and GPS week/seconds.

Nothing here reads a file: the report (:mod:`groundstation.solve.report`) and the printout are
drawn from this, so the counts and the per-mark table agree with the exports by construction.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.rules.marks import (
    LOST_CAUSE_TEXT,
    LOST_IN_RECEIVER,
    LOST_ON_LINK,
    NOT_COUNTED_TEXT,
    numbers_text,
)
from groundstation.solve.flight import SatelliteObs, Span
from groundstation.solve.integrity.grade import CHECK_TEXT, GRADE_NAMES
from groundstation.solve.interpolate import FLAG_CAMERA_CLOCK, FLAG_GAP
from groundstation.solve.outputs import CameraRow
from groundstation.solve.trajectory import Q_DGPS, Q_FIX, Q_FLOAT, Q_PPP, Q_SBAS, Q_SINGLE

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


LostMarks = Mapping[str, Sequence[int]]
"""The numbers of the marks lost in count jumps, by cause
(:func:`groundstation.rules.marks.lost_by_cause`)."""


@dataclass(frozen=True, slots=True)
class ReportInput:
    """Everything the report shows; the pipeline fills it.

    Attributes:
        flight: recording name.
        engine_name, engine_version, engine_options: the positioning engine and its option set.
        position_source: where the trajectory came from (engine or imported file).
        base_name: base recording (None without one).
        base_ecef_m: base coordinates used (WGS84 ECEF), None when unknown.
        base_check: how the base coordinates were checked, in words.
        base_doubtful: the check failed or was impossible in a way a reviewer must know.
        epsg, crs_name, projected: output CRS; ``height_datum`` names the heights.
        lever_arm_m: lever arm in the camera frame (None: not applied).
        shutter_delay_ms, edge, interp, max_gap_s: how marks became camera positions.
        rows: the camera rows ``cameras.csv`` is written from (photos, then orphan marks).
        marks_total, marks_duplicate: marks in the flight and duplicates set aside.
        photos_total: photos found (0 without ``--photos``).
        photos_given: ``--photos`` was given (without, the marks are exported by name,
            ``mark_0031``, and a mark without photo is no warning).
        lost_marks: the numbers of the pulses the receiver counted whose records never
            arrived (jumps in its count), by cause (lost on the link, not reported by the
            receiver: :func:`groundstation.rules.marks.lost_by_cause`).
        photos_not_counted: photos without a mark that no count jump accounts for.
        photos_unmatched: (photo name, reason) of every photo without a mark.
        orphan_marks: mark indices without a photo.
        clock_offset_s, pair_window_s: photo matching (None without photos); the clock offset
            is GPS − camera (``MatchResult.gps_minus_camera_s``).
        clock_leap_s: GPS − UTC leap seconds in ``clock_offset_s``.
        pairing_warnings: an ambiguous photo pairing (``MatchResult.warnings``).
        pair_t_gps_ns, pair_residual_s: mark time and residual of every pair.
        track_*: the trajectory in the output CRS.
        radio_gaps, source_outages: link dropouts and source outages recorded by the station.
        station_events: the recording is a station session that records them (else unknown).
        satellites: the rover's raw observations (None when the recording has none).
        slips_found, slips_repaired: cycle slips found and repaired by the conditioning (None
            when none ran; the pipeline then counts the receiver's loss-of-lock flags).
        lever_residual_m, lever_outlier: lever-arm estimate from an EO file.
        metre_level: the positions are the receiver's own fix.
        notes: the solve's notes.
    """

    flight: str
    engine_name: str
    engine_version: str
    engine_options: dict[str, str]
    position_source: str
    base_name: str | None
    base_ecef_m: tuple[float, float, float] | None
    base_check: str
    base_doubtful: bool
    epsg: int | str
    crs_name: str
    projected: bool
    lever_arm_m: tuple[float, float, float] | None
    shutter_delay_ms: float
    edge: str
    interp: str
    max_gap_s: float
    rows: tuple[CameraRow, ...]
    marks_total: int
    marks_duplicate: int
    track_t_gps_ns: IntArray
    track_x_m: FloatArray
    track_y_m: FloatArray
    track_quality: IntArray
    height_datum: str = "WGS84 ellipsoidal height"
    base_sd_enu_m: tuple[float, float, float] | None = None
    base_before: tuple[str, ...] = ()
    """Re-based (``solve --rebase``): the base positions the result had before, oldest first."""
    photos_total: int = 0
    photos_given: bool = True
    lost_marks: LostMarks = field(default_factory=dict)
    photos_not_counted: int = 0
    photos_unmatched: tuple[tuple[str, str], ...] = ()
    orphan_marks: tuple[int, ...] = ()
    clock_offset_s: float | None = None
    clock_leap_s: int = 0
    pairing_warnings: tuple[str, ...] = ()
    pair_window_s: float | None = None
    pair_t_gps_ns: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    pair_residual_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    radio_gaps: tuple[Span, ...] = ()
    source_outages: tuple[Span, ...] = ()
    station_events: bool = True
    satellites: SatelliteObs | None = None
    slips_found: int | None = None
    slips_repaired: int | None = None
    lever_residual_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    lever_outlier: BoolArray = field(default_factory=lambda: np.zeros(0, bool))
    metre_level: bool = False
    notes: tuple[str, ...] = ()
    integrity: dict[str, Any] | None = None
    """The integrity stage's summary (``engine.json``'s ``integrity``), None when it did not
    run."""
    map_origin: tuple[float, float] | None = None
    """The base in the output CRS: the map is drawn from it (None: in the CRS's coordinates),
    so that moving the base and the flight alike leaves the map as it was."""
    kept_figures: Mapping[str, str] = field(default_factory=dict)
    """Figures of the result a re-base moves, as ``key@digest of their inputs`` -> SVG
    (``report.figures_in``): a figure whose inputs are as they were is not drawn again."""


QUALITY_KEYS = {Q_FIX: "fixed", Q_FLOAT: "float", Q_SBAS: "sbas", Q_DGPS: "dgps",
                Q_SINGLE: "single", Q_PPP: "ppp"}
"""Count keys of the positioned rows per RTKLIB quality (every positioned row has one)."""


# -- time and number formatting ---------------------------------------------------------------


def utc_text(t_gps_ns: int, decimals: int = 3) -> str:
    """``2018-10-09 12:21:33.123`` (UTC) for a GPS instant; "" for none (< 0)."""
    if t_gps_ns < 0:
        return ""
    unix_ns = gpstime.gps_to_unix_ns(t_gps_ns)
    sec, frac = divmod(unix_ns, gpstime.NS_PER_S)
    base = gpstime.gps_to_datetime(t_gps_ns).strftime("%Y-%m-%d %H:%M:%S")
    return base + (f".{frac // 10 ** (9 - decimals):0{decimals}d}" if decimals else "")


def gps_text(t_gps_ns: int, decimals: int = 3) -> str:
    """``2022 130893.123`` (GPS week and seconds of week); "" for none."""
    if t_gps_ns < 0:
        return ""
    week, tow_ns = gpstime.week_tow(t_gps_ns)
    sec, frac = divmod(tow_ns, gpstime.NS_PER_S)
    return f"{week} {sec}" + (f".{frac // 10 ** (9 - decimals):0{decimals}d}" if decimals else "")


# -- counts -----------------------------------------------------------------------------------


def lost_marks_text(lost: LostMarks) -> list[str]:
    """One sentence per cause: how many marks were lost, why, what to do, and which (the
    receiver's numbers, as ``mark_NNNN`` and ``mark_count``)."""
    return [f"{len(nums)} time mark(s) {LOST_CAUSE_TEXT[cause]}: number(s) "
            f"{numbers_text(nums)}." for cause, nums in lost.items() if nums]


def not_counted_text(n: int) -> str:
    """The photos no mark and no count jump account for."""
    return f"{n} photo(s) {NOT_COUNTED_TEXT}."


def counts(inp: ReportInput) -> dict[str, int]:
    """The summary counts, all derived from the rows (so they equal ``cameras.csv``'s)."""
    rows = inp.rows
    pos = [r for r in rows if r.positioned]
    in_radio = 0
    for r in rows:
        if r.t_gps_ns >= 0 and any(s.start_gps_ns <= r.t_gps_ns <= s.end_gps_ns
                                   for s in inp.radio_gaps):
            in_radio += 1
    return {
        "rows": len(rows),
        **{QUALITY_KEYS[q]: sum(1 for r in pos if r.quality == q) for q in QUALITY_KEYS},
        "not_positioned": sum(1 for r in rows if not r.positioned),
        "photos": inp.photos_total,
        "photos_matched": sum(1 for r in rows if r.photo and r.mark >= 0),
        "photos_unmatched": sum(1 for r in rows if r.photo and r.mark < 0),
        "photos_by_camera_clock": sum(1 for r in rows if r.flags & FLAG_CAMERA_CLOCK
                                      and r.positioned),
        "orphan_marks": sum(1 for r in rows if not r.photo and r.mark >= 0),
        "marks_missed": sum(len(j) for j in inp.lost_marks.values()),
        "marks_lost_on_link": len(inp.lost_marks.get(LOST_ON_LINK, ())),
        "marks_not_reported": len(inp.lost_marks.get(LOST_IN_RECEIVER, ())),
        "photos_not_counted": inp.photos_not_counted,
        "marks_bridging_gap": sum(1 for r in rows if r.flags & FLAG_GAP),
        "marks_in_radio_gap": in_radio,
        "nadir_assumed": sum(1 for r in rows if r.attitude == "nadir-track"),
    }


def nearest_epoch_s(inp: ReportInput) -> FloatArray:
    """Per row: seconds from its instant to the nearest solved epoch (NaN without instant)."""
    t = inp.track_t_gps_ns
    out = np.full(len(inp.rows), np.nan)
    if t.size == 0:
        return out
    for i, r in enumerate(inp.rows):
        if r.t_gps_ns < 0:
            continue
        j = int(np.searchsorted(t, r.t_gps_ns))
        cand = [k for k in (j - 1, j) if 0 <= k < t.size]
        out[i] = min(abs(int(t[k]) - r.t_gps_ns) for k in cand) / 1e9
    return out


# -- warnings ---------------------------------------------------------------------------------


def warnings(inp: ReportInput) -> list[str]:
    """Every condition a reviewer must know before signing off, most serious first."""
    c = counts(inp)
    out: list[str] = []
    if inp.metre_level:
        out.append("The positions are the receiver's own fix (metre level): not for mapping.")
    if inp.base_doubtful:
        out.append(f"Base coordinates doubtful: {inp.base_check}")
    out.extend(f"{w[:1].upper()}{w[1:]}" for w in inp.pairing_warnings)
    if c["not_positioned"]:
        out.append(f"{c['not_positioned']} camera position(s) could not be computed (see the "
                   "flags column: outside the trajectory, no edge, or a photo without mark).")
    worse = {k: c[k] for k in QUALITY_KEYS.values() if k != "fixed" and c[k]}
    if worse:
        parts = ", ".join(f"{v} {k}" for k, v in worse.items())
        out.append(f"{sum(worse.values())} camera position(s) are not ambiguity-fixed ({parts}): "
                   "expect decimetres (float) to metres (dgps, single).")
    if c["marks_bridging_gap"]:
        out.append(f"{c['marks_bridging_gap']} camera position(s) are interpolated across a gap "
                   f"of more than {inp.max_gap_s:g} s between solved epochs.")
    if c["marks_in_radio_gap"]:
        out.append(f"{c['marks_in_radio_gap']} mark(s) fall inside radio dropouts recorded by "
                   "the ground station.")
    if inp.source_outages:
        out.append(f"{len(inp.source_outages)} outage(s) of the receiver connection during the "
                   "session.")
    if c["photos_unmatched"]:
        names = ", ".join(n for n, _ in inp.photos_unmatched[:8])
        extra = len(inp.photos_unmatched) - 8
        more = f" and {extra} more" if extra > 0 else ""
        timed = c["photos_by_camera_clock"]
        how = (f" ({timed} positioned at their own time through the camera clock fitted on the "
               "paired photos: flag camera_clock, the timing in their sigma)" if timed else "")
        out.append(f"{c['photos_unmatched']} photo(s) without a time mark{how}: {names}{more}.")
    out.extend(lost_marks_text(inp.lost_marks))
    if inp.photos_not_counted:
        out.append(not_counted_text(inp.photos_not_counted))
    if c["orphan_marks"] and inp.photos_given:
        out.append(f"{c['orphan_marks']} time mark(s) without a photo (camera fired, no image "
                   "found): check the image count.")
    if inp.marks_duplicate:
        out.append(f"{inp.marks_duplicate} duplicate time mark(s) set aside.")
    if c["nadir_assumed"]:
        out.append(f"Attitude assumed for {c['nadir_assumed']} camera position(s): nadir camera "
                   "(omega = phi = 0), kappa from the direction of travel. The lever arm is "
                   "applied with this assumed attitude.")
    if inp.lever_arm_m is None and c["rows"]:
        out.append("No lever arm applied: the positions are those of the antenna, not of the "
                   "camera's projection centre.")
    if not inp.engine_version:
        out.append("The engine version is not recorded for this solution.")
    return out


def _cm(v: float) -> str:
    return f"{v * 100:.1f} cm" if v < 1.0 else f"{v:.2f} m"


def accuracy_text(inp: ReportInput) -> str:
    """The engine's σ at the positioned camera positions, horizontal and up: median and worst."""
    pos = [r for r in inp.rows if r.positioned and math.isfinite(r.sd_u_m)]
    if not pos:
        return "no camera position"
    hor = np.array([math.hypot(r.sd_e_m, r.sd_n_m) for r in pos])
    up = np.array([r.sd_u_m for r in pos])
    return (f"σ horizontal {_cm(float(np.median(hor)))} median, {_cm(float(hor.max()))} worst; "
            f"σ up {_cm(float(np.median(up)))} median, {_cm(float(up.max()))} worst "
            f"(the engine's estimate at the {len(pos)} positioned camera position(s))")


def grades_text(rows: Sequence[CameraRow]) -> str:
    """Camera positions per grade, with the checks that decided them:
    ``fixed 636 (arcs 600, both-directions 36); float 21 (demoted:interpolation 14, ...)``."""
    pos = [r for r in rows if r.positioned]
    if not pos:
        return "no camera position"
    parts = []
    for name in GRADE_NAMES.values():
        mine = [r for r in pos if r.grade == name]
        if not mine:
            continue
        by: dict[str, int] = {}
        for r in mine:
            by[r.check or "no check"] = by.get(r.check or "no check", 0) + 1
        detail = ", ".join(f"{k} {v}" for k, v in sorted(by.items(), key=lambda kv: -kv[1]))
        parts.append(f"{name} {len(mine)} ({detail})")
    return "; ".join(parts)


def checks_text(rows: Sequence[CameraRow]) -> str:
    """What each check named in :func:`grades_text` means, for the checks the camera positions
    carry: ``arcs: our whole-arc phase solution fixed it on its own; ...``."""
    seen = sorted({r.check for r in rows if r.positioned and r.check in CHECK_TEXT})
    return "; ".join(f"{c}: {CHECK_TEXT[c]}" for c in seen)


GO_GAP_NS = 30 * 1_000_000_000
"""Marks not fixed that far apart (or a fixed one between them) are separate stretches."""


def go_no_go(rows: Sequence[CameraRow]) -> dict[str, Any]:
    """Before the team packs up: how many of the flight's marks are fixed and checked, and the
    stretches of the others (first and last mark time, how many), which to fly again. A
    stretch ends at a fixed mark or after :data:`GO_GAP_NS` without a mark."""
    marks = sorted((r for r in rows if r.mark >= 0 and r.t_gps_ns >= 0),
                   key=lambda r: r.t_gps_ns)
    fixed = sum(r.grade == "fixed" for r in marks)
    stretches: list[dict[str, int]] = []
    last_bad = False
    for r in marks:
        if r.grade == "fixed":
            last_bad = False
            continue
        if last_bad and r.t_gps_ns - stretches[-1]["end_t_gps_ns"] <= GO_GAP_NS:
            stretches[-1]["end_t_gps_ns"] = r.t_gps_ns
            stretches[-1]["marks"] += 1
        else:
            stretches.append({"start_t_gps_ns": r.t_gps_ns, "end_t_gps_ns": r.t_gps_ns,
                              "marks": 1})
        last_bad = True
    return {"marks": len(marks), "fixed": fixed, "stretches": stretches}

