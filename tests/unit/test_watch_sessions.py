"""The terminal view across sessions: a new session (a restarted daemon, the next replay)
drops the previous session's time marks, keeps its own early ones, and counts its marks again
from index 0."""

from __future__ import annotations

from typing import Any

from test_dashboard import NS, T0, mark, status

from groundstation import jsonio
from groundstation.view.watch import WatchState


def drawable(last_s: float, **kw: Any) -> bytes:
    doc = jsonio.loads(status(last_s, **kw))
    doc["sats"] = [{"sv": "G05", "cno_dbhz": 44, "elev_deg": 40, "azim_deg": 120,
                    "state": "clean", "lock_s": 10.0, "clean_phase_s": 9.0, "slips": 0,
                    "half_cycle_unresolved": False}]
    doc["marks"].update(last_count=1, rate_per_min=1.0, last_pulse_width_ms=1.0)
    return jsonio.dumps(doc)


def test_a_new_session_drops_the_previous_marks() -> None:
    w = WatchState("st")
    w.on_payload("groundstation/st/status", drawable(1000.0), now_s=0.0)
    for i in range(3):
        w.on_payload("groundstation/st/timemark", mark(i, 990.0 + i), now_s=0.1)
    assert len(w.marks) == 3
    # a replay of an older recording: its first mark comes just before its first status
    w.on_payload("groundstation/st/timemark", mark(0, 20.5), now_s=1.0)
    w.on_payload("groundstation/st/timemark", mark(0, 20.5), now_s=1.0)  # and its catch-up
    assert len(w.marks) == 4  # index 0 again, at another time: the next session's
    older = "st_replay-20250602T100000Z-abcdef_20250601T080000Z"
    w.on_payload("groundstation/st/status", drawable(20.0, first_s=10.0, sid=older), now_s=1.1)
    assert len(w.marks) == 1  # the old session's three are gone, its own early one stays
    w.on_payload("groundstation/st/timemark", mark(1, 21.5), now_s=1.3)
    assert [m["falling_t_gps_ns"] for m in w.marks] == [T0 + 20_500_000_000,
                                                        T0 + 21_500_000_000]
    # the same session again: nothing dropped
    w.on_payload("groundstation/st/status", drawable(22.0, first_s=10.0, sid=older), now_s=2.0)
    assert len(w.marks) == 2 and w.marks[-1]["falling_t_gps_ns"] == T0 + 21 * NS + NS // 2
