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
   sub-millisecond part in [0, 1 ms), a GPS week from 1024 (1999, :data:`MIN_WEEK`; week 0 is a
   receiver without time yet: such an epoch passes as a cold start but never sets the clock),
   measurements a
   receiver makes (finite, a pseudorange within 1e9 m, a phase within 1e10 cycles, a Doppler
   within 1 MHz: a receiver never sends NaN, infinity or 1e308), a stated GPS - UTC near the
   leap-second table's,
   and a time the records and the bus carry (before 2^62 ns, the year 2126:
   :data:`MAX_T_GPS_NS`).
2. **The host clock, where there is one**: the session's first time cannot lie after the host's
   clock (its reception time live, the computer's clock offline) by more than
   :data:`HOST_CLOCK_SLACK_NS` (more than any host clock is wrong by).
3. **The session's own clock**: the latest plausible epoch. The next epoch may follow it by the
   *allowance* (:func:`allowance_ns`): where the frames have host reception times, the host time
   elapsed since that epoch plus the link's latency (:data:`LINK_LATENCY_NS`: the receiver's
   time and the host's run at the same rate, whatever the host clock's offset); without them
   (a ``.ubx`` file), a minute or ten of the receiver's epoch intervals. It may precede it by
   :data:`BACK_NS` (a repeat, a receiver clock reset). An epoch that falls between the latest
   and the one before it shows the latest, which put the clock ahead, to be the odd one: the
   clock goes on from the one before it and readers that collect epochs leave the odd one out
   (:attr:`SessionClock.refuted`). A mark's new edge and a fix with a week
   lie within the allowance either side of the clock; a mark's repeated edge (the receiver
   repeats its last one, which may be hours old) not after it and within 1024 weeks before it;
   a fix with a time of week only, within the allowance around the clock's time of week. Before
   the session's first epoch, a mark or a fix lies within 1024 weeks of the host's clock.
4. **A jump is the receiver's new time only when an epoch confirms it**: two epochs in a row
   that follow each other as the receiver's epochs do (one interval apart, as far apart in host
   time) and not the clock (the receiver was off, the host clock was wrong, the first epoch was
   the false one) move the clock to them; the first of the two is counted as not used. A frame
   that passed its checksum by chance is not confirmed by the next epoch, nor by another chance
   frame of the same burst.

The session's first plausible epoch anchors the clock; the frames before it are judged by the
ranges and the host clock alone.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation.gpstime import (
    GPS_EPOCH_UNIX_S,
    NS_PER_S,
    NS_PER_WEEK,
    gps_to_unix_ns,
    leap_seconds_at_gps,
)
from groundstation.records import positional_constructor

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
MIN_WEEK = 1024
"""No receiver that speaks UBX reports an earlier GPS week: the broadcast week number has 10
bits, and every receiver built after its first rollover (1999-08-22, week 1024; the UBX protocol
is younger) puts it in an era that starts there or later (a receiver with the rollover bug
reports 1024 weeks too early, which is still after it)."""
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
PR_MAX_M = 1e9
"""No pseudorange is longer: the farthest GNSS satellites (geostationary) are 4.2e7 m away and a
receiver steers its clock within a millisecond (3e5 m); 1e9 m is 3.3 light-seconds."""
CP_MAX_CYC = 1e10
"""No carrier phase is larger: it starts near the range in cycles (~2e8) and grows at the
Doppler (< 10 kHz) while a satellite is tracked (a pass lasts hours: < 2e8 more); 1e10 is also
the largest value RINEX's F14.3 holds."""
DO_MAX_HZ = 1e6
"""No Doppler is larger: a GNSS satellite's is within ±6 kHz, an aircraft adds < 1 kHz."""
ODD_RUN_MAX = 8
"""At most this many epochs in a row, taken within the allowance, are found to be odd ones when
an epoch comes back behind them (a burst of chance frames each within a minute of the last)."""
LEAP_SLACK_S = 5
"""How far a receiver's GPS - UTC may differ from the leap-second table: leap seconds come at
most one a year, and the table may be a few years out of date."""
BACK_NS = NS_PER_S
"""How far an epoch may precede the clock: a repeat (RXM-RAW and RXM-RAWX both on) or a
receiver clock reset (RXM-RAWX ``clkReset``, a millisecond); never more on an ordered link."""

HOST_TIME_MIN_NS = GPS_EPOCH_UNIX_S * NS_PER_S
"""A reception time before the GPS epoch (1980-01-06) is no host clock reading (a stream's
chunks numbered from 0, a test's counter): such a frame is judged as one without a host time."""

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


def span_text(ns: int, signed: bool = True) -> str:
    """A time difference for a message: ``+1.2 s``, ``-3.0 h``, ``+6.2 days``, ``6.6 years``
    (``signed``: with its sign)."""
    a = abs(ns) / NS_PER_S
    sign = ("-" if ns < 0 else "+") if signed else ""
    if a < 120:
        return f"{sign}{a:.1f} s"
    if a < 7200:
        return f"{sign}{a / 60:.1f} min"
    if a < 172_800:
        return f"{sign}{a / 3600:.1f} h"
    if a < 2 * 365.25 * 86_400:
        return f"{sign}{a / 86_400:.1f} days"
    return f"{sign}{a / (365.25 * 86_400):.1f} years"


# -- 1. the receiver's ranges ------------------------------------------------------------------


def week_problem(week: int) -> str | None:
    """Why a GPS week (with a time) is out of range, or None."""
    if week < MIN_WEEK:
        return f"GPS week {week} (before 1999)" if week > 0 else f"GPS week {week}"
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


def measurement_ok(pr_m: float, cp_cyc: float, do_hz: float) -> bool:
    """Whether one satellite's pseudorange, carrier phase and Doppler are numbers a receiver
    measures: finite and within :data:`PR_MAX_M`, :data:`CP_MAX_CYC`, :data:`DO_MAX_HZ` (a NaN
    fails every comparison). The decoder inlines it; :func:`measurement_rows` is the bulk form
    (the same comparisons)."""
    return (-PR_MAX_M <= pr_m <= PR_MAX_M and -CP_MAX_CYC <= cp_cyc <= CP_MAX_CYC
            and -DO_MAX_HZ <= do_hz <= DO_MAX_HZ)


def leap_problem(leap_s: int, t_gps_ns: int) -> str | None:
    """Why a receiver's stated GPS - UTC (RXM-RAWX ``leapS`` with its valid flag) cannot be
    right at ``t_gps_ns``, or None: within :data:`LEAP_SLACK_S` of the leap-second table (a UTC
    time mark would otherwise be put on GPS time by a random number of seconds)."""
    known = leap_seconds_at_gps(t_gps_ns)
    if abs(leap_s - known) <= LEAP_SLACK_S:
        return None
    return f"GPS - UTC {leap_s} s where it is {known} s"


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
        state: the clock (None before the first plausible epoch: the host clock alone, within
            :data:`HOST_CLOCK_SLACK_NS` either side; an epoch, which can be confirmed, only
            not after it).
        t_gps_ns: the time.
        t_host_ns: when it was received (None: no host time).
        now_ns: the host's clock when there is no reception time (offline: now).
        new: a new edge or a fix (within the allowance either side), else a repeated edge (not
            after the clock's allowance, nor more than :data:`HOST_CLOCK_SLACK_NS` before it:
            the receiver repeats its last edge, which may be from before the session).
    """
    if not 0 <= t_gps_ns < MAX_T_GPS_NS:
        return f"time {t_gps_ns} ns"
    if state is None:  # before the session's first epoch: within the host clock's slack
        host = t_host_ns if t_host_ns is not None else now_ns
        off = gps_to_unix_ns(t_gps_ns) - host
        if host > HOST_TIME_MIN_NS and abs(off) > HOST_CLOCK_SLACK_NS:
            return f"{span_text(off)} from the host's clock"
        return None
    d = t_gps_ns - state.t_gps_ns
    allow = allowance_ns(state, t_host_ns)
    if d > allow or d < (-allow if new else -HOST_CLOCK_SLACK_NS):
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
    """Why a time mark's edges ((falling, new), (rising, new): GPS ns or None and the record's
    "new" flag) cannot belong to the session, or None (rule 3: a new edge near the clock, a
    repeated one not after it). A repeated edge may be old: a real receiver's record of a new
    rising edge repeated a falling edge 2.2 minutes old (rover-20181004-1532)."""
    (falling, new_falling), (rising, new_rising) = edges
    for t, new, name in ((falling, new_falling, "falling"), (rising, new_rising, "rising")):
        if t is not None:
            why = time_problem(state, t, t_host_ns, now_ns, new=new)
            if why is not None:
                return f"{name} edge {why}"
    return None


_clock_state = positional_constructor(ClockState)  # one per epoch: the fast form
_HALF_WEEK = NS_PER_WEEK // 2


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
            A frame's ``t_host_ns`` is its reception time when it is one (after
            :data:`HOST_TIME_MIN_NS`); a ``.ubx`` file's frames have none (0).
    """

    def __init__(self, now_ns: int | None = None) -> None:
        self.now_ns = time.time_ns() if now_ns is None else now_ns
        self.state: ClockState | None = None
        self._taken: deque[ClockState] = deque(maxlen=ODD_RUN_MAX + 1)  # latest last
        self._min_spacing: int | None = None
        self._jump_ns = JUMP_MIN_NS  # jump_of(self._min_spacing)
        self._candidate: tuple[int, int | None] | None = None
        self.jumps: list[Jump] = []
        self.refuted: list[int] = []
        """Times of epochs taken within the allowance that the next epoch showed to be the odd
        one (rule 3): a reader that collects the epochs leaves them out afterwards."""

    def host(self, t_host_ns: int) -> int | None:
        """A frame's reception time as the rule uses it (None: not a host time)."""
        return t_host_ns if t_host_ns > HOST_TIME_MIN_NS else None

    def epoch(self, t_gps_ns: int, t_host_ns: int) -> str | None:
        """Judge a measurement epoch that passed the ranges (a week of its own); a plausible
        one moves the clock. Returns why it is not plausible, or None. A confirmed jump appends to
        :attr:`jumps` (and returns None)."""
        h = t_host_ns if t_host_ns > HOST_TIME_MIN_NS else None  # host()
        st = self.state
        if st is None:
            why = host_bound_problem(t_gps_ns, h if h is not None else self.now_ns)
        else:
            d = t_gps_ns - st.t_gps_ns
            # the common case first, allowance_ns() inlined (an epoch per 0.2 s per receiver)
            sh = st.t_host_ns
            allow = (max(h - sh, 0) + LINK_LATENCY_NS if h is not None and sh is not None
                     else st.jump_ns)
            if 0 <= d <= allow:
                self._accept(t_gps_ns, h, d)
                return None
            if d < 0:
                back = self._follows_earlier(t_gps_ns, h)
                if back is not None:
                    # behind the latest epochs, after an earlier one: the latest, which put the
                    # clock ahead, were the odd ones; the clock goes on from that earlier one
                    for _ in range(back):
                        self.refuted.append(self._taken.pop().t_gps_ns)
                    self.state = self._taken[-1]
                    self._accept(t_gps_ns, h, t_gps_ns - self.state.t_gps_ns)
                    return None
            if -BACK_NS <= d < 0:  # a little behind the clock: a repeat, a clock reset
                self._accept(t_gps_ns, h, d)
                return None
            why = f"{span_text(d)} from the session's clock"
        if why is None:  # the session's first epoch
            self._accept(t_gps_ns, h, None)
            return None
        return self._confirm(t_gps_ns, h, why)

    def _follows_earlier(self, t: int, h: int | None) -> int | None:
        """How many of the latest epochs taken ``t`` shows to be odd ones: they began with a
        leap ahead of an earlier epoch (more than two intervals), and ``t``, behind them, follows
        that earlier one (within its allowance); None when there are none (an epoch behind a
        run of ordinary ones is the odd one itself)."""
        taken = self._taken
        if self._min_spacing is None:
            return None
        leap = 2 * self._min_spacing
        for back in range(1, len(taken)):
            earlier, first = taken[-1 - back], taken[-back]
            if (first.t_gps_ns - earlier.t_gps_ns > leap and earlier.t_gps_ns <= t
                    and t - earlier.t_gps_ns <= allowance_ns(earlier, h)):
                return back
        return None

    def _accept(self, t: int, h: int | None, spacing: int | None) -> None:
        if (spacing is not None and spacing > 0
                and (self._min_spacing is None or spacing < self._min_spacing)):
            self._min_spacing = spacing
            self._jump_ns = jump_of(spacing)
        elif self._min_spacing is None:
            self._jump_ns = JUMP_MIN_NS
        self.state = state = _clock_state(t, h, self._jump_ns)
        self._taken.append(state)
        self._candidate = None

    def _confirm(self, t: int, h: int | None, why: str) -> str | None:
        """Rule 4: ``t`` (refused) confirms the epoch refused just before it when it follows it
        as the receiver's next epoch would: by at least half an interval (in GPS time, and in
        host time where there is one), and by at most one interval more than the host time
        between them, or (no host times) by at most two intervals; with no interval known yet,
        by at most a second more than the host time, or as long as the first lay after the
        clock (a slow receiver's next epoch comes as late as the first did). Frames that passed
        their checksum by chance in one burst do not: they arrive together, and their times
        (0 and 1 ms, a minute and 61 s) are seldom one interval apart."""
        cand = self._candidate
        if cand is not None:
            ct, ch = cand
            d = t - ct
            st = self.state
            interval = self._min_spacing
            if h is not None and ch is not None:
                allow = max(h - ch, 0) + (interval if interval is not None else NS_PER_S)
            elif interval is not None:
                allow = 2 * interval
            else:
                allow = max(ct - st.t_gps_ns if st is not None else 0, NS_PER_S)
            least = interval // 2 if interval is not None else 1
            # with host times, the second must also arrive that much later: two chance frames
            # of one burst arrive together, whatever times they carry
            later = h is None or ch is None or h - ch >= least
            if least <= d <= allow and later:
                self.jumps.append(Jump(st.t_gps_ns if st is not None else None, t, ct))
                self._min_spacing = None
                self.state = None
                self._taken.clear()
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
        h = t_host_ns if t_host_ns > HOST_TIME_MIN_NS else None
        st = self.state
        if st is not None and 0 <= itow_ms < WEEK_MS and -FTOW_MAX_NS <= ftow_ns <= FTOW_MAX_NS:
            # the common case, inlined (a fix or two per epoch); anything else: the full rule
            sh = st.t_host_ns
            allow = (max(h - sh, 0) + LINK_LATENCY_NS if h is not None and sh is not None
                     else st.jump_ns)
            tow_ns = itow_ms * 1_000_000 + ftow_ns
            if week is None:
                d = (tow_ns - st.t_gps_ns % NS_PER_WEEK + _HALF_WEEK) % NS_PER_WEEK - _HALF_WEEK
            elif MIN_WEEK <= week <= MAX_WEEK:
                d = week * NS_PER_WEEK + tow_ns - st.t_gps_ns
            else:
                d = allow + 1
            if -allow <= d <= allow:
                return None
        return fix_problem(st, itow_ms, ftow_ns, week, h, self.now_ns)

    def mark(
        self, edges: tuple[tuple[int | None, bool], tuple[int | None, bool]], t_host_ns: int
    ) -> str | None:
        """Judge a time mark's edges (:func:`mark_problem`); the clock stays."""
        return mark_problem(self.state, edges, self.host(t_host_ns), self.now_ns)


# -- the bulk form -----------------------------------------------------------------------------


ODD_EPOCH = "the odd one: the next epoch follows the epoch before it"
"""Why an epoch taken within the allowance is refused afterwards (:attr:`SessionClock.refuted`)."""


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
) -> EpochVerdicts:
    """The rule over epochs in stream order; the same verdicts as :class:`SessionClock`.

    Args:
        week: GPS week of each epoch.
        tow_ns: time of week of each epoch in ns (any value where a range failed).
        static_reasons: the epochs that failed the receiver's ranges (position -> why).
        t_host_ns: host reception time of each epoch (None, or values before
            :data:`HOST_TIME_MIN_NS`: none).
        now_ns: the host's clock for epochs without a reception time.
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
    if t_host_ns is not None:
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
    if first_ok and bool(np.all((diffs >= 0) & (diffs <= limit))):
        # Every timed epoch follows the one before (or repeats it) within its least allowance:
        # the streaming rule accepts each of them; the clock after an epoch is the latest.
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
    clock = SessionClock(now_ns)
    cur = (-1, -1, JUMP_MIN_NS)
    t_list = t.tolist()
    timed_list = timed.tolist()
    host_list = host.tolist() if host is not None else None
    taken: deque[int] = deque(maxlen=ODD_RUN_MAX + 1)  # the epochs taken, latest last
    for k in range(n):
        if timed_list[k]:
            refuted = len(clock.refuted)
            jumps = len(clock.jumps)
            why = clock.epoch(t_list[k], host_list[k] if host_list is not None else 0)
            if why is not None:
                ok[k] = False
                reasons[k] = why
            else:
                for _ in range(len(clock.refuted) - refuted):
                    odd = taken.pop()
                    ok[odd] = False
                    reasons[odd] = ODD_EPOCH
                if len(clock.jumps) != jumps:
                    taken.clear()
                taken.append(k)
            st = clock.state
            if st is not None:
                cur = (st.t_gps_ns, st.t_host_ns if st.t_host_ns is not None else -1, st.jump_ns)
        clock_t[k], clock_host[k], jump[k] = cur
    return EpochVerdicts(ok, reasons, clock_t, clock_host, jump, tuple(clock.jumps))


def measurement_rows(
    pr_m: npt.NDArray[Any], cp_cyc: npt.NDArray[Any], do_hz: npt.NDArray[Any]
) -> BoolArray:
    """:func:`measurement_ok` of each row of measurement columns."""
    with np.errstate(invalid="ignore"):
        ok: BoolArray = ((np.abs(pr_m.astype(np.float64)) <= PR_MAX_M)
                         & (np.abs(cp_cyc.astype(np.float64)) <= CP_MAX_CYC)
                         & (np.abs(do_hz.astype(np.float64)) <= DO_MAX_HZ))
    return ok
