"""TIM-TM2 fields to a :class:`~groundstation.records.TimeMark` (no pyubx2: the bulk decoder
uses this too)."""

from __future__ import annotations

from groundstation import gpstime
from groundstation.records import TimeMark


def edge_gps_ns(
    week: int, tow_ms: int, sub_ns: int, time_base: int, leap_s: int | None
) -> tuple[int | None, int]:
    """GPS ns of one TIM-TM2 edge and the leap seconds applied (UTC time base only).

    All-zero fields mean the edge was never seen. ``leap_s`` is what the receiver last declared;
    without it the leap-second table is used.
    """
    if week == 0 and tow_ms == 0 and sub_ns == 0:
        return None, 0
    t = gpstime.gps_ns_from_ms(week, tow_ms, sub_ns)
    if time_base != 2:
        return t, 0
    leap = leap_s if leap_s is not None else gpstime.leap_seconds_at_utc(t)
    return t + leap * gpstime.NS_PER_S, leap


def timemark_from_fields(
    ch: int, flags: int, count: int, wn_r: int, ms_r: int, sub_r: int, wn_f: int, ms_f: int,
    sub_f: int, acc_ns: int, *, leap_s: int | None, t_host_ns: int,
) -> TimeMark:
    """A :class:`TimeMark` from TIM-TM2's raw fields (the one place that maps them), edges on
    GPS time whatever the time base."""
    time_base = (flags >> 3) & 0x03
    rising, leap_r = edge_gps_ns(wn_r, ms_r, sub_r, time_base, leap_s)
    falling, leap_f = edge_gps_ns(wn_f, ms_f, sub_f, time_base, leap_s)
    return TimeMark(
        channel=ch,
        count=count,
        rising_t_gps_ns=rising,
        falling_t_gps_ns=falling,
        new_rising=bool(flags & 0x80),
        new_falling=bool(flags & 0x04),
        time_base=time_base,
        valid=bool(flags & 0x40),
        acc_ns=acc_ns,
        t_host_ns=t_host_ns,
        flags=flags,
        mode_running=bool(flags & 0x01),
        run=bool(flags & 0x02),
        utc_valid=bool(flags & 0x20),
        leap_s_applied=leap_f or leap_r,
    )
