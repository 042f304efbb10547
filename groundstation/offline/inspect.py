"""Summary of a recording: span, message counts, damage, epochs and gaps, time marks, satellites.

Sans-I/O: :class:`Inspector` takes frames (from any source) and returns a :class:`Summary`;
:func:`inspect_path` wires it to a file through the same framer and decoder as the daemon.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from groundstation import gpstime
from groundstation.errors import InputError
from groundstation.records import (
    GNSS_GLONASS,
    UNKNOWN_GLONASS_SV,
    Frame,
    RawEpoch,
    TimeMark,
    UndecodedFrame,
    sv_label,
)
from groundstation.rules.epochs import Gap, find_gaps, nominal_interval_ns
from groundstation.rules.marks import (
    LOST_IN_RECEIVER,
    LOST_ON_LINK,
    lost_by_cause,
    track_marks,
)
from groundstation.storage.reading import Recording
from groundstation.storage.skipped import Skipped
from groundstation.ubx.decode import Decoder, message_name
from groundstation.ubx.framer import DEFAULT_MAX_PAYLOAD, FramerStats, UbxFramer

UNKNOWN_SV = UNKNOWN_GLONASS_SV
"""u-blox svId of a GLONASS satellite whose slot number is not known yet."""


def gap_json(g: Gap) -> dict[str, Any]:
    """A gap as ``inspect --json`` prints it."""
    return {
        "after": gpstime.format_gps(g.after_t_gps_ns),
        "before": gpstime.format_gps(g.before_t_gps_ns),
        "after_t_gps_ns": g.after_t_gps_ns,
        "before_t_gps_ns": g.before_t_gps_ns,
        "missing_epochs": g.missing_epochs,
        "duration_s": round(g.duration_s, 3),
    }


@dataclass(frozen=True, slots=True)
class TimeMarkSummary:
    records: int = 0
    falling: int = 0
    rising: int = 0
    count_jumps: int = 0
    missed_marks: int = 0
    lost_on_link: int = 0
    """Of ``missed_marks``: their epochs lie in holes of the received epochs (inspect sees the
    holes, not damaged bytes between frames: those count as not reported here)."""
    not_reported: int = 0
    repeated_counts: int = 0
    first_count: int | None = None
    last_count: int | None = None
    time_bases: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class Summary:
    """What ``groundstation inspect`` reports."""

    path: str
    format: str
    bytes: int
    messages: dict[str, int]
    frames: int
    damaged_frames: int
    damage: dict[str, int]
    garbage_bytes: int
    nmea_sentences: int
    rtcm3_frames: int
    undecodable: int
    epochs: int
    empty_epochs: int
    epoch_sources: dict[str, int]
    epoch_interval_s: float | None
    first_epoch_t_gps_ns: int | None
    last_epoch_t_gps_ns: int | None
    gaps: tuple[Gap, ...]
    missing_epochs: int
    timemarks: TimeMarkSummary
    satellites: tuple[str, ...]
    max_sats_per_epoch: int
    file_bytes: int = 0
    """Size on disk of the recording (all parts); ``bytes`` is the raw stream inside it."""
    unknown_slot_signals: int = 0
    """GLONASS measurements without a known slot (u-blox svId 255): not a satellite name."""
    skipped: tuple[Skipped, ...] = ()
    """Damaged stretches of the file read past: their bytes are not in ``bytes``."""
    orphan_messages: int = 0
    """Messages whose channel was defined only in a skipped stretch (not read)."""
    implausible: dict[str, int] = field(default_factory=dict)
    """Frames with a valid checksum whose time cannot belong to the session, by message type
    (:mod:`groundstation.rules.plausible`): kept in the recording, not counted as epochs or
    marks (RINEX and the solver leave them out too)."""
    time_jumps: int = 0
    """Jumps of the receiver's time that a second epoch confirmed."""

    def as_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["skipped"] = [k.as_json() for k in self.skipped]
        d["gaps"] = [gap_json(g) for g in self.gaps]
        d["timemarks"] = asdict(self.timemarks)
        d["satellites"] = list(self.satellites)
        d["span"] = None
        if self.first_epoch_t_gps_ns is not None and self.last_epoch_t_gps_ns is not None:
            d["span"] = {
                "first": gpstime.format_gps(self.first_epoch_t_gps_ns),
                "last": gpstime.format_gps(self.last_epoch_t_gps_ns),
                "first_utc": gpstime.gps_to_datetime(self.first_epoch_t_gps_ns).isoformat(),
                "last_utc": gpstime.gps_to_datetime(self.last_epoch_t_gps_ns).isoformat(),
                "duration_s": (self.last_epoch_t_gps_ns - self.first_epoch_t_gps_ns) / 1e9,
            }
        return d


@dataclass(slots=True)
class Inspector:
    """Accumulates frames and produces a :class:`Summary`."""

    decoder: Decoder = field(default_factory=Decoder)
    messages: Counter[tuple[int, int]] = field(default_factory=Counter)
    """Frames by (class, id); named once in :meth:`summary`."""
    epoch_times: Counter[int] = field(default_factory=Counter)
    """Epochs by time (RXM-RAW and RXM-RAWX of one epoch count once)."""
    epoch_offsets: dict[int, int] = field(default_factory=dict)
    """Stream offset -> time of each epoch counted (to take out one found odd afterwards)."""
    empty_epochs: int = 0
    epoch_sources: Counter[str] = field(default_factory=Counter)
    sats: set[tuple[int, int]] = field(default_factory=set)
    max_sats: int = 0
    unknown_slot: int = 0
    marks: list[TimeMark] = field(default_factory=list)
    undecodable: int = 0

    def add(self, frame: Frame) -> None:
        self.messages[frame.cls, frame.id] += 1
        record = self.decoder.decode(frame)
        if isinstance(record, RawEpoch):
            # A receiver without a time fix (week 0) or without measurements makes no epoch.
            if record.gps_week == 0 or not record.sats:
                self.empty_epochs += 1
                return
            self.epoch_times[record.t_gps_ns] += 1
            self.epoch_offsets[frame.offset] = record.t_gps_ns
            self.epoch_sources[record.source] += 1
            self.max_sats = max(self.max_sats, len(record.sats))
            # u-blox reports a GLONASS satellite whose slot it does not know yet as svId 255
            # ("R255"): a measurement, not a satellite to list.
            # keyed by (gnss, sv), labelled once in summary(): a label per measurement was a
            # tenth of inspect's time
            ids = {(s.gnss, s.sv) for s in record.sats}
            if (GNSS_GLONASS, UNKNOWN_SV) in ids:
                ids.discard((GNSS_GLONASS, UNKNOWN_SV))
                self.unknown_slot += sum(
                    (s.gnss, s.sv) == (GNSS_GLONASS, UNKNOWN_SV) for s in record.sats)
            self.sats |= ids
        elif isinstance(record, TimeMark):
            self.marks.append(record)
        elif isinstance(record, UndecodedFrame) and not record.implausible:
            self.undecodable += 1

    def _named_messages(self) -> Counter[str]:
        named: Counter[str] = Counter()
        for (cls, mid), n in self.messages.items():
            named[message_name(cls, mid)] += n
        return named

    def summary(self, stats: FramerStats, *, path: str = "", fmt: str = "") -> Summary:
        # epochs the plausibility rule found to be the odd ones after they were decoded (by
        # their frames: a real epoch may have the same time as an odd one)
        odd = Counter(self.epoch_offsets[o] for o in self.decoder.refuted_offsets
                      if o in self.epoch_offsets)
        times = sorted(self.epoch_times - odd)
        interval_ns = nominal_interval_ns(times)
        gaps = find_gaps(times, interval_ns)
        return Summary(
            path=path,
            format=fmt,
            bytes=stats.bytes_in,
            messages=dict(sorted(self._named_messages().items())),
            frames=stats.frames,
            damaged_frames=stats.damaged_frames,
            damage={
                "bad_checksum": stats.bad_checksum,
                "too_long": stats.too_long,
                "truncated": stats.truncated,
            },
            garbage_bytes=stats.garbage_bytes,
            nmea_sentences=stats.nmea_sentences,
            rtcm3_frames=stats.rtcm3_frames,
            undecodable=self.undecodable,
            epochs=len(times),
            empty_epochs=self.empty_epochs,
            epoch_sources=dict(self.epoch_sources),
            epoch_interval_s=interval_ns / 1e9 if interval_ns else None,
            first_epoch_t_gps_ns=times[0] if times else None,
            last_epoch_t_gps_ns=times[-1] if times else None,
            gaps=tuple(gaps),
            missing_epochs=sum(g.missing_epochs for g in gaps),
            timemarks=summarise_marks(
                self.marks, [(g.after_t_gps_ns, g.before_t_gps_ns) for g in gaps], interval_ns),
            satellites=tuple(sorted({sv_label(g, sv) for g, sv in self.sats})),
            max_sats_per_epoch=self.max_sats,
            unknown_slot_signals=self.unknown_slot,
            implausible=dict(sorted(self.decoder.stats.implausible_by_type.items())),
            time_jumps=self.decoder.stats.time_jumps,
        )


def summarise_marks(records: list[TimeMark], holes: Sequence[tuple[int, int]] = (),
                    interval_ns: int | None = None) -> TimeMarkSummary:
    """Pulses, their edges, count continuity and duplicates, from TIM-TM2 records (the marks
    rule of :mod:`groundstation.rules.marks`, as for RINEX, the solver and the monitor); the
    lost ones by cause (:func:`~groundstation.rules.marks.lost_cause`, ``holes`` in the
    received epochs)."""
    if not records:
        return TimeMarkSummary()
    marks, tracker = track_marks(records)
    lost = lost_by_cause(marks, holes, (), interval_ns)
    return TimeMarkSummary(
        lost_on_link=len(lost[LOST_ON_LINK]), not_reported=len(lost[LOST_IN_RECEIVER]),
        records=len(records),
        falling=sum(m.falling_t_gps_ns is not None for m in marks),
        rising=sum(m.rising_t_gps_ns is not None for m in marks),
        count_jumps=sum(m.lost_before > 0 for m in marks),
        missed_marks=sum(m.lost_before for m in marks),
        repeated_counts=tracker.duplicates,
        first_count=marks[0].number if marks else None,  # the marks' names (mark_NNNN)
        last_count=marks[-1].number if marks else None,
        time_bases=tuple(sorted({r.time_base_name for r in records})),
    )


def inspect_path(path: str | Path, max_payload: int = DEFAULT_MAX_PAYLOAD) -> Summary:
    """Read a recording through the framer and decoder and summarise it."""
    p = Path(path)
    recording = Recording(p)
    framer = UbxFramer(max_payload)
    insp = Inspector()
    last_t = 0
    for chunk, t_host_ns in recording.chunks():
        last_t = t_host_ns
        for frame in framer.feed(chunk, t_host_ns):
            insp.add(frame)
    for frame in framer.flush(last_t):
        insp.add(frame)
    out = insp.summary(framer.stats, path=str(p), fmt=recording.format)
    return replace(out, file_bytes=recording.size_bytes, skipped=tuple(recording.skipped),
                   orphan_messages=recording.orphan_messages)


FILE_SIGNATURES: tuple[tuple[bytes, str], ...] = (
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"\x89PNG", "a PNG image"),
    (b"%PDF", "a PDF document"),
    (b"PK\x03\x04", "a ZIP archive"),
)
"""Leading bytes of files users hand over by mistake (a photo instead of the flight)."""

RINEX_TYPES = {"O": "observation", "N": "navigation", "G": "navigation", "H": "navigation",
               "L": "navigation", "C": "navigation", "M": "meteorological"}
"""A RINEX header's file type letter (column 21 of its first line), in words."""


def what_file(head: bytes) -> str | None:
    """What a file that is not a recording looks like from its first bytes ("a JPEG image",
    "a RINEX 3.04 observation file"), or None.

    RINEX is recognised by its first header line's label (columns 61-80 ``RINEX VERSION /
    TYPE``, or Hatanaka's ``CRINEX VERS   / TYPE``): the files ``rinex`` writes and RTKLIB
    reads, handed to a command that reads receiver recordings.
    """
    named = next((name for magic, name in FILE_SIGNATURES if head.startswith(magic)), None)
    if named is not None:
        return named
    first = head.split(b"\n", 1)[0].decode("ascii", "replace")
    if first[60:80] == "CRINEX VERS   / TYPE":
        return "a Hatanaka-compressed RINEX file"
    if first[60:80] != "RINEX VERSION / TYPE":
        return None
    version = first[:9].strip()
    kind = RINEX_TYPES.get(first[20:21], "")
    return f"a RINEX {version} {kind} file".replace("  ", " ")


def require_ubx_frames(path: str | Path, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
    """Raise unless the recording holds at least one valid UBX frame.

    Reads only as far as the first frame, so a real recording costs one chunk. The one check
    behind ``inspect``, ``replay`` and ``run --file``: a JPEG or an empty file gives an error
    ("no UBX frames in this file", exit 1) instead of an all-zero report.

    Raises:
        InputError: missing, unreadable, or no UBX frame in the whole file.
    """
    p = Path(path)
    recording = Recording(p)
    framer = UbxFramer(max_payload)
    last_t = 0
    head = b""
    for chunk, t_host_ns in recording.chunks():
        if not head:
            head = chunk[:256]
        last_t = t_host_ns
        if any(True for _ in framer.feed(chunk, t_host_ns)):
            return
    if any(True for _ in framer.flush(last_t)):
        return
    detail = content_detail(recording.size_bytes, head, recording.skipped)
    raise InputError(f"{p}: no UBX frames in this file ({detail})")


def content_detail(size: int, head: bytes, skipped: Sequence[Skipped] = ()) -> str:
    """A file without UBX frames in a few words: "513 bytes, a JPEG image", "empty file",
    "142 bytes; bytes 29 .. the end of the file unreadable: chunk header damaged (...)"."""
    what = what_file(head)
    out = "empty file" if size == 0 else (
        f"{size:,} bytes, {what}, not a receiver recording" if what and "RINEX" in what
        else f"{size:,} bytes, {what}" if what else f"{size:,} bytes"
    )
    return "; ".join([out, *(k.brief() for k in skipped)])
