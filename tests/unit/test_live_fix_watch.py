"""The operator's alert for the live position, its line in ``watch`` and its message's checks.

``FixWatch``: no alert while marks do not come in, however long the fix is lost; raised once
the fix has been lost for 10 s with a mark in the last 10 s; cleared (with how long it was
lost) at the next fix. ``rtk_line``: quality, fixed share, ratio, satellites, base age, sigma,
why there is none, the alert. ``messages.check``: the ``rtk`` fields in range, the rest refused.
"""

from __future__ import annotations

import dataclasses

import pytest

from groundstation import events, messages
from groundstation.live.rtk import FIX_LOST_ALERT_S, FixWatch
from groundstation.records import LiveSolution
from groundstation.view.watch import rtk_line

S = 1_000_000_000


def _sol(t_s: float, quality: str) -> LiveSolution:
    fixed = quality != "none"
    return LiveSolution(int(t_s * S), quality, 5.0 if fixed else 0.0, 8, 0.2,
                        (4146349.0, 612312.0, 4791750.0) if fixed else None,
                        (0.01, 0.01, 0.02) if fixed else None,
                        "" if fixed else "no base epoch yet")


def test_the_alert_needs_a_lost_fix_and_marks() -> None:
    w = FixWatch()
    assert w.update(_sol(0, "fix")) is None
    for t in range(1, 40):  # 39 s of float, no mark: nothing to say
        assert w.update(_sol(t, "float")) is None
    w.mark(40 * S)
    raised = w.update(_sol(40.2, "float"))
    assert raised is not None and raised[0] == events.RTK_FIX_LOST
    assert raised[1] == {"since_t_gps_ns": 0, "lost_s": 40.2}
    assert w.update(_sol(41, "float")) is None  # once
    cleared = w.update(_sol(45, "fix"))
    assert cleared == (events.RTK_FIX_REGAINED, {"lost_s": 45.0})


def test_raised_at_the_threshold_while_photos_are_taken() -> None:
    w = FixWatch()
    w.update(_sol(100, "fix"))
    out = []
    for k in range(1, 80):
        t = 100 + k * 0.2
        if k % 10 == 0:
            w.mark(int(t * S))
        out.append((t, w.update(_sol(t, "float"))))
    first = next(t for t, r in out if r is not None)
    assert first == pytest.approx(100 + FIX_LOST_ALERT_S)


def test_the_line_in_watch() -> None:
    fixed = _sol(1, "fix").message()
    line = rtk_line(fixed, ["fix"] * 240 + ["float"] * 60).plain
    assert "fix" in line and "fixed 80% of the last 60 s" in line
    assert "ratio 5.0  sats 8  base age 0.2 s  σ e/n/u 1.0/1.0/2.0 cm" in line
    none = rtk_line(_sol(1, "none").message(), []).plain
    assert "(no base epoch yet)" in none
    lost = rtk_line({**_sol(2, "float").message(), "alert": "fix_lost"}, ["float"]).plain
    assert "FIX LOST while photos are taken" in lost
    held = rtk_line({**fixed, "ratio": 999.9}, ["fix"]).plain
    assert "ambiguities held  sats 8" in held  # fix-and-hold's 999.9, said in words
    untried = rtk_line({**_sol(3, "float").message(), "ratio": 0.0}, ["float"]).plain
    assert "ratio" not in untried and "  sats 8" in untried  # no "ratio 0.0" on a float


def test_the_message_is_checked() -> None:
    good = {"type": "rtk", "station": "demo", **_sol(1, "fix").message()}
    assert messages.check(good, "rtk") == good
    cases: list[tuple[dict[str, object], str]] = [
        ({"quality": "great"}, "quality"), ({"sats": -1}, "sats"), ({"ecef_m": [1, 2]}, "ecef_m"),
        ({"t_gps_ns": 1.5}, "t_gps_ns"), ({"ratio": float("nan")}, "ratio"), ({"why": 5}, "why")]
    for bad, said in cases:
        with pytest.raises(messages.BadMessage, match=said):
            messages.check({**good, **bad}, "rtk")


def test_the_dashboard_draws_the_live_track_and_the_marks_on_it() -> None:
    """The dashboard's live panel: the latest message, the fixed share, the track in metres
    east/north of its first point with each point's quality, each mark where it fell with the
    quality there; what lies more than a second from any live position is not placed."""
    import json

    from groundstation.geodesy import enu_to_ecef
    from groundstation.view.dashboard.state import StationView

    v = StationView("demo")
    origin = (4146349.0, 612312.0, 4791750.0)
    for k in range(50):
        xyz = enu_to_ecef((k * 1.0, k * 0.5, 0.0), origin)
        sol = LiveSolution(1000 * S + k * S // 5, "fix" if k >= 10 else "float", 5.0, 8, 0.1,
                           xyz, (0.01, 0.01, 0.02))
        v.on_payload("groundstation/demo/rtk", json.dumps(
            {"type": "rtk", "station": "demo", **sol.message()}).encode(), 0.0)
    for idx, t in enumerate((1001 * S, 1009 * S, 2000 * S)):
        v.on_payload("groundstation/demo/timemark", json.dumps(
            {"type": "timemark", "index": idx, "falling_t_gps_ns": t, "count": idx + 1}
        ).encode(), 0.0)
    panel = v.snapshot(0.0)["rtk"]
    assert panel["latest"]["quality"] == "fix" and panel["fixed_share"] == pytest.approx(0.8)
    assert panel["track"][0] == [0.0, 0.0, "float"]
    assert panel["track"][-1] == pytest.approx([49.0, 24.5, "fix"], abs=0.01)
    assert panel["marks"] == [pytest.approx([5.0, 2.5, "float"], abs=0.01),
                              pytest.approx([45.0, 22.5, "fix"], abs=0.01)]


def test_the_line_rtk_prints_says_held_and_no_ratio_in_words() -> None:
    from groundstation.live.rtk import _line

    held = _line(dataclasses.replace(_sol(1, "fix"), ratio=999.9))
    assert " fix    ratio  held  sats  8" in held  # fix-and-hold's 999.9
    untried = _line(dataclasses.replace(_sol(2, "float"), ratio=0.0))
    assert " float  ratio     -  sats  8" in untried  # no "ratio 0.0"
    assert "ratio   5.0" in _line(_sol(3, "fix"))
