"""GPS time conversions and the leap-second table."""

from __future__ import annotations

import datetime as dt

import pytest

from groundstation import gpstime


@pytest.mark.parametrize(
    ("utc", "leap"),
    [
        (dt.datetime(2012, 6, 30, 23, 59, 59, tzinfo=dt.UTC), 15),
        (dt.datetime(2012, 7, 1, 0, 0, 0, tzinfo=dt.UTC), 16),
        (dt.datetime(2016, 12, 31, 12, 0, 0, tzinfo=dt.UTC), 17),
        (dt.datetime(2018, 11, 4, 16, 34, 0, tzinfo=dt.UTC), 18),
        (dt.datetime(1980, 1, 6, tzinfo=dt.UTC), 0),
    ],
)
def test_leap_seconds(utc: dt.datetime, leap: int) -> None:
    t = gpstime.datetime_to_gps_ns(utc)
    assert gpstime.leap_seconds_at_gps(t) == leap
    assert gpstime.gps_to_datetime(t) == utc


def test_week_tow_round_trip() -> None:
    t = gpstime.gps_ns(2026, 59_981_608_930_556)
    assert gpstime.week_tow(t) == (2026, 59_981_608_930_556)
    assert gpstime.gps_ns_from_ms(2026, 59_981_608, 930_556) == t


def test_known_instant() -> None:
    # 2018-11-04 16:34:42 UTC is GPS week 2026, tow 59700 s (Sunday) + 18 s leap.
    t = gpstime.datetime_to_gps_ns(dt.datetime(2018, 11, 4, 16, 34, 42, tzinfo=dt.UTC))
    assert gpstime.week_tow(t) == (2026, 59_700 * 10**9)
    unix = gpstime.gps_to_unix_ns(t)
    assert gpstime.unix_to_gps_ns(unix) == t
    assert gpstime.format_gps(t) == "week 2026 tow 59700.000"


def test_gps_calendar_has_no_leap_seconds() -> None:
    t = gpstime.gps_ns(2026, 59_700 * 10**9)
    assert gpstime.gps_as_datetime(t) == dt.datetime(2018, 11, 4, 16, 35, 0, tzinfo=dt.UTC)
