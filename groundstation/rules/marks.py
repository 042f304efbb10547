"""Camera time marks: pulses from TIM-TM2 records, their numbering, duplicates, lost marks, and
the instant (edge and shutter delay) that stands for the exposure.

A TIM-TM2 record repeats the latest falling and rising edge times; the ``new_falling`` and
``new_rising`` flags say which of them are new. A *mark* is one new falling edge, paired with
the first new rising edge after it (and before the next falling edge); a rising edge with no
falling edge before it (the receiver was connected mid-pulse, or the falling record was lost)
makes a mark of its own, with the falling time the record repeats when that one is new.

:class:`MarkTracker` is the rule in streaming form (the monitor); :func:`build_marks` runs it over
a whole recording (RINEX, inspect, the solver), so live and offline counts cannot differ.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

from groundstation.records import TimeMark

MarkEdge = Literal["falling", "rising", "both", "mid"]
MARK_EDGES: tuple[MarkEdge, ...] = ("falling", "rising", "both", "mid")

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
        number: the pulse's number in the receiver's count (:func:`mark_number`: ``count`` of
            its falling-edge record, whichever record made the mark); it names the mark
            (``mark_0000``) and is the ``mark_count`` of the exports; -1 when not made by the
            rule.
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
    number: int = -1

    @property
    def pulse_ns(self) -> int | None:
        if self.falling_t_gps_ns is None or self.rising_t_gps_ns is None:
            return None
        return self.rising_t_gps_ns - self.falling_t_gps_ns


def mark_number(record: TimeMark) -> int:
    """The pulse's number in the receiver's own count: the rising edges it had counted when the
    pulse's falling edge came, i.e. ``count`` of the falling-edge record (what u-center and
    RTKLIB's event list show: the first pulse after power-up is 0). A record that carries the
    pulse's rising edge has counted it already: ``count - 1`` there, so a pulse whose
    falling-edge record was lost, or whose two edges came in one record, has the same number."""
    return (record.count - 1) & 0xFFFF if record.new_rising else record.count


def count_jump(mark: Mark) -> tuple[int, int] | None:
    """``(last number before, this number)`` of the jump in the receiver's count before a mark
    that follows missed ones (``lost_before`` > 0), else None: "count 29 -> 31" is one missed
    mark, number 30."""
    if not mark.lost_before or mark.number < 0:
        return None
    return (mark.number - mark.lost_before - 1) & 0xFFFF, mark.number


LOST_ON_LINK = "link"
"""Pulses the receiver counted whose TIM-TM2 records never arrived: the count jumped across a
hole in the received epochs or a stretch of damaged data."""
LOST_IN_RECEIVER = "receiver"
"""Pulses the receiver counted but did not report although the link delivered everything: the
count jumped with no hole and no damage around it (two pulses within one measurement period,
of which a TIM-TM2 carries only the latest, or a record the receiver did not send)."""
LOST_CAUSE_TEXT = {
    LOST_ON_LINK: ("lost on the radio link (the receiver counted them; their TIM-TM2 messages "
                   "fell into link dropouts or damaged data): check the radio link, or log the "
                   "receiver on board"),
    LOST_IN_RECEIVER: ("not reported by the receiver (its count jumped with no link loss "
                       "around: two pulses within one measurement period, of which only the "
                       "latest is reported): check the camera's trigger interval against the "
                       "receiver's measurement rate"),
}
"""What each cause means and what to do, for every place that names it."""
NOT_COUNTED_TEXT = ("not counted by the receiver (photos with no mark and no jump in the "
                    "count): check the camera's trigger wiring to the receiver's EXTINT pin")


def lost_cause(
    lost_t_ns: int, holes: Sequence[tuple[int, int]], damage: Sequence[tuple[int, int]],
    interval_ns: int | None,
) -> str:
    """Why a pulse the receiver counted never arrived (:data:`LOST_ON_LINK` or
    :data:`LOST_IN_RECEIVER`): the one rule of the monitor, inspect and the solver.

    A pulse's TIM-TM2 is output with the first measurement epoch after it, after that epoch's
    measurements. It was lost on the link when that epoch is missing from the received ones
    (it lies inside a hole), or damaged bytes came after the epoch before it or after it (a
    dropout that began inside the epoch's burst cuts a frame). An epoch that arrived whole,
    even the last one before a hole, brought its TIM-TM2 too: a dropout that begins after the
    measurements mostly begins after the burst. Otherwise the receiver did not report it.

    Args:
        lost_t_ns: the lost pulse's time, as well as it is known (a photo's time through the
            camera clock, else spread evenly between the received marks around it).
        holes: ``(last epoch before, first epoch after)`` of every hole in the received epochs
            (``first after`` far in the future for a hole still open).
        damage: for every stretch of damaged data, the epochs it lies between, as well as
            they are known (a file: the epoch before it, twice; the monitor: the epochs when
            the counters last showed none and showed it).
        interval_ns: the measurement interval.
    """
    iv = interval_ns or 0
    e = -(-lost_t_ns // iv) * iv if iv else lost_t_ns  # the epoch its record comes with
    if any(a < e < b for a, b in holes):
        return LOST_ON_LINK
    if any(d0 <= e and d1 >= e - iv for d0, d1 in damage):  # after the epoch before, or it
        return LOST_ON_LINK
    return LOST_IN_RECEIVER


def lost_times(before_t_ns: int | None, after_t_ns: int | None, n: int,
               known_t_ns: Sequence[int] = ()) -> list[int]:
    """The times of ``n`` pulses lost between two received marks: ``known_t_ns`` when it holds
    exactly ``n`` (photos timed by the camera clock), else spread evenly between the two."""
    if len(known_t_ns) == n:
        return sorted(known_t_ns)
    if before_t_ns is None or after_t_ns is None:
        return [t for t in (before_t_ns, after_t_ns) if t is not None]
    step = (after_t_ns - before_t_ns) / (n + 1)
    return [round(before_t_ns + k * step) for k in range(1, n + 1)]


def lost_by_cause(
    marks: Sequence[Mark], holes: Sequence[tuple[int, int]], damage: Sequence[tuple[int, int]],
    interval_ns: int | None, known_t_ns: Sequence[int] = (),
) -> dict[str, list[int]]:
    """The numbers of the pulses lost in the count jumps (:func:`count_jump`) of a recording's
    marks, by :func:`lost_cause`; ``known_t_ns``: times of pulses known otherwise (photos
    without a mark, timed by the camera clock)."""
    out: dict[str, list[int]] = {LOST_ON_LINK: [], LOST_IN_RECEIVER: []}
    prev: Mark | None = None
    for m in marks:
        jump = count_jump(m)
        if jump is not None:
            a, b = (_edge(prev) if prev is not None else None), _edge(m)
            known = [t for t in known_t_ns
                     if (a is None or t > a) and (b is None or t < b)]
            n = jump_size(jump)
            times = lost_times(a, b, n, known)
            for k, t in enumerate(times[:n]):
                out[lost_cause(t, holes, damage, interval_ns)].append(
                    (jump[0] + 1 + k) & 0xFFFF)
        prev = m
    return out


def numbers_text(numbers: Sequence[int], most: int = 40) -> str:
    """``12, 30-33, 41`` (runs joined; at most ``most`` items, then how many more; -1 stands
    for a mark whose number no count jump tells)."""
    unknown = sum(1 for n in numbers if n < 0)
    runs: list[list[int]] = []
    for n in (n for n in numbers if n >= 0):
        if runs and n == runs[-1][-1] + 1:
            runs[-1].append(n)
        else:
            runs.append([n])
    items = [f"{r[0]}" if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in runs]
    more = f" and {len(items) - most} more" if len(items) > most else ""
    tail = (f"{' and ' if items else ''}{unknown} outside the received marks' numbers"
            if unknown else "")
    return ", ".join(items[:most]) + more + tail


def jump_size(jump: tuple[int, int]) -> int:
    """Pulses lost in a jump ``(last number before, this number)``."""
    return ((jump[1] - jump[0]) & 0xFFFF) - 1


def _edge(m: Mark) -> int | None:
    return m.falling_t_gps_ns if m.falling_t_gps_ns is not None else m.rising_t_gps_ns


@dataclass(frozen=True, slots=True)
class MarkUpdate:
    """What one TIM-TM2 record changed.

    Attributes:
        new: marks it started, in order (each numbered by :attr:`MarkTracker.marks` order).
        completed: (index, mark) of an open mark its rising edge completed.
        duplicate: it reported an already seen falling edge as new (the same exposure again).
        recovered: it started a mark from a repeated falling edge whose own record was lost.
    """

    new: tuple[Mark, ...] = ()
    completed: tuple[int, Mark] | None = None
    duplicate: bool = False
    recovered: bool = False


SEEN_EDGES_KEPT = 1 << 16
"""Edges remembered to recognise repeats: hours of marks at several per second. A receiver
repeats only its latest edges, so forgetting the oldest changes nothing but the memory a
station running for days needs."""


class _SeenEdges:
    """A set of edge times that forgets the oldest beyond :data:`SEEN_EDGES_KEPT`."""

    def __init__(self) -> None:
        self._set: set[int] = set()
        self._order: deque[int] = deque()

    def __contains__(self, t: int) -> bool:
        return t in self._set

    def add(self, t: int) -> None:
        self._set.add(t)
        self._order.append(t)
        if len(self._order) > SEEN_EDGES_KEPT:
            self._set.discard(self._order.popleft())


class MarkTracker:
    """The marks rule, one TIM-TM2 record at a time, in stream order.

    Repeated records (the same edge reported again) add nothing. A pulse whose falling-edge
    record was lost keeps its falling edge, which the rising-edge record repeats. A jump in the
    pulses' numbers (:func:`mark_number`) is recorded as ``lost_before`` on the next mark: those
    pulses were counted by the receiver but none of their records arrived.

    Attributes:
        marks: marks started so far (received pulses).
        missed: pulses lost before the marks, from the count jumps.
        duplicates: records that reported a seen falling edge as new.
    """

    def __init__(self) -> None:
        self.marks = 0
        self.missed = 0
        self.duplicates = 0
        self._seen_falling = _SeenEdges()
        self._seen_rising = _SeenEdges()
        self._open: tuple[int, Mark] | None = None  # a mark whose rising edge has not come yet
        self._last_number: int | None = None

    def _lost_before(self, r: TimeMark) -> int:
        number = mark_number(r)
        step = 1 if self._last_number is None else (number - self._last_number) & 0xFFFF
        self._last_number = number
        lost = step - 1 if 1 < step < 0x8000 else 0
        self.missed += lost
        return lost

    def _start(self, r: TimeMark, f: int | None, ri: int | None) -> tuple[int, Mark]:
        m = _make(r, f, ri, self._lost_before(r))
        self.marks += 1
        return self.marks - 1, m

    def feed(self, r: TimeMark) -> MarkUpdate:
        """Take one record; return what it changed."""
        new: list[Mark] = []
        completed: tuple[int, Mark] | None = None
        duplicate = recovered = False
        falling = r.falling_t_gps_ns
        rising = r.rising_t_gps_ns
        if r.new_falling and falling is not None:
            if falling in self._seen_falling:
                duplicate = True
                self.duplicates += 1
            else:
                self._seen_falling.add(falling)
                self._open = self._start(r, falling, None)
                new.append(self._open[1])
        if r.new_rising and rising is not None and rising not in self._seen_rising:
            self._seen_rising.add(rising)
            op = self._open
            # The rising edge of the open mark's own pulse: after its falling edge, and
            # counted with it (a record of a later pulse, whose falling-edge record and the
            # open pulse's rising-edge record were lost on the link, is a pulse of its own).
            if op is not None and op[1].falling_t_gps_ns is not None and (
                rising >= op[1].falling_t_gps_ns and mark_number(r) == op[1].number
            ):
                m = op[1]
                done = _make(r, m.falling_t_gps_ns, rising, m.lost_before)
                if new:
                    new[-1] = done  # started and completed by the same record
                else:
                    completed = (op[0], done)
            else:
                # Its falling-edge record never arrived: the rising-edge record repeats it.
                f = falling if falling is not None and falling not in self._seen_falling and (
                    falling <= rising) else None
                if f is not None:
                    self._seen_falling.add(f)
                    recovered = True
                new.append(self._start(r, f, rising)[1])
            self._open = None
        return MarkUpdate(tuple(new), completed, duplicate, recovered)


def _make(r: TimeMark, f: int | None, ri: int | None, lost: int) -> Mark:
    return Mark(f, ri, r.count, r.channel, r.flags, r.time_base, r.valid, r.utc_valid, r.acc_ns,
                lost, mark_number(r))


def track_marks(records: Iterable[TimeMark]) -> tuple[list[Mark], MarkTracker]:
    """Marks (one per pulse) from TIM-TM2 records in stream order, and the tracker's counts."""
    marks: list[Mark] = []
    tracker = MarkTracker()
    for r in records:
        up = tracker.feed(r)
        if up.completed is not None:
            marks[up.completed[0]] = up.completed[1]
        marks.extend(up.new)
    return marks, tracker


def build_marks(records: Iterable[TimeMark]) -> list[Mark]:
    """Marks (one per pulse) from TIM-TM2 records in stream order (:class:`MarkTracker`)."""
    return track_marks(records)[0]


def edge_time_ns(
    falling_t_gps_ns: int | None,
    rising_t_gps_ns: int | None,
    edge: MarkEdge,
    shutter_delay_ns: int = 0,
) -> int | None:
    """The instant a pulse stands for: the chosen edge (``mid``: halfway; ``both``: the falling
    edge) plus the shutter delay; None when the pulse lacks what the choice needs."""
    f, r = falling_t_gps_ns, rising_t_gps_ns
    if edge in ("falling", "both"):
        t = f
    elif edge == "rising":
        t = r
    elif edge == "mid":
        t = (f + r) // 2 if f is not None and r is not None else None
    else:
        raise ValueError(f"unknown mark edge {edge!r} ({', '.join(MARK_EDGES)})")
    return None if t is None else t + shutter_delay_ns


def mark_time_ns(mark: Mark, edge: MarkEdge, shutter_delay_ns: int = 0) -> int | None:
    """The time a mark stands for under an edge choice (:func:`edge_time_ns`)."""
    return edge_time_ns(mark.falling_t_gps_ns, mark.rising_t_gps_ns, edge, shutter_delay_ns)


def event_times_ns(marks: Sequence[Mark], edge: MarkEdge, shutter_delay_ns: int = 0) -> list[int]:
    """GPS ns of the event epochs to write, sorted: the chosen edge(s) plus the shutter delay.

    ``both`` gives one event per edge; marks lacking the chosen edge make no event.
    """
    out: list[int] = []
    for m in marks:
        if edge == "both":
            out.extend(t + shutter_delay_ns
                       for t in (m.falling_t_gps_ns, m.rising_t_gps_ns) if t is not None)
        else:
            t = mark_time_ns(m, edge, shutter_delay_ns)
            if t is not None:
                out.append(t)
    return sorted(out)


def record_time_ns(record: TimeMark) -> int | None:
    """The instant one TIM-TM2 record stands for on its own (before pairing into marks): the
    edge it reports as new, the falling one first; else the falling edge it repeats."""
    t = record.falling_t_gps_ns if record.new_falling else record.rising_t_gps_ns
    return t if t is not None else record.falling_t_gps_ns
