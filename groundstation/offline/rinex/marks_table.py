"""The time-mark table written beside the RINEX files (``<stem>.marks.csv``)."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence

from groundstation import gpstime
from groundstation.rules.epochs import GapInfo, locate, nominal_interval_ns
from groundstation.rules.marks import Mark, MarkEdge, mark_time_ns

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


def _tow_col(t: int) -> str:
    tow_ns = gpstime.week_tow(t)[1]
    return f"{tow_ns // 10**9}.{tow_ns % 10**9:09d}"


def _gps_cols(t: int | None) -> tuple[str, str, str]:
    if t is None:
        return "", "", ""
    week = gpstime.week_tow(t)[0]
    unix_ns = gpstime.gps_to_unix_ns(t)
    d = gpstime.gps_to_datetime(t)
    utc = f"{d.year:04d}-{d.month:02d}-{d.day:02d}T{d.hour:02d}:{d.minute:02d}:{d.second:02d}"
    return str(week), _tow_col(t), f"{utc}.{unix_ns % 10**9:09d}Z"


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
        ev = "" if t is None else _tow_col(t)
        w.writerow(
            (
                i,
                m.number,
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
