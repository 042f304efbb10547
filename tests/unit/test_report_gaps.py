"""The report's words for the radio gaps across which the whole-arc solution split arcs."""

from __future__ import annotations

from groundstation.solve.report import _gap_splits, _judged_again


def test_no_split_says_the_continuity_was_checked() -> None:
    assert _gap_splits({}) == "every arc's continuity across the radio gaps checked"
    assert _gap_splits({"steps_found": 0, "steps_could_hide": 0}) == _gap_splits({})


def test_splits_are_counted_by_why() -> None:
    words = _gap_splits({"steps_found": 1, "steps_could_hide": 3,
                         "arcs_split_where_steps_could_hide": 5})
    assert words.startswith("arcs split at 4 radio gap(s)")
    assert "1 with a step of several satellites at once: every arc split there" in words
    assert "3 where such a step could have passed unseen: 5 arc(s)" in words
    only = _gap_splits({"steps_found": 0, "steps_could_hide": 2})
    assert "with a step" not in only and "2 where such a step" in only


def test_gaps_judged_again_are_said_with_why() -> None:
    assert _judged_again({}) == "" and _judged_again({"gap_judgements": 1}) == ""
    words = _judged_again({"gap_judgements": 2, "contradictions": 0})
    assert "checked 2 times" in words and "did not all fit" in words and "left" not in words
    assert "(3 misfit(s) left after the last)" in _judged_again({"gap_judgements": 3,
                                                                "contradictions": 3})
