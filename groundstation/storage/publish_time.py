"""Which GPS time stamps a recorded record's ``publish_time`` (UNIX ns, UTC).

RawEpoch: its epoch; TimeMark: the edge that stands for the mark; NavSolution and SvInfo: their
TOW in the week of the latest epoch (or their own). Records without a GPS time (a week-0 epoch of
a receiver without time yet), before one is known, or with one an MCAP ``publish_time`` cannot
hold (an unsigned 64-bit count of ns since 1970: before 1970 or after 2554), keep the host
receive time. The decoder passes only times that can belong to the session
(:mod:`groundstation.rules.plausible`); the range is checked here too because this is where a
time becomes a field of the file, and one out of its range ended the recording.
"""

from __future__ import annotations

from typing import Any

from groundstation import gpstime
from groundstation.records import NavSolution, RawEpoch, SvInfo, TimeMark
from groundstation.rules.marks import record_time_ns

HALF_WEEK_NS = gpstime.NS_PER_WEEK // 2
MCAP_TIME_MAX_NS = (1 << 64) - 1
"""The largest MCAP ``log_time`` / ``publish_time`` (uint64 ns)."""


class PublishClock:
    """Stateful: remembers the GPS week of the latest epoch for records that carry only a TOW."""

    def __init__(self) -> None:
        self._week: int | None = None
        self._tow_ns = 0

    def _gps_unix_ns(self, tow_ns: int, week: int | None) -> int | None:
        if week is None:
            if self._week is None:
                return None
            week = self._week
            if tow_ns - self._tow_ns > HALF_WEEK_NS:
                week -= 1
            elif self._tow_ns - tow_ns > HALF_WEEK_NS:
                week += 1
        return gpstime.gps_to_unix_ns(week * gpstime.NS_PER_WEEK + tow_ns)

    def publish_time_ns(self, record: Any, log_time_ns: int) -> int:
        """The ``publish_time`` of ``record`` received at ``log_time_ns``."""
        t: int | None = None
        if isinstance(record, RawEpoch):
            if record.gps_week > 0:
                self._week, self._tow_ns = record.gps_week, record.tow_ns
                t = gpstime.gps_to_unix_ns(record.t_gps_ns)
        elif isinstance(record, TimeMark):
            edge = record_time_ns(record)  # the marks rule (rules/marks.py)
            t = gpstime.gps_to_unix_ns(edge) if edge is not None else None
        elif isinstance(record, (NavSolution, SvInfo)):
            week = record.gps_week if isinstance(record, NavSolution) else None
            t = self._gps_unix_ns(record.tow_ns, week)
        return t if t is not None and 0 <= t <= MCAP_TIME_MAX_NS else log_time_ns
