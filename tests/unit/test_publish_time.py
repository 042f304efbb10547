"""Which time stamps a recorded record's MCAP ``publish_time``: never one the file cannot hold
(issue 27: a frame of week 32 767 passed its checksum and its publish time, past 2^64 ns, ended
the recording)."""

from __future__ import annotations

from streams import TOW0_MS, WEEK

from groundstation.gpstime import NS_PER_WEEK, gps_to_unix_ns
from groundstation.records import NavSolution, RawEpoch, TimeMark
from groundstation.storage.publish_time import MCAP_TIME_MAX_NS, PublishClock

LOG_NS = 1_700_000_000 * 10**9


def epoch(week: int, tow_ms: int = TOW0_MS) -> RawEpoch:
    return RawEpoch(week, tow_ms * 1_000_000, (), "RXM-RAW")


def nav(tow_ms: int, week: int | None = None) -> NavSolution:
    return NavSolution("NAV-SOL", tow_ms * 1_000_000, week, 3, True, 5, None, None, None, None,
                       None, None, None)


def mark(falling_t_gps_ns: int) -> TimeMark:
    return TimeMark(0, 1, None, falling_t_gps_ns, False, True, 1, True, 20, 0)


def test_gps_times_stamp_records() -> None:
    clock = PublishClock()
    assert clock.publish_time_ns(nav(TOW0_MS), LOG_NS) == LOG_NS  # no week known yet
    t = WEEK * NS_PER_WEEK + TOW0_MS * 1_000_000
    assert clock.publish_time_ns(epoch(WEEK), LOG_NS) == gps_to_unix_ns(t)
    assert clock.publish_time_ns(nav(TOW0_MS + 200), LOG_NS) == gps_to_unix_ns(t + 200_000_000)
    assert clock.publish_time_ns(mark(t + 5), LOG_NS) == gps_to_unix_ns(t + 5)


def test_times_an_mcap_cannot_hold_keep_the_log_time() -> None:
    clock = PublishClock()
    assert clock.publish_time_ns(epoch(32767), LOG_NS) == LOG_NS  # past the year 2554
    assert clock.publish_time_ns(nav(TOW0_MS, 65535), LOG_NS) == LOG_NS
    assert clock.publish_time_ns(mark(65535 * NS_PER_WEEK), LOG_NS) == LOG_NS
    assert clock.publish_time_ns(epoch(-1), LOG_NS) == LOG_NS  # before 1970
    assert gps_to_unix_ns(29979 * NS_PER_WEEK) > MCAP_TIME_MAX_NS  # in week 29 978 already


def test_a_week_0_epoch_has_no_gps_time_and_sets_no_week() -> None:
    clock = PublishClock()
    assert clock.publish_time_ns(epoch(0, 5000), LOG_NS) == LOG_NS
    assert clock.publish_time_ns(nav(TOW0_MS), LOG_NS) == LOG_NS  # still no week
