"""TIM-TM2 fields to a :class:`~groundstation.records.TimeMark` (no pyubx2: the bulk decoder
uses this too). The flag bits come from :data:`~groundstation.ubx.layouts.TIM_TM2_FLAGS`."""

from __future__ import annotations

from groundstation import gpstime
from groundstation.records import TimeMark
from groundstation.ubx.layouts import TIM_TM2_FLAGS as _FLAGS

_MODE = _FLAGS.mask("mode")
_RUN = _FLAGS.mask("run")
_NEW_FALLING = _FLAGS.mask("newFallingEdge")
_UTC = _FLAGS.mask("utc")
_TIME_VALID = _FLAGS.mask("time")
_NEW_RISING = _FLAGS.mask("newRisingEdge")
_BASE_LO, _BASE_W = _FLAGS.parts["timeBase"]
TIME_BASE_UTC = 2


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
    if time_base != TIME_BASE_UTC:
        return t, 0
    leap = leap_s if leap_s is not None else gpstime.leap_seconds_at_utc(t)
    return t + leap * gpstime.NS_PER_S, leap


def timemark_from_fields(
    ch: int, flags: int, count: int, wn_r: int, ms_r: int, sub_r: int, wn_f: int, ms_f: int,
    sub_f: int, acc_ns: int, *, leap_s: int | None, t_host_ns: int,
) -> TimeMark:
    """A :class:`TimeMark` from TIM-TM2's raw fields (the one place that maps them), edges on
    GPS time whatever the time base."""
    time_base = (flags >> _BASE_LO) & ((1 << _BASE_W) - 1)
    rising, leap_r = edge_gps_ns(wn_r, ms_r, sub_r, time_base, leap_s)
    falling, leap_f = edge_gps_ns(wn_f, ms_f, sub_f, time_base, leap_s)
    return TimeMark(
        channel=ch,
        count=count,
        rising_t_gps_ns=rising,
        falling_t_gps_ns=falling,
        new_rising=bool(flags & _NEW_RISING),
        new_falling=bool(flags & _NEW_FALLING),
        time_base=time_base,
        valid=bool(flags & _TIME_VALID),
        acc_ns=acc_ns,
        t_host_ns=t_host_ns,
        flags=flags,
        mode_running=bool(flags & _MODE),
        run=bool(flags & _RUN),
        utc_valid=bool(flags & _UTC),
        leap_s_applied=leap_f or leap_r,
    )
