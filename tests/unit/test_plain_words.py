"""The lines a surveyor reads say what they mean, not the u-blox message that carried it:
"48 mark messages here", "time-mark records", "GLONASS satellites the receiver had not identified
yet" rather than "TIM-TM2 records here" or "no slot number". Message names stay in the
``inspect`` table of messages (that is what it lists), debug logs and the docs.

Read from the real renderers: the terminal view of a status with marks, ``inspect`` of a
generated stream (tests/streams.py) with marks, without marks and with unidentified GLONASS
satellites.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

from rich.console import Console
from streams import flight_stream
from test_dashboard import mark
from test_watch_sessions import drawable

from groundstation.commands.inspect import format_summary
from groundstation.offline.inspect import TimeMarkSummary, inspect_path
from groundstation.view.watch import WatchState, render

MESSAGE_NAME = re.compile(r"\b(TIM-TM2|RXM-\w+|NAV-\w+|AID-\w+|SFRBX?|TM2)\b|slot number")


def _watch_text() -> str:
    w = WatchState("st")
    w.on_payload("groundstation/st/status", drawable(1000.0), now_s=0.0)
    for i in range(3):
        w.on_payload("groundstation/st/timemark", mark(i, 990.0 + i), now_s=0.1)
    console = Console(width=100, record=True, force_terminal=False)
    console.print(render(w, now_s=0.2))
    return console.export_text()


def test_the_terminal_view_counts_marks_in_plain_words() -> None:
    text = _watch_text()
    assert "(3 mark messages here)" in text
    assert not MESSAGE_NAME.search(text), MESSAGE_NAME.search(text)


def _outside_the_message_table(text: str) -> str:
    """``inspect``'s lines but its table of messages by name (indented under ``messages``)."""
    out, in_table = [], False
    for line in text.splitlines():
        if line == "messages":
            in_table = True
            continue
        if in_table and line.startswith("  "):
            continue
        in_table = False
        out.append(line)
    return "\n".join(out)


def test_inspect_says_marks_and_glonass_in_plain_words(tmp_path: Path) -> None:
    data, _ = flight_stream(100)
    (tmp_path / "flight.ubx").write_bytes(data)
    s = inspect_path(tmp_path / "flight.ubx")
    assert s.timemarks.records > 0
    variants = [s, replace(s, timemarks=TimeMarkSummary()), replace(s, unknown_slot_signals=7)]
    texts = [_outside_the_message_table(format_summary(v)) for v in variants]
    assert f"marks     {s.timemarks.records} time-mark records:" in texts[0]
    assert "no camera marks in this recording" in texts[1]
    assert "7 measurements of GLONASS satellites the receiver had not identified yet" in texts[2]
    for text in texts:
        assert not MESSAGE_NAME.search(text), (MESSAGE_NAME.search(text), text)
    assert "TIM-TM2" in format_summary(s)  # the table of messages still names them
