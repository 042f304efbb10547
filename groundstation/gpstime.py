"""GPS time: week/TOW <-> nanoseconds since the GPS epoch <-> UTC, with a leap-second table."""

from __future__ import annotations

import bisect
import datetime as dt
from typing import Any

NS_PER_S = 1_000_000_000
NS_PER_WEEK = 604_800 * NS_PER_S
GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.UTC)
GPS_EPOCH_UNIX_S = int(GPS_EPOCH.timestamp())  # 315964800

# (UTC date the offset took effect, GPS - UTC in seconds). From IERS Bulletin C; the last entry
# is 2017-01-01 and none has been announced since (checked to Bulletin C 70, 2025).
LEAP_SECONDS: tuple[tuple[dt.datetime, int], ...] = tuple(
    (dt.datetime(y, m, 1, tzinfo=dt.UTC), n)
    for (y, m, n) in (
        (1981, 7, 1), (1982, 7, 2), (1983, 7, 3), (1985, 7, 4), (1988, 1, 5), (1990, 1, 6),
        (1991, 1, 7), (1992, 7, 8), (1993, 7, 9), (1994, 7, 10), (1996, 1, 11), (1997, 7, 12),
        (1999, 1, 13), (2006, 1, 14), (2009, 1, 15), (2012, 7, 16), (2015, 7, 17), (2017, 1, 18),
    )
)
# The same table as GPS ns at which each offset starts (UTC instant + the new offset).
_LEAP_GPS_NS = [
    (int(d.timestamp()) - GPS_EPOCH_UNIX_S + n) * NS_PER_S for d, n in LEAP_SECONDS
]
_LEAP_UTC_NS = [(int(d.timestamp()) - GPS_EPOCH_UNIX_S) * NS_PER_S for d, _ in LEAP_SECONDS]
_LEAP_VALUES = [n for _, n in LEAP_SECONDS]


def gps_ns(week: int, tow_ns: int) -> int:
    """Nanoseconds since the GPS epoch for a full week number and time of week in ns."""
    return week * NS_PER_WEEK + tow_ns


def gps_ns_from_ms(week: int, tow_ms: int, sub_ms_ns: int = 0) -> int:
    """GPS ns from the u-blox pair (time of week in ms, sub-millisecond part in ns)."""
    return week * NS_PER_WEEK + tow_ms * 1_000_000 + sub_ms_ns


def week_tow(t_gps_ns: int) -> tuple[int, int]:
    """Split GPS ns into (week, tow_ns)."""
    week, tow_ns = divmod(t_gps_ns, NS_PER_WEEK)
    return week, tow_ns


def leap_seconds_at_gps(t_gps_ns: int) -> int:
    """GPS - UTC in seconds at a GPS instant (0 before 1981-07-01)."""
    i = bisect.bisect_right(_LEAP_GPS_NS, t_gps_ns)
    return _LEAP_VALUES[i - 1] if i else 0


def leap_seconds_at_gps_array(t_gps_ns: Any) -> Any:
    """:func:`leap_seconds_at_gps` of every element of an int64 array."""
    import numpy as np

    i = np.searchsorted(np.asarray(_LEAP_GPS_NS, dtype=np.int64), t_gps_ns, side="right")
    values = np.asarray([0, *_LEAP_VALUES], dtype=np.int64)
    return values[i]


def leap_seconds_at_utc(t_utc_since_gps_epoch_ns: int) -> int:
    """GPS - UTC in seconds for a UTC instant given as ns since 1980-01-06 00:00 UTC."""
    i = bisect.bisect_right(_LEAP_UTC_NS, t_utc_since_gps_epoch_ns)
    return _LEAP_VALUES[i - 1] if i else 0


def gps_to_unix_ns(t_gps_ns: int) -> int:
    """UTC as UNIX ns for a GPS instant."""
    return t_gps_ns - leap_seconds_at_gps(t_gps_ns) * NS_PER_S + GPS_EPOCH_UNIX_S * NS_PER_S


def unix_to_gps_ns(t_unix_ns: int) -> int:
    """GPS ns for a UTC instant given as UNIX ns."""
    since_epoch = t_unix_ns - GPS_EPOCH_UNIX_S * NS_PER_S
    return since_epoch + leap_seconds_at_utc(since_epoch) * NS_PER_S


def gps_to_datetime(t_gps_ns: int) -> dt.datetime:
    """UTC datetime (microsecond resolution) for a GPS instant."""
    unix_ns = gps_to_unix_ns(t_gps_ns)
    return dt.datetime.fromtimestamp(unix_ns // 1000 / 1e6, tz=dt.UTC).replace(
        microsecond=(unix_ns // 1000) % 1_000_000
    )


def gps_as_datetime(t_gps_ns: int) -> dt.datetime:
    """The GPS time scale written as a calendar date (no leap seconds), as RINEX does."""
    return GPS_EPOCH + dt.timedelta(microseconds=t_gps_ns // 1000)


def gps_calendar_ns(when: dt.datetime) -> int:
    """GPS ns for the GPS time scale written as a calendar date (as RINEX does; the inverse of
    :func:`gps_as_datetime`, whole microseconds)."""
    delta = when - GPS_EPOCH
    return ((delta.days * 86_400 + delta.seconds) * NS_PER_S + delta.microseconds * 1000)


def utc_span(span: tuple[int, int]) -> str:
    """``2018-10-09 12:21:05 - 12:58:40 UTC`` for a GPS-ns span (the date again when it
    changes)."""
    a, b = gps_to_datetime(span[0]), gps_to_datetime(span[1])
    end = b.strftime("%H:%M:%S") if a.date() == b.date() else b.strftime("%Y-%m-%d %H:%M:%S")
    return f"{a:%Y-%m-%d %H:%M:%S} - {end} UTC"


def datetime_to_gps_ns(when: dt.datetime) -> int:
    """GPS ns for an aware UTC datetime."""
    if when.tzinfo is None:
        raise ValueError("datetime must be timezone-aware")
    delta = when - GPS_EPOCH
    since_epoch = (delta.days * 86_400 + delta.seconds) * NS_PER_S + delta.microseconds * 1000
    return since_epoch + leap_seconds_at_utc(since_epoch) * NS_PER_S


def format_gps(t_gps_ns: int) -> str:
    """``week 2026 tow 59700.994000000`` style text for logs and summaries."""
    week, tow_ns = week_tow(t_gps_ns)
    return f"week {week} tow {tow_ns / NS_PER_S:.3f}"
