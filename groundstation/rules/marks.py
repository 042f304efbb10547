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
            if op is not None and op[1].falling_t_gps_ns is not None and (
                rising >= op[1].falling_t_gps_ns
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
