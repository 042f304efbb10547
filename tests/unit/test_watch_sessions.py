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


def test_a_finished_session_reads_finished_with_its_alerts_as_of_the_end() -> None:
    """The daemon said its session finished: watch says SESSION FINISHED at once (not LIVE),
    and the alerts standing then are titled as those at the end, with nothing to acknowledge;
    the next session is live again."""
    from rich.console import Console

    from groundstation.bus import encode
    from groundstation.view.watch import render

    def screen(w: WatchState, now_s: float) -> str:
        console = Console(record=True, width=100, color_system=None)
        console.print(render(w, now_s=now_s))
        return console.export_text()

    doc = jsonio.loads(drawable(1000.0))
    doc["alerts"] = ["2 time mark(s) missed this session; acknowledge to clear"]
    w = WatchState("st")
    w.on_payload("groundstation/st/status", jsonio.dumps(doc), now_s=0.0)
    live = screen(w, 0.1)
    assert " LIVE " in live and "press a to acknowledge" in live
    w.on_payload("groundstation/st/session",
                 encode("session", {"state": "finished", "session_id": doc["session_id"]}),
                 now_s=0.2)
    done = screen(w, 0.3)
    assert "SESSION FINISHED" in done and " LIVE " not in done
    assert "ALERTS at the end of the session" in done and "2 time mark(s) missed" in done
    assert "press a to acknowledge" not in done
    w.on_payload("groundstation/st/status",
                 drawable(1001.0, sid="st_20250602T100000Z"), now_s=1.0)
    assert " LIVE " in screen(w, 1.1)
