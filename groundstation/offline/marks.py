"""Camera time marks from TIM-TM2 records: pulses, event times per edge choice, dropouts, CSV table.

A TIM-TM2 record repeats the latest falling and rising edge times; the ``new_falling`` and
``new_rising`` flags say which of them are new. A *mark* is one new falling edge, paired with
the first new rising edge after it (and before the next falling edge); a rising edge with no
falling edge before it (the receiver was connected mid-pulse, or the falling record was lost)
makes a mark of its own with no falling time.
"""

from __future__ import annotations

import bisect
import csv
import io
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

from groundstation import gpstime
from groundstation.records import TimeMark

MarkEdge = Literal["falling", "rising", "both", "mid"]
MARK_EDGES: tuple[MarkEdge, ...] = ("falling", "rising", "both", "mid")

DROPOUT_FACTOR = 1.5
"""A gap between epochs longer than this many nominal intervals is a dropout."""


@dataclass(frozen=True, slots=True)
class Mark:
    """One camera trigger pulse.

    Attributes:
        falling_t_gps_ns: falling edge (shutter contact closes) in GPS ns, if seen.
        rising_t_gps_ns: rising edge (contact opens) in GPS ns, if seen.
        count: the receiver's edge counter of the record that brought the last new edge.
        channel: EXTINT channel.
        flags: TIM-TM2 flags byte of that record.
        time_base: 0 receiver, 1 GPS, 2 UTC (edge times are converted to GPS time anyway).
        time_valid: the receiver said its time was valid.
        utc_valid: the receiver said UTC was valid.
        acc_ns: accuracy estimate (ns).
        lost_before: marks lost just before this one, from jumps of ``count``.
    """

    falling_t_gps_ns: int | None
    rising_t_gps_ns: int | None
    count: int
    channel: int
    flags: int
    time_base: int
    time_valid: bool
    utc_valid: bool
    acc_ns: int
    lost_before: int = 0

    @property
    def pulse_ns(self) -> int | None:
        if self.falling_t_gps_ns is None or self.rising_t_gps_ns is None:
            return None
        return self.rising_t_gps_ns - self.falling_t_gps_ns


def mark_number(record: TimeMark) -> int:
    """The rising-edge count a pulse has once its rising edge is counted: ``count`` itself on a
    record that carries the pulse's rising edge, ``count + 1`` on a falling-edge-only record
    (the receiver's counter counts rising edges)."""
    return record.count if record.new_rising else (record.count + 1) & 0xFFFF


def build_marks(records: Iterable[TimeMark]) -> list[Mark]:
    """Marks (one per pulse) from TIM-TM2 records in stream order.

    Repeated records (the same edge reported again) add nothing. A pulse whose falling-edge
    record was lost keeps its falling edge, which the rising-edge record repeats. A jump in the
    pulses' numbers (:func:`mark_number`) is recorded as ``lost_before`` on the next mark: those
    pulses were counted by the receiver but none of their records arrived.
    """
    marks: list[Mark] = []
    seen_falling: set[int] = set()
    seen_rising: set[int] = set()
    open_idx: int | None = None  # a mark whose rising edge has not come yet
    last_number: int | None = None

    def make(r: TimeMark, f: int | None, ri: int | None, lost: int) -> Mark:
        return Mark(
            f, ri, r.count, r.channel, r.flags, r.time_base, r.valid, r.utc_valid, r.acc_ns, lost
        )

    def lost_before(r: TimeMark) -> int:
        nonlocal last_number
        number = mark_number(r)
        step = 1 if last_number is None else (number - last_number) & 0xFFFF
        last_number = number
        return step - 1 if 1 < step < 0x8000 else 0

    for r in records:
        falling = r.falling_t_gps_ns
        rising = r.rising_t_gps_ns
        if r.new_falling and falling is not None and falling not in seen_falling:
            seen_falling.add(falling)
            marks.append(make(r, falling, None, lost_before(r)))
            open_idx = len(marks) - 1
        if r.new_rising and rising is not None and rising not in seen_rising:
            seen_rising.add(rising)
            m = marks[open_idx] if open_idx is not None else None
            if (
                open_idx is not None
                and m is not None
                and m.falling_t_gps_ns is not None
                and rising >= m.falling_t_gps_ns
            ):
                marks[open_idx] = make(r, m.falling_t_gps_ns, rising, m.lost_before)
            else:
                # Its falling-edge record never arrived: the rising-edge record repeats it.
                f = falling if falling is not None and falling not in seen_falling and (
                    falling <= rising) else None
                if f is not None:
                    seen_falling.add(f)
                marks.append(make(r, f, rising, lost_before(r)))
            open_idx = None
    return marks


def event_times_ns(marks: Sequence[Mark], edge: MarkEdge, shutter_delay_ns: int = 0) -> list[int]:
    """GPS ns of the event epochs to write, sorted: the chosen edge(s) plus the shutter delay.

    ``mid`` needs both edges of a pulse; marks lacking the chosen edge make no event.
    """
    out: list[int] = []
    for m in marks:
        f, r = m.falling_t_gps_ns, m.rising_t_gps_ns
        if edge == "falling" and f is not None:
            out.append(f)
        elif edge == "rising" and r is not None:
            out.append(r)
        elif edge == "both":
            out.extend(t for t in (f, r) if t is not None)
        elif edge == "mid" and f is not None and r is not None:
            out.append((f + r) // 2)
    return sorted(t + shutter_delay_ns for t in out)


def mark_time_ns(mark: Mark, edge: MarkEdge, shutter_delay_ns: int = 0) -> int | None:
    """The time a mark stands for under an edge choice (``both`` uses the falling edge)."""
    f, r = mark.falling_t_gps_ns, mark.rising_t_gps_ns
    if edge in ("falling", "both"):
        t = f
    elif edge == "rising":
        t = r
    else:
        t = (f + r) // 2 if f is not None and r is not None else None
    return None if t is None else t + shutter_delay_ns


def nominal_interval_ns(epoch_t_gps_ns: Sequence[int]) -> int | None:
    """The most common spacing of consecutive epochs (the logging interval), if any."""
    if len(epoch_t_gps_ns) < 2:
        return None
    counts: dict[int, int] = {}
    for a, b in zip(epoch_t_gps_ns, epoch_t_gps_ns[1:], strict=False):
        d = round((b - a) / 1e6) * 1_000_000  # to the ms: RXM-RAWX epochs jitter by ns
        if d > 0:
            counts[d] = counts.get(d, 0) + 1
    return max(counts, key=lambda k: (counts[k], -k)) if counts else None


@dataclass(frozen=True, slots=True)
class GapInfo:
    """Where a time lies in the epoch sequence."""

    in_dropout: bool
    outside: bool
    gap_ns: int | None


def locate(t_gps_ns: int, epochs: Sequence[int], interval_ns: int | None) -> GapInfo:
    """Whether ``t_gps_ns`` falls inside a dropout (a gap longer than 1.5 intervals)."""
    if not epochs:
        return GapInfo(False, True, None)
    i = bisect.bisect_right(epochs, t_gps_ns)
    if i == 0 or i == len(epochs):
        if i and epochs[-1] == t_gps_ns:
            return GapInfo(False, False, 0)
        return GapInfo(False, True, None)
    gap = epochs[i] - epochs[i - 1]
    dropout = interval_ns is not None and gap > DROPOUT_FACTOR * interval_ns
    return GapInfo(dropout, False, gap)


CSV_COLUMNS = (
    "mark",
    "count",
    "channel",
    "falling_gps_week",
    "falling_gps_tow_s",
    "falling_utc",
    "rising_gps_week",
    "rising_gps_tow_s",
    "rising_utc",
    "pulse_ms",
    "event_gps_tow_s",
    "flags_hex",
    "time_base",
    "time_valid",
    "utc_valid",
    "acc_ns",
    "lost_before",
    "in_dropout",
    "outside_epochs",
    "gap_s",
)


def _gps_cols(t: int | None) -> tuple[str, str, str]:
    if t is None:
        return "", "", ""
    week, tow_ns = gpstime.week_tow(t)
    unix_ns = gpstime.gps_to_unix_ns(t)
    utc = gpstime.gps_to_datetime(t).strftime("%Y-%m-%dT%H:%M:%S")
    return str(week), f"{tow_ns // 10**9}.{tow_ns % 10**9:09d}", f"{utc}.{unix_ns % 10**9:09d}Z"


def marks_csv(
    marks: Sequence[Mark],
    epochs: Sequence[int],
    edge: MarkEdge,
    shutter_delay_ns: int = 0,
) -> str:
    """The marks table as CSV text (GPS week/TOW and UTC with ns, flags, dropout status)."""
    interval = nominal_interval_ns(epochs)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for i, m in enumerate(marks, start=1):
        t = mark_time_ns(m, edge, shutter_delay_ns)
        where = locate(t, epochs, interval) if t is not None else GapInfo(False, True, None)
        pulse = m.pulse_ns
        ev = "" if t is None else _gps_cols(t)[1]
        w.writerow(
            (
                i,
                m.count,
                m.channel,
                *_gps_cols(m.falling_t_gps_ns),
                *_gps_cols(m.rising_t_gps_ns),
                "" if pulse is None else f"{pulse / 1e6:.6f}",
                ev,
                f"0x{m.flags:02X}",
                {0: "receiver", 1: "GPS", 2: "UTC"}.get(m.time_base, str(m.time_base)),
                int(m.time_valid),
                int(m.utc_valid),
                m.acc_ns,
                m.lost_before,
                int(where.in_dropout),
                int(where.outside),
                "" if where.gap_ns is None else f"{where.gap_ns / 1e9:.3f}",
            )
        )
    return buf.getvalue()
