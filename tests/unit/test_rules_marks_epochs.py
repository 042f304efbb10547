"""The marks and epochs rules on hand-made sequences: pairing, numbering, duplicates, recovered
and lost marks, the edge choice; the interval, dropouts and where a mark lies."""

from __future__ import annotations

import pytest

from groundstation.records import TimeMark
from groundstation.rules import epochs, marks

S = 1_000_000_000


def rec(count: int, falling: int | None, rising: int | None, new_f: bool, new_r: bool) -> TimeMark:
    return TimeMark(0, count, rising, falling, new_r, new_f, 1, True, 10, 0)


def test_tracker_pairs_numbers_and_counts() -> None:
    records = [
        rec(0, 10 * S, None, True, False),  # mark 1 falls
        rec(1, 10 * S, 10 * S + 15_000_000, False, True),  # ... and rises
        rec(1, 10 * S, 10 * S + 15_000_000, True, False),  # the same exposure again: duplicate
        rec(1, 11 * S, 10 * S + 15_000_000, True, False),  # mark 2 falls
        rec(2, 11 * S, 11 * S + 15_000_000, False, True),  # ... and rises
        # marks 3 and 4 lost entirely; mark 5 arrives by its rising record only (recovered)
        rec(5, 14 * S, 14 * S + 15_000_000, False, True),
        rec(6, 15 * S, 15 * S + 15_000_000, True, True),  # mark 6: both edges in one record
    ]
    got, tracker = marks.track_marks(records)
    assert [(m.falling_t_gps_ns, m.pulse_ns) for m in got] == [
        (k * S, 15_000_000) for k in (10, 11, 14, 15)]
    assert [m.lost_before for m in got] == [0, 0, 2, 0]
    assert (tracker.marks, tracker.missed, tracker.duplicates) == (4, 2, 1)
    # The streaming updates say the same, record by record.
    t = marks.MarkTracker()
    ups = [t.feed(r) for r in records]
    assert [len(u.new) for u in ups] == [1, 0, 0, 1, 0, 1, 1]
    assert [u.completed[0] if u.completed else None for u in ups] == [
        None, 0, None, None, 1, None, None]
    assert [u.duplicate for u in ups] == [False, False, True, False, False, False, False]
    assert [u.recovered for u in ups] == [False, False, False, False, False, True, False]


def _pulse_records(n: int, rising_first: bool) -> list[TimeMark]:
    """The two TIM-TM2 records of pulse ``n`` (count = rising edges so far): a camera whose
    contact falls first (falling at 2n s, rising 15 ms later), or one whose pulse rises first
    (rising at 2n s, falling 1 s later, as in the jdesbonnet recordings)."""
    if rising_first:
        r, f, f_before = 2 * n * S, 2 * n * S + S, 2 * (n - 1) * S + S
        return [rec(n, f_before, r, False, True), rec(n, f, r, True, False)]
    f, r, r_before = 2 * n * S, 2 * n * S + 15_000_000, 2 * (n - 1) * S + 15_000_000
    return [rec(n, f, r_before, True, False), rec(n + 1, f, r, False, True)]


@pytest.mark.parametrize("rising_first", [False, True])
def test_a_later_pulses_rising_record_does_not_complete_an_earlier_mark(
        rising_first: bool) -> None:
    """The records between pulse 3's falling-edge record and pulse 5's rising-edge record were
    lost on the link (pulse 3's rising edge, pulse 4's falling edge). Pulse 5's rising-edge
    record must not complete pulse 3's mark: that named pulse 3's position mark 4 and lost
    pulse 4, whose falling edge the record repeats (seen on the 2018-10-09 flight replayed
    through the seed link: 3-13 photos per flight matched to the pulse before theirs)."""
    records = [r for n in range(1, 7) for r in _pulse_records(n, rising_first)]
    # rising first: pulse 4's two records lost (pulse 3's falling record arrived);
    # falling first: pulse 3's rising record and pulse 4's falling record lost
    lost = records[6:8] if rising_first else records[5:7]
    got, tracker = marks.track_marks([r for r in records if r not in lost])
    fall = {m.number: m.falling_t_gps_ns for m in got}
    # (a rising-first stream's first record repeats the falling edge of the pulse before)
    assert [m.number for m in got] == list(range(0 if rising_first else 1, 7))
    for n in range(1, 7):  # each pulse under its own number, at its own falling edge
        assert fall[n] == (2 * n * S + S if rising_first else 2 * n * S)
    assert tracker.missed == 0


@pytest.mark.parametrize(("edge", "want"), [
    ("falling", 10 * S + 5), ("both", 10 * S + 5), ("rising", 10 * S + 20 + 5),
    ("mid", 10 * S + 10 + 5),
])
def test_edge_choice(edge: marks.MarkEdge, want: int) -> None:
    assert marks.edge_time_ns(10 * S, 10 * S + 20, edge, 5) == want
    assert marks.edge_time_ns(None, 10 * S, "mid") is None
    with pytest.raises(ValueError, match="unknown mark edge"):
        marks.edge_time_ns(1, 2, "middle")  # type: ignore[arg-type]


def test_record_time_is_its_new_edge() -> None:
    assert marks.record_time_ns(rec(0, 5, 9, False, True)) == 9
    assert marks.record_time_ns(rec(0, 5, 9, True, True)) == 5
    assert marks.record_time_ns(rec(0, 5, None, False, True)) == 5


def test_interval_gaps_and_locate() -> None:
    ms = 1_000_000
    t = [0, 200 * ms, 400 * ms + 3, 1000 * ms, 1200 * ms, 1400 * ms, 1800 * ms]
    iv = epochs.nominal_interval_ns(t)
    assert iv == 200 * ms
    gaps = epochs.find_gaps(t, iv)
    got = [(g.after_t_gps_ns, g.missing_epochs) for g in gaps]
    assert got == [(400 * ms + 3, 2), (1400 * ms, 1)]
    assert not epochs.is_dropout(300 * ms, iv) and epochs.is_dropout(300 * ms + 1, iv)
    assert epochs.locate(700 * ms, t, iv).in_dropout
    assert not epochs.locate(1100 * ms, t, iv).in_dropout
    assert epochs.locate(-1, t, iv).outside and epochs.locate(1800 * ms, t, iv).gap_ns == 0
    assert epochs.interval_from_spacings([]) is None
    assert epochs.interval_from_spacings([200 * ms, 400 * ms]) == 200 * ms  # a tie: the shorter
