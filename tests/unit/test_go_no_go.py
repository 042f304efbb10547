"""The go / no-go before the team packs up: the flight's marks fixed and checked, or the
stretches of the others to fly again (a fixed mark or 30 s without a mark ends a stretch), in
the solver's ``solution`` message and in words on the dashboard."""

from __future__ import annotations

import math

from groundstation.solve.outputs import CameraRow
from groundstation.solve.report_data import go_no_go
from groundstation.view.dashboard.state import StationView
from groundstation.view.summary import go_no_go_text

S = 1_000_000_000
T0 = 1_432_886_400 * S  # 2025-06-03 08:00:00 GPS


def _row(k: int, t_s: float, grade: str) -> CameraRow:
    t = T0 + int(t_s * S) if math.isfinite(t_s) else -1
    return CameraRow(photo="", mark=k, mark_count=k, t_gps_ns=t, lat_deg=49.0,
                     lon_deg=8.4, h_m=160.0, x_m=0.0, y_m=0.0, sd_e_m=0.01, sd_n_m=0.01,
                     sd_u_m=0.02, quality=1, flags=0, grade=grade)


def test_all_fixed_is_go() -> None:
    doc = go_no_go([_row(k, k * 2.0, "fixed") for k in range(59)])
    assert doc == {"marks": 59, "fixed": 59, "stretches": []}
    assert go_no_go_text(doc) == "all 59 marks fixed and checked"


def test_the_stretches_to_fly_again() -> None:
    grades = ["fixed"] * 5 + ["float"] * 4 + ["fixed"] * 3 + ["float"] * 2
    rows = [_row(k, k * 2.0, g) for k, g in enumerate(grades)]
    rows.append(_row(14, 100.0, "float"))  # 72 s after the previous: a stretch of its own
    rows.append(_row(-1, math.nan, "none"))  # a photo without a mark: not counted
    doc = go_no_go(rows)
    assert doc["marks"] == 15 and doc["fixed"] == 8
    assert [(s["start_t_gps_ns"] - T0) // S for s in doc["stretches"]] == [10, 24, 100]
    assert [s["marks"] for s in doc["stretches"]] == [4, 2, 1]
    assert go_no_go_text(doc) == ("7 of 15 marks not fixed: fly again over 08:00:10-08:00:16 "
                                  "GPS (4), 08:00:24-08:00:26 GPS (2), 08:01:40-08:01:40 GPS (1)")


def test_the_dashboard_shows_the_verdict() -> None:
    import json

    v = StationView("rover")
    body = {"type": "solution", "station": "rover", "status": "ok", "report": "/x/report.html",
            "flight": "/x/rover.mcap", "go_no_go": go_no_go([_row(0, 1.0, "float")])}
    v.on_payload("groundstation/rover/solution", json.dumps(body).encode(), 0.0)
    verdict = v.snapshot(0.0)["report"]["verdict"]
    assert verdict == {"ok": False, "text": "1 of 1 marks not fixed: fly again over "
                       "08:00:01-08:00:01 GPS (1)"}
