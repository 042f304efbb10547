"""UBX recording -> RINEX observation and navigation files and the time-mark table.

Every falling edge (or the chosen edge) becomes an event epoch (unless
``RinexOptions.events`` is off), frames after damage are recovered, and AID-EPH gives a
navigation file. Epochs, marks and fixes whose time cannot belong to the session
(:mod:`groundstation.rules.plausible`: the decoder's verdicts, in bulk) are left out, counted
(``RinexResult.implausible``) and logged.
"""

from __future__ import annotations

import bisect
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation import gpstime
from groundstation.errors import InputError
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.offline.ephemeris import collect_ephemerides
from groundstation.offline.inspect import content_detail
from groundstation.offline.multinav import MultiNav, collect_multi, receiver_times, today_gps_week
from groundstation.offline.rinex.marks_table import marks_csv
from groundstation.offline.rinex.nav_writer import write_nav
from groundstation.offline.rinex.obs_writer import HeaderInfo, ProgressFn, kept_epochs, write_obs
from groundstation.offline.rinex.observations import (
    SIGNAL_CODES,
    ObsSet,
    obs_from_raw,
    obs_from_rawx,
)
from groundstation.records import TimeMark
from groundstation.rules import epochs as epochs_rule
from groundstation.rules import marks as marks_mod
from groundstation.rules import plausible
from groundstation.storage.reading import Recording
from groundstation.ubx import layouts as L
from groundstation.ubx.fastraw import (
    FrameIndex,
    RawBlock,
    SessionTimes,
    decode_raw,
    decode_rawx,
    decode_timtm2,
    index_timed_chunks,
    plausible_epochs,
)
from groundstation.ubx.timemark import timemark_from_fields

log = logging.getLogger("groundstation.rinex")
IMPLAUSIBLE_LOGGED = 20
"""Implausible messages of one type logged one by one; after that one line per 1000."""

RTKLIB_DTTOL_NS = 25_000_000
"""RTKLIB's tolerance on the spacing of epochs (``DTTOL`` in ``rtklib.h``, 0.025 s)."""


def events_after_spacing_change(epochs_ns: Sequence[int], events_ns: Sequence[int]) -> int:
    """Event epochs whose next observation epoch comes at another spacing from the epoch
    before it than that epoch's own spacing (by :data:`RTKLIB_DTTOL_NS`), as after a radio gap.
    RTKLIB's RINEX reader (``rinex.c``, ``readrnxobs``) drops that epoch and takes the next;
    the spacing it then compares with is two epochs long, so the epoch after each later mark
    can go the same way until the marks pause."""
    w = np.asarray(epochs_ns, dtype=np.int64)
    e = np.asarray(events_ns, dtype=np.int64)
    if w.size < 3 or e.size == 0:
        return 0
    k = np.searchsorted(w, e, side="right")  # the epoch written after each event
    k = k[(k >= 2) & (k < w.size)]
    change = np.abs((w[k] - w[k - 1]) - (w[k - 1] - w[k - 2])) >= RTKLIB_DTTOL_NS
    return int(np.count_nonzero(change))


# -- the whole conversion ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RinexOptions:
    """Options of :func:`convert` (see ``groundstation rinex --help``)."""

    version: str = "3.04"
    marks: marks_mod.MarkEdge = "falling"
    shutter_delay_ns: int = 0
    marker: str | None = None
    events: bool = True
    """Write each mark as an event epoch (flag 5) of the observations; the marks are in
    ``<stem>.marks.csv`` either way. The PPK engine's copy leaves them out
    (:func:`groundstation.solve.engine.run_engine`)."""


@dataclass(frozen=True, slots=True)
class RinexResult:
    """What a conversion produced."""

    obs_path: Path
    nav_path: Path
    marks_path: Path
    source: str
    epochs: int
    events: int
    marks: int
    marks_in_dropout: int
    ephemerides: int
    dropped_epochs: int
    damaged_frames: int
    frames: int
    rejected_messages: int
    nav_parity_errors: int
    implausible: int = 0
    """Epochs and time marks left out: their time cannot belong to the session."""
    skipped_systems: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    other_ephemerides: tuple[tuple[str, int], ...] = ()
    """(system letter, count) of the GLONASS, Galileo ... records in the nav file."""
    obs_written: bool = True
    """False for a recording without raw measurements (navigation file only)."""


def read_recording(path: Path, progress: ProgressFn | None = None) -> bytes:
    """All bytes of a recording (``.ubx``, ``.ubx.gz``, log, MCAP ``/ubx/raw``; a session's
    later parts too)."""
    recording = Recording(path)
    parts: list[bytes] = []
    for chunk, _t in recording.chunks(chunk_bytes=1 << 20):
        parts.append(chunk)
        if progress is not None:
            progress("read", recording.progress)
    return b"".join(parts)


def read_frames(path: Path, progress: ProgressFn | None = None) -> tuple[bytes, FrameIndex]:
    """The valid UBX frames of a recording (a session's later parts too) and their index (with
    each frame's host time where the recording has them: MCAP), read streaming: memory holds
    one block of the input plus the frames, never the whole input (a 2 GB log with nothing in
    it costs one block)."""
    recording = Recording(path)

    def on_block() -> None:
        if progress is not None:
            progress("read", recording.progress)

    data, index = index_timed_chunks(recording.chunks(chunk_bytes=1 << 20), on_block=on_block)
    on_block()
    return data, index


def _time_marks(
    data: bytes, index: FrameIndex, leap_by_offset: list[tuple[int, int]], times: SessionTimes
) -> tuple[list[TimeMark], int]:
    """TIM-TM2 records, UTC-based edges put on GPS time with the leap seconds the receiver
    declared last before each record (as :class:`~groundstation.ubx.decode.Decoder` does), and
    how many were left out because their times cannot belong to the session (as the decoder
    leaves them out)."""
    sel, rows = decode_timtm2(data, index)
    offsets = [o for o, _ in leap_by_offset]
    out: list[TimeMark] = []
    implausible = 0
    for i, r in zip(sel.tolist(), rows.tolist(), strict=True):
        ch, flags, count, wn_r, wn_f, ms_r, sub_r, ms_f, sub_f, acc = r
        why = (plausible.edge_range_problem(wn_r, ms_r, sub_r)
               or plausible.edge_range_problem(wn_f, ms_f, sub_f))
        if why is None:
            j = bisect.bisect_right(offsets, int(index.start[i])) - 1
            leap = leap_by_offset[j][1] if j >= 0 else None
            tm = timemark_from_fields(
                ch, flags, count, wn_r, ms_r, sub_r, wn_f, ms_f, sub_f, acc, leap_s=leap,
                t_host_ns=0,
            )
            why = times.mark_problem(
                i, ((tm.falling_t_gps_ns, tm.new_falling), (tm.rising_t_gps_ns, tm.new_rising)))
        if why is not None:
            implausible += 1
            _log_implausible("TIM-TM2", implausible, why)
            continue
        out.append(tm)
    return out, implausible


def _log_implausible(name: str, n: int, why: str) -> None:
    if n <= IMPLAUSIBLE_LOGGED or n % 1000 == 0:
        log.warning("implausible %s left out (%d so far): %s", name, n, why)


def _approx_position(
    data: bytes, index: FrameIndex, times: SessionTimes
) -> tuple[float, float, float] | None:
    """The receiver's first good 3D fix (NAV-SOL or NAV-PVT) whose time can belong to the
    session, ECEF metres."""
    import struct

    from groundstation.geodesy import llh_to_ecef

    mv = memoryview(data)
    for key in ((0x01, 0x06), (0x01, 0x07)):
        for i in index.select(key).tolist():
            s = int(index.start[i]) + 6
            p = bytes(mv[s : s + int(index.length[i])])
            if key == (0x01, 0x06) and len(p) >= 52:
                itow, ftow, week, fix, flags = struct.unpack_from("<IihBB", p, 0)
                x, y, z = struct.unpack_from("<iii", p, 12)
                if (fix >= 3 and flags & 1 and (x or y or z) and times.fix_problem(
                        i, itow, ftow, week if flags & 0x04 else None) is None):
                    return x / 100.0, y / 100.0, z / 100.0
            elif key == (0x01, 0x07) and len(p) >= 92:
                (itow,) = struct.unpack_from("<I", p, 0)
                fix, flags = p[20], p[21]
                lon, lat, h_mm = struct.unpack_from("<iii", p, 24)
                if (fix >= 3 and flags & 1 and abs(lat) <= 900_000_000
                        and times.fix_problem(i, itow, 0, None) is None):
                    return llh_to_ecef(lat * 1e-7, lon * 1e-7, h_mm / 1000.0)
    return None


def _receiver(data: bytes, index: FrameIndex, source: str) -> tuple[str, str]:
    """Receiver type and version from MON-VER if recorded, else from the message set."""
    sel = index.select((0x0A, 0x04))
    if sel.size:
        s = int(index.start[sel[0]]) + 6
        p = data[s : s + int(index.length[sel[0]])]
        sw = p[:30].split(b"\0")[0].decode("ascii", "replace").strip()
        hw = p[30:40].split(b"\0")[0].decode("ascii", "replace").strip()
        model = ""
        for k in range(40, len(p), 30):
            ext = p[k : k + 30].split(b"\0")[0].decode("ascii", "replace")
            if ext.startswith("MOD="):
                model = ext[4:]
        return f"u-blox {model or hw}".strip(), sw
    family = {"RXM-RAWX": "u-blox M8/F9 (RAWX)", "RXM-RAW": "u-blox 4/5/6 (RAW)"}
    return family.get(source, "u-blox"), ""


def observations_of(
    data: bytes, index: FrameIndex, now_ns: int | None = None
) -> tuple[RawBlock, ObsSet, int, SessionTimes]:
    """The raw-measurement messages a recording is converted from (RXM-RAWX when it has at
    least as many as RXM-RAW), their observations, how many messages were rejected (too short
    for their layout), and the session's times (which epochs, marks and fixes can belong to
    the session: :func:`~groundstation.ubx.fastraw.plausible_epochs`; the implausible epochs
    are not in the block)."""
    rawx, raw, times = plausible_epochs(
        index, decode_rawx(data, index), decode_raw(data, index), now_ns)
    rejected = int(rawx.rejected.size + raw.rejected.size)
    for block in (rawx, raw):
        for n, k in enumerate(block.implausible.tolist(), 1):
            _log_implausible(block.source, n, times.verdicts.reasons.get(
                int(np.searchsorted(times.frame, k)), "?"))
    if rawx.frame.size >= raw.frame.size:
        return rawx, obs_from_rawx(rawx), rejected, times
    return raw, obs_from_raw(raw), rejected, times


def _leap_by_offset(index: FrameIndex, block: RawBlock) -> list[tuple[int, int]]:
    """Leap seconds the receiver declared, by stream position (for UTC-based time marks)."""
    if block.source != "RXM-RAWX":
        return []
    valid = (block.header["recStat"] & L.RAWX_REC_STAT.mask("leapSec")) != 0
    return list(
        zip(
            index.start[block.frame[valid]].tolist(),
            block.header["leapS"][valid].astype(np.int64).tolist(),
            strict=True,
        )
    )


def time_marks_of(
    data: bytes, index: FrameIndex, block: RawBlock, times: SessionTimes
) -> list[TimeMark]:
    """The TIM-TM2 records of a recording, on GPS time, as the conversion reads them (those
    whose times can belong to the session)."""
    return _time_marks(data, index, _leap_by_offset(index, block), times)[0]


ObsHook = Callable[[ObsSet, Sequence[BroadcastEphemeris], tuple[float, float, float]], ObsSet]
"""A change made to the observations before they are written (the solver's phase conditioning):
(observations, GPS ephemerides, approximate position) -> observations."""


def convert(
    input_path: str | Path,
    out_dir: str | Path,
    options: RinexOptions | None = None,
    progress: ProgressFn | None = None,
    obs_hook: ObsHook | None = None,
) -> RinexResult:
    """Convert one recording to ``<stem>.obs``, ``<stem>.nav`` and ``<stem>.marks.csv``.

    A recording with navigation data but no raw measurements gives the ``.nav`` file alone
    (``RinexResult.obs_written`` is false).

    Args:
        input_path: ``.ubx``, ``.ubx.gz``, raw log or MCAP.
        out_dir: output directory (created if missing).
        options: version, mark edge, shutter delay, marker name.
        progress: optional progress callback.
        obs_hook: applied to the observations before they are written.

    Raises:
        InputError: unreadable input, or neither raw measurements nor navigation data in it.
    """
    opt = options or RinexOptions()
    src = Path(input_path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = src.name
    for suffix in (".gz", ".ubx", ".mcap", ".log"):
        if stem.endswith(suffix):
            stem = stem[: -len(suffix)]
    data, index = read_frames(src, progress)
    if progress is not None:
        progress("index", 1.0)
    block, obs, rejected, times = observations_of(data, index)
    if obs.t_gps_ns.size == 0:
        return _convert_nav_only(src, data, index, out, stem, opt, times)
    leap_by_offset = _leap_by_offset(index, block)
    leap = leap_by_offset[-1][1] if leap_by_offset else gpstime.leap_seconds_at_gps(
        int(obs.t_gps_ns[0]))
    tms, marks_implausible = _time_marks(data, index, leap_by_offset, times)
    mark_list = marks_mod.build_marks(tms)
    events = (marks_mod.event_times_ns(mark_list, opt.marks, opt.shutter_delay_ns)
              if opt.events else [])
    rec_type, rec_vers = _receiver(data, index, obs.source)
    approx = _approx_position(data, index, times) or (0.0, 0.0, 0.0)
    week_hint = int(obs.t_gps_ns[0] // gpstime.NS_PER_WEEK)
    nav = collect_ephemerides(data, index, week_hint)
    multi = collect_multi(data, index, receiver_times(data, index, times), int(obs.t_gps_ns[0]))
    implausible = times.implausible + marks_implausible
    if obs_hook is not None:
        obs = obs_hook(obs, nav.ephemerides, approx)
    epochs_sorted = np.sort(obs.t_gps_ns).tolist()
    interval = epochs_rule.nominal_interval_ns(epochs_sorted)
    comments = (
        f"converted from {src.name}",
        f"observations: {obs.source}; LLI bit 0 slip, bit 1 half cycle unresolved",
        (f"events (flag 5): {opt.marks} edge + shutter delay {opt.shutter_delay_ns / 1e6:g} ms"
         if opt.events else f"events: none written (the marks are in {stem}.marks.csv)"),
    )
    info = HeaderInfo(
        marker=opt.marker or stem,
        receiver_type=rec_type,
        receiver_version=rec_vers,
        approx_ecef_m=approx,
        leap_s=leap,
        comments=comments,
    )
    obs_path = out / f"{stem}.obs"
    nav_path = out / f"{stem}.nav"
    marks_path = out / f"{stem}.marks.csv"
    wr = write_obs(obs_path, obs, events, info, opt.version, interval, progress)
    n_eph = write_nav(nav_path, nav.ephemerides, opt.version, leap, nav, multi)
    written = np.sort(obs.t_gps_ns[kept_epochs(obs)]).tolist()
    marks_path.write_text(
        marks_csv(mark_list, written, opt.marks, opt.shutter_delay_ns), encoding="ascii"
    )
    in_gap = 0
    for m in mark_list:
        t = marks_mod.mark_time_ns(m, opt.marks, opt.shutter_delay_ns)
        if t is not None and epochs_rule.locate(t, written, interval).in_dropout:
            in_gap += 1
    notes: list[str] = []
    if block.source == "RXM-RAWX" and block.meas.size:
        pairs = block.meas["gnssId"].astype(np.int64) * 256 + block.meas["sigId"]
        v1 = block.header["version"][block.epoch] >= 1
        uniq, counts = np.unique(pairs[v1], return_counts=True)
        unknown = [
            f"gnssId {g // 256} sigId {g % 256} ({n})"
            for g, n in zip(uniq.tolist(), counts.tolist(), strict=True)
            if (g // 256, g % 256) not in SIGNAL_CODES
        ]
        if unknown:
            notes.append("signals without a RINEX 3.04 code here, left out: " + ", ".join(unknown))
    after_change = events_after_spacing_change(written, events)
    if after_change:
        notes.append(
            f"{after_change} of the {len(events)} event epochs come where the epochs' spacing "
            "changed (radio gaps): RTKLIB's RINEX reader drops the observation epoch after such "
            "an event, and can go on dropping the one after every later mark; for RTKLIB, "
            f"convert with --no-events (the marks stay in {marks_path.name}). groundstation "
            "solve gives its engine no events")
    if math.isfinite(approx[0]) and approx == (0.0, 0.0, 0.0):
        notes.append("the receiver recorded no position of its own: APPROX POSITION XYZ is zero")
    if not nav.ephemerides:
        notes.append("no GPS orbit data (broadcast ephemerides) in the recording: empty nav file")
    if opt.version != "3.04" and _other_counts(multi):
        notes.append("RINEX 2.11 navigation file holds GPS only: GLONASS/Galileo left out")
    if times.verdicts.jumps:
        notes.append(f"the receiver's time jumped {len(times.verdicts.jumps)} time(s) and the "
                     "next epoch confirmed it: the epoch where each jump was first seen is "
                     "left out")
    return RinexResult(
        obs_path=obs_path,
        nav_path=nav_path,
        marks_path=marks_path,
        source=obs.source,
        epochs=wr.epochs,
        events=wr.events,
        marks=len(mark_list),
        marks_in_dropout=in_gap,
        ephemerides=n_eph,
        dropped_epochs=wr.dropped_epochs,
        damaged_frames=index.damaged,
        frames=len(index),
        rejected_messages=rejected,
        nav_parity_errors=nav.parity_errors,
        implausible=implausible,
        skipped_systems=wr.skipped_systems,
        notes=tuple(notes),
        other_ephemerides=_other_counts(multi),
    )


def _other_counts(multi: MultiNav) -> tuple[tuple[str, int], ...]:
    counts = {"R": len(multi.glonass)}
    for e in multi.kepler:
        counts[e.system] = counts.get(e.system, 0) + 1
    return tuple((s, n) for s, n in counts.items() if n)


def _convert_nav_only(
    src: Path, data: bytes, index: FrameIndex, out: Path, stem: str, opt: RinexOptions,
    session: SessionTimes,
) -> RinexResult:
    """A recording without raw measurements: the navigation file alone (no obs, no marks).

    Raises:
        InputError: no navigation data either.
    """
    times = receiver_times(data, index, session)
    week_hint = (times[0][1] // gpstime.NS_PER_WEEK) if times else today_gps_week()
    nav = collect_ephemerides(data, index, week_hint)
    # GLONASS needs the day: a receiver time if any, else the first GPS ephemeris's.
    first = nav.ephemerides[0] if nav.ephemerides else None
    approx = (round((first.week * 604_800 + (first.tow_s or first.toe_s)) * 1e9)
              if first is not None else None)
    multi = collect_multi(data, index, times, approx)
    others = _other_counts(multi)
    if not nav.ephemerides and not others:
        if len(index) == 0:  # not a receiver's output at all: say what it is, as inspect does
            recording = Recording(src)
            head = next((c[:256] for c, _ in recording.chunks(chunk_bytes=4096)), b"")
            raise InputError(
                f"{src}: no raw measurements and no navigation data: no UBX frames in this file "
                f"({content_detail(recording.size_bytes, head, recording.skipped)})")
        raise InputError(
            f"{src}: no raw measurements and no navigation data (is the receiver's raw output "
            "on? groundstation configure)"
        )
    nav_path = out / f"{stem}.nav"
    known = times[0][1] if times else approx
    leap = gpstime.leap_seconds_at_gps(known) if known is not None else None
    n_eph = write_nav(nav_path, nav.ephemerides, opt.version, leap, nav, multi)
    return RinexResult(
        obs_path=out / f"{stem}.obs",
        nav_path=nav_path,
        marks_path=out / f"{stem}.marks.csv",
        source="none",
        epochs=0,
        events=0,
        marks=0,
        marks_in_dropout=0,
        ephemerides=n_eph,
        dropped_epochs=0,
        damaged_frames=index.damaged,
        frames=len(index),
        rejected_messages=0,
        nav_parity_errors=nav.parity_errors,
        implausible=session.implausible,
        notes=("no raw measurements in the recording: navigation file only",),
        other_ephemerides=others,
        obs_written=False,
    )
