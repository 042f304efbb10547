"""Plausible times: which measurement epochs, time marks and fixes can belong to a session.

A frame that passed its checksum by chance carries random field values: a lossy radio makes the
framer try many candidate frames after damage, and a 16-bit Fletcher checksum passes about one
random candidate in 65 536. Such a frame's bytes stay in the recording (``/ubx/raw``, the
``.ubx`` sidecar); whether its *time* can belong to the session is decided here, once, for the
streaming decoder (:class:`SessionClock`, in :class:`~groundstation.ubx.decode.Decoder`: the
daemon, replay, inspect, the solver's marks) and for the bulk decoder (:func:`epoch_verdicts`,
in :mod:`~groundstation.ubx.fastraw`: RINEX, the solver's observations), so that every tool keeps
and drops the same records. A record that fails is counted, logged and never decoded: it does not
move the clock, the monitor, the recorder's publish times, RINEX or the solver.

The rule, from the receiver and the session:

1. **The receiver's ranges**, each message alone: a time of week in [0, 604 800 s), a
   sub-millisecond part in [0, 1 ms), a GPS week of at least 1 (week 0 is a receiver without
   time yet: such an epoch passes as a cold start but never sets the clock), finite measurements
   (a receiver never sends NaN or infinity), and a time the records and the bus carry (before
   2^62 ns, the year 2126: :data:`MAX_T_GPS_NS`).
2. **The host clock, where there is one**: the session's first time cannot lie after the host's
   clock (its reception time live, the computer's clock offline) by more than
   :data:`HOST_CLOCK_SLACK_NS` (more than any host clock is wrong by).
3. **The session's own clock**: the latest plausible epoch. The next epoch may follow it by the
   *allowance* (:func:`allowance_ns`): where the frames have host reception times, the host time
   elapsed since that epoch plus the link's latency (:data:`LINK_LATENCY_NS`: the receiver's
   time and the host's run at the same rate, whatever the host clock's offset); without them
   (a ``.ubx`` file), a minute or ten of the receiver's epoch intervals. It may precede it by
   :data:`BACK_NS` (a repeat, a receiver clock reset). A mark's new edge and a fix with a week
   lie within the allowance either side of the clock; a mark's repeated edge (the receiver
   repeats its last one) not after it; a fix with a time of week only, within the allowance
   around the clock's time of week.
4. **A jump is the receiver's new time only when an epoch confirms it**: two epochs in a row
   that agree with each other and not with the clock (the receiver was off, the host clock was
   wrong, the first epoch was the false one) move the clock to them; the first of the two is
   counted as not used. A random frame is never confirmed by the next one.

The session's first plausible epoch anchors the clock; the frames before it are judged by the
ranges and the host clock alone.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation.gpstime import GPS_EPOCH_UNIX_S, NS_PER_S, NS_PER_WEEK, gps_to_unix_ns

WEEK_MS = 604_800_000
"""A time of week in ms is below this (u-blox ``iTOW``, ``towMs``)."""
WEEK_S = 604_800.0
MS_NS = 1_000_000
"""A sub-millisecond part in ns is below this (TIM-TM2 ``towSubMs``)."""
FTOW_MAX_NS = 500_000
"""NAV-SOL ``fTOW`` rounds ``iTOW`` to the nearest ms: within ±0.5 ms."""
MAX_T_GPS_NS = 1 << 62
"""No time at or after this (about the year 2126): the bus's limit (``messages.MAX_TIME_NS``),
and a time a week number times ``NS_PER_WEEK`` computes without overflow in 64 bits."""
MAX_WEEK = MAX_T_GPS_NS // NS_PER_WEEK - 1
"""The largest GPS week whose every time of week lies before :data:`MAX_T_GPS_NS`."""
HOST_CLOCK_SLACK_NS = 1024 * NS_PER_WEEK
"""How far the session's first time may lie after the host's clock: one GPS week-number era
(1024 weeks, 19.6 years, the span of the broadcast 10-bit week). A host clock is never that far
behind: a field laptop without network time drifts by seconds a day, a Raspberry Pi without a
real-time clock restores the time of its last shutdown (days or weeks behind), one reset to its
firmware's date is a year or two behind. A random week (16 bits) mostly lies beyond it. A host
clock further behind costs one epoch (rule 4) and is said."""
JUMP_MIN_NS = 60 * NS_PER_S
"""The allowance of a stream without host times: a radio that shares its channel loses seconds
of epochs (the field report: ~300 places of one or more 0.2 s epochs in a flight); a minute
without a single epoch is an outage (out of range, receiver off), after which the new time needs
a confirming epoch."""
JUMP_INTERVALS = 10
"""... or ten of the receiver's epoch intervals (its shortest spacing so far), for a receiver
that logs slowly (a base polled every 30 s)."""
LINK_LATENCY_NS = 5 * NS_PER_S
"""What the host clock's elapsed time is allowed besides: an epoch's bytes wait in the radio,
the serial buffer and the reader for milliseconds to a second; the margin also covers a host
clock slewed by NTP (at most 0.5 ms a second). A host clock stepped by more costs one epoch
(rule 4)."""
BACK_NS = NS_PER_S
"""How far an epoch may precede the clock: a repeat (RXM-RAW and RXM-RAWX both on) or a
receiver clock reset (RXM-RAWX ``clkReset``, a millisecond); never more on an ordered link."""

HOST_TIME_MIN_NS = GPS_EPOCH_UNIX_S * NS_PER_S
"""A reception time before the GPS epoch (1980-01-06) is no host clock reading (a stream's
chunks numbered from 0, a test's counter): such a frame is judged as one without a host time."""

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


def span_text(ns: int) -> str:
    """A signed time difference for a log line: ``+1.2 s``, ``-3.0 h``, ``+6.2 days``."""
    a = abs(ns) / NS_PER_S
    sign = "-" if ns < 0 else "+"
    if a < 120:
        return f"{sign}{a:.1f} s"
    if a < 7200:
        return f"{sign}{a / 60:.1f} min"
    if a < 172_800:
        return f"{sign}{a / 3600:.1f} h"
    return f"{sign}{a / 86_400:.1f} days"


# -- 1. the receiver's ranges ------------------------------------------------------------------


def week_problem(week: int) -> str | None:
    """Why a GPS week (with a time) is out of range, or None."""
    if week < 1:
        return f"GPS week {week}"
    if week > MAX_WEEK:
        return f"GPS week {week} (after the year 2126)"
    return None


def tow_ms_problem(tow_ms: int) -> str | None:
    """Why a time of week in ms is out of range, or None."""
    if 0 <= tow_ms < WEEK_MS:
        return None
    return f"time of week {tow_ms} ms"


def tow_s_problem(tow_s: float) -> str | None:
    """Why a time of week in s (RXM-RAWX ``rcvTow``) is out of range or not finite, or None."""
    if 0.0 <= tow_s < WEEK_S:  # False for NaN
        return None
    return f"time of week {tow_s!r} s"


def sub_ms_problem(sub_ns: int) -> str | None:
    """Why a sub-millisecond part (ns) is out of range, or None."""
    if 0 <= sub_ns < MS_NS:
        return None
    return f"sub-millisecond part {sub_ns} ns"


def finite_sum(*values: float) -> bool:
    """Whether measurements are finite numbers: their sum minus itself is 0 (NaN and infinity
    give NaN; values so large that their sum overflows count as not finite too). The decoder
    inlines it; :func:`finite_rows` is the bulk form (the same sum in the same order, IEEE 754:
    the same bits)."""
    s = 0.0
    for v in values:
        s = s + v
    return s - s == 0.0


def host_bound_problem(t_gps_ns: int, host_ns: int) -> str | None:
    """Why a time lies too far after the host's clock (rule 2), or None (also when ``host_ns``
    is no clock reading: before :data:`HOST_TIME_MIN_NS`)."""
    if host_ns <= HOST_TIME_MIN_NS:
        return None
    lead = gps_to_unix_ns(t_gps_ns) - host_ns
    if lead <= HOST_CLOCK_SLACK_NS:
        return None
    return f"{span_text(lead)} after the host's clock"


# -- 3. the session's clock --------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ClockState:
    """The session's clock after a plausible epoch.

    Attributes:
        t_gps_ns: the epoch's GPS time.
        t_host_ns: its host reception time (None: the stream has no host times).
        jump_ns: the allowance without host time (:data:`JUMP_MIN_NS` or ten intervals).
    """

    t_gps_ns: int
    t_host_ns: int | None
    jump_ns: int


def allowance_ns(state: ClockState, t_host_ns: int | None) -> int:
    """How far from the clock a time received at ``t_host_ns`` may lie (rule 3): the host
    time elapsed since the clock's epoch plus the link's latency where both have host times
    (the receiver's time runs as the host's does), else the clock's ``jump_ns``."""
    if t_host_ns is not None and state.t_host_ns is not None:
        return max(t_host_ns - state.t_host_ns, 0) + LINK_LATENCY_NS
    return state.jump_ns


def jump_of(min_spacing_ns: int | None) -> int:
    """The allowance without host time for the shortest epoch spacing seen (None: none yet)."""
    if min_spacing_ns is None:
        return JUMP_MIN_NS
    return max(JUMP_MIN_NS, JUMP_INTERVALS * min_spacing_ns)


def time_problem(
    state: ClockState | None, t_gps_ns: int, t_host_ns: int | None, now_ns: int, *, new: bool
) -> str | None:
    """Why a mark's edge or a fix's time cannot belong to the session, or None.

    Args:
        state: the clock (None before the first plausible epoch: the host clock alone).
        t_gps_ns: the time.
        t_host_ns: when it was received (None: no host time).
        now_ns: the host's clock when there is no reception time (offline: now).
        new: a new edge or a fix (within the allowance either side), else a repeated edge (not
            after the clock's allowance).
    """
    if not 0 <= t_gps_ns < MAX_T_GPS_NS:
        return f"time {t_gps_ns} ns"
    if state is None:
        return host_bound_problem(t_gps_ns, t_host_ns if t_host_ns is not None else now_ns)
    d = t_gps_ns - state.t_gps_ns
    allow = allowance_ns(state, t_host_ns)
    if d > allow or (new and d < -allow):
        return f"{span_text(d)} from the session's clock"
    return None


def tow_problem(state: ClockState | None, tow_ns: int, t_host_ns: int | None) -> str | None:
    """Why a time of week without a week (NAV-PVT, NAV-SVINFO ...) cannot belong to the
    session, or None: it must lie within the allowance around the clock's time of week."""
    if state is None:
        return None
    half = NS_PER_WEEK // 2
    d = (tow_ns - state.t_gps_ns % NS_PER_WEEK + half) % NS_PER_WEEK - half
    if abs(d) > allowance_ns(state, t_host_ns):
        return f"time of week {span_text(d)} from the session's clock"
    return None


def fix_problem(
    state: ClockState | None, itow_ms: int, ftow_ns: int, week: int | None,
    t_host_ns: int | None, now_ns: int,
) -> str | None:
    """Why a fix or tracking message's time (NAV-SOL, NAV-PVT, NAV-POSLLH, NAV-SVINFO, NAV-SAT,
    NAV-TIMEGPS) cannot belong to the session, or None: ``iTOW`` (+ ``fTOW``) in range, and a
    full time (``week`` when the receiver says it is valid, else None) or a time of week near
    the clock."""
    why = tow_ms_problem(itow_ms)
    if why is None and not -FTOW_MAX_NS <= ftow_ns <= FTOW_MAX_NS:
        why = f"fTOW {ftow_ns} ns"
    if why is not None:
        return why
    tow_ns = itow_ms * 1_000_000 + ftow_ns
    if week is not None:
        return week_problem(week) or time_problem(
            state, week * NS_PER_WEEK + tow_ns, t_host_ns, now_ns, new=True)
    return tow_problem(state, tow_ns, t_host_ns)


def edge_range_problem(week: int, tow_ms: int, sub_ns: int) -> str | None:
    """Why one TIM-TM2 edge's fields are out of range, or None (all zero: never seen, fine)."""
    if week == 0 and tow_ms == 0 and sub_ns == 0:
        return None
    return week_problem(week) or tow_ms_problem(tow_ms) or sub_ms_problem(sub_ns)


def mark_problem(
    state: ClockState | None,
    edges: tuple[tuple[int | None, bool], tuple[int | None, bool]],
    t_host_ns: int | None,
    now_ns: int,
) -> str | None:
    """Why a time mark's edges (GPS ns or None, each with its "new" flag) cannot belong to the
    session, or None (rule 3: a new edge near the clock, a repeated one not after it)."""
    for t, new in edges:
        if t is not None:
            why = time_problem(state, t, t_host_ns, now_ns, new=new)
            if why is not None:
                return f"{'new' if new else 'repeated'} edge {why}"
    return None


@dataclass(frozen=True, slots=True)
class Jump:
    """The clock moved to a confirmed new time (rule 4)."""

    from_t_gps_ns: int | None
    """The clock before (None: the first epochs lay too far after the host's clock)."""
    to_t_gps_ns: int
    skipped_t_gps_ns: int
    """The first of the two agreeing epochs, not used."""


class SessionClock:
    """The rule in streaming form: one epoch, mark or fix at a time, in stream order.

    Args:
        now_ns: the host's clock for frames without a reception time (UNIX ns; default: now).
        host_times: frames carry host reception times (a live source, an MCAP recording);
            False for a stream timed from its own epochs (``.ubx`` through the daemon).
    """

    def __init__(self, now_ns: int | None = None, *, host_times: bool = True) -> None:
        self.now_ns = time.time_ns() if now_ns is None else now_ns
        self.host_times = host_times
        self.state: ClockState | None = None
        self._min_spacing: int | None = None
        self._candidate: tuple[int, int | None] | None = None
        self.jumps: list[Jump] = []

    def host(self, t_host_ns: int) -> int | None:
        """A frame's reception time as the rule uses it (None: not a host time)."""
        return t_host_ns if self.host_times and t_host_ns > HOST_TIME_MIN_NS else None

    def epoch(self, t_gps_ns: int, t_host_ns: int) -> str | None:
        """Judge a measurement epoch that passed the ranges (week >= 1); a plausible one moves
        the clock. Returns why it is not plausible, or None. A confirmed jump appends to
        :attr:`jumps` (and returns None)."""
        h = self.host(t_host_ns)
        st = self.state
        if st is None:
            why = host_bound_problem(t_gps_ns, h if h is not None else self.now_ns)
        else:
            d = t_gps_ns - st.t_gps_ns
            if -BACK_NS <= d <= allowance_ns(st, h):
                self._accept(t_gps_ns, h, d)
                return None
            why = f"{span_text(d)} from the session's clock"
        if why is None:  # the session's first epoch
            self._accept(t_gps_ns, h, None)
            return None
        return self._confirm(t_gps_ns, h, why)

    def _accept(self, t: int, h: int | None, spacing: int | None) -> None:
        if (spacing is not None and spacing > 0
                and (self._min_spacing is None or spacing < self._min_spacing)):
            self._min_spacing = spacing
        self.state = ClockState(t, h, jump_of(self._min_spacing))
        self._candidate = None

    def _confirm(self, t: int, h: int | None, why: str) -> str | None:
        cand = self._candidate
        if cand is not None:
            ct, ch = cand
            d = t - ct
            st = self.state
            allow = allowance_ns(ClockState(ct, ch, jump_of(self._min_spacing)), h)
            if st is not None:  # a slow receiver's next epoch comes as late as the first did
                allow = max(allow, ct - st.t_gps_ns)
            if 0 < d <= allow:
                self.jumps.append(Jump(st.t_gps_ns if st is not None else None, t, ct))
                self._min_spacing = None
                self._accept(t, h, d)
                return None
        self._candidate = (t, h)
        return why

    def time(self, t_gps_ns: int, t_host_ns: int, *, new: bool) -> str | None:
        """Judge a mark's edge or a fix's full time (:func:`time_problem`); the clock stays."""
        return time_problem(self.state, t_gps_ns, self.host(t_host_ns), self.now_ns, new=new)

    def tow(self, tow_ns: int, t_host_ns: int) -> str | None:
        """Judge a time of week without a week (:func:`tow_problem`); the clock stays."""
        return tow_problem(self.state, tow_ns, self.host(t_host_ns))

    def fix(self, itow_ms: int, ftow_ns: int, week: int | None, t_host_ns: int) -> str | None:
        """Judge a fix's time (:func:`fix_problem`); the clock stays."""
        return fix_problem(self.state, itow_ms, ftow_ns, week, self.host(t_host_ns), self.now_ns)

    def mark(
        self, edges: tuple[tuple[int | None, bool], tuple[int | None, bool]], t_host_ns: int
    ) -> str | None:
        """Judge a time mark's edges (:func:`mark_problem`); the clock stays."""
        return mark_problem(self.state, edges, self.host(t_host_ns), self.now_ns)


# -- the bulk form -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class EpochVerdicts:
    """The rule over a recording's measurement epochs in stream order (:func:`epoch_verdicts`).

    Attributes:
        ok: each epoch is plausible (week-0 epochs within the ranges included).
        reasons: why, for each epoch that is not (by position).
        clock_t: the clock's GPS time after each epoch (-1: no clock yet).
        clock_host: its host time (-1: none).
        jump_ns: its allowance without host time.
        jumps: the confirmed jumps (rule 4).
    """

    ok: BoolArray
    reasons: dict[int, str]
    clock_t: IntArray
    clock_host: IntArray
    jump_ns: IntArray
    jumps: tuple[Jump, ...]

    def state_after(self, k: int) -> ClockState | None:
        """The clock after epoch ``k`` (None: before the first plausible epoch, or k < 0)."""
        if k < 0 or self.clock_t[k] < 0:
            return None
        h = int(self.clock_host[k])
        return ClockState(int(self.clock_t[k]), h if h >= 0 else None, int(self.jump_ns[k]))


def epoch_verdicts(
    week: IntArray,
    tow_ns: IntArray,
    static_reasons: dict[int, str],
    t_host_ns: IntArray | None,
    now_ns: int,
    *,
    host_times: bool = True,
) -> EpochVerdicts:
    """The rule over epochs in stream order; the same verdicts as :class:`SessionClock`.

    Args:
        week: GPS week of each epoch.
        tow_ns: time of week of each epoch in ns (any value where a range failed).
        static_reasons: the epochs that failed the receiver's ranges (position -> why).
        t_host_ns: host reception time of each epoch (None, or values before
            :data:`HOST_TIME_MIN_NS`: none).
        now_ns: the host's clock for epochs without a reception time.
        host_times: as :class:`SessionClock`.
    """
    n = int(week.size)
    ok = np.ones(n, dtype=bool)
    for k in static_reasons:
        ok[k] = False
    timed = ok & (week != 0)
    idx = np.flatnonzero(timed)
    safe_week = np.where(timed, week, 0).astype(np.int64)
    t = safe_week * NS_PER_WEEK + np.where(timed, tow_ns, 0).astype(np.int64)
    host = None
    if host_times and t_host_ns is not None:
        host = np.where(t_host_ns > HOST_TIME_MIN_NS, t_host_ns, -1).astype(np.int64)
    clock_t = np.full(n, -1, dtype=np.int64)
    clock_host = np.full(n, -1, dtype=np.int64)
    jump = np.full(n, JUMP_MIN_NS, dtype=np.int64)
    reasons = dict(static_reasons)
    if idx.size == 0:
        return EpochVerdicts(ok, reasons, clock_t, clock_host, jump, ())
    tt = t[idx]
    diffs = np.diff(tt)
    h0 = int(host[idx[0]]) if host is not None else -1
    first_ok = host_bound_problem(int(tt[0]), h0 if h0 >= 0 else now_ns) is None
    limit = np.full(diffs.size, JUMP_MIN_NS, dtype=np.int64)
    if host is not None:
        hh = host[idx]
        both = (hh[1:] >= 0) & (hh[:-1] >= 0)
        limit = np.where(both, np.maximum(hh[1:] - hh[:-1], 0) + LINK_LATENCY_NS, limit)
    if first_ok and bool(np.all((diffs >= -BACK_NS) & (diffs <= limit))):
        # Every timed epoch follows the one before within its least allowance: the streaming
        # rule accepts each of them; the clock after an epoch is the latest timed epoch.
        pos = np.where(diffs > 0, diffs, np.iinfo(np.int64).max)
        run_min = np.minimum.accumulate(pos) if pos.size else pos
        jumps_t = np.full(idx.size, JUMP_MIN_NS, dtype=np.int64)
        if run_min.size:
            have = run_min < np.iinfo(np.int64).max
            jumps_t[1:] = np.where(
                have, np.maximum(JUMP_MIN_NS, JUMP_INTERVALS * np.where(have, run_min, 0)),
                JUMP_MIN_NS)
        # forward-fill: the state after each epoch is that of the last timed one at or before
        last = np.full(n, -1, dtype=np.int64)
        last[idx] = np.arange(idx.size)
        last = np.maximum.accumulate(last)
        have_clock = last >= 0
        src = np.where(have_clock, last, 0)
        clock_t = np.where(have_clock, tt[src], -1)
        if host is not None:
            clock_host = np.where(have_clock, host[idx][src], -1)
        jump = np.where(have_clock, jumps_t[src], JUMP_MIN_NS)
        return EpochVerdicts(ok, reasons, clock_t, clock_host, jump, ())
    clock = SessionClock(now_ns, host_times=host_times)
    cur = (-1, -1, JUMP_MIN_NS)
    timed_list = timed.tolist()
    t_list = t.tolist()
    host_list = host.tolist() if host is not None else None
    for k in range(n):
        if timed_list[k]:
            why = clock.epoch(t_list[k], host_list[k] if host_list is not None else 0)
            if why is not None:
                ok[k] = False
                reasons[k] = why
            st = clock.state
            if st is not None:
                cur = (st.t_gps_ns, st.t_host_ns if st.t_host_ns is not None else -1, st.jump_ns)
        clock_t[k], clock_host[k], jump[k] = cur
    return EpochVerdicts(ok, reasons, clock_t, clock_host, jump, tuple(clock.jumps))


def finite_rows(*columns: npt.NDArray[Any]) -> BoolArray:
    """:func:`finite_sum` of each row of measurement columns (the same sum, left to right)."""
    with np.errstate(invalid="ignore", over="ignore"):
        s = columns[0].astype(np.float64)
        for c in columns[1:]:
            s = s + c.astype(np.float64)
        return np.asarray((s - s) == 0.0)
