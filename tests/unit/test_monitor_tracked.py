"""What the views count as tracked, and say about what they do not count.

Found by a surveyor trying the real multi-GNSS data: ``watch`` and the dashboard listed a GLONASS
measurement the receiver had not identified (u-blox svId 255) as satellite "R255", elevation
-91, "clean", and counted it as tracked; "PPK-ready 8 of 10 tracked" with every row clean did
not say that the other two were below the elevation mask; a clash of two daemons on one station
ended the demo's summary with "alerts: none". The monitor, the end-of-run summary, ``watch``
and the dashboard's document are checked on the same status.
"""

from __future__ import annotations

import asyncio
import io
from pathlib import Path
from typing import Any

from peers import StatusEventCollector
from rich.console import Console
from statuses import GLONASS, GPS, HOST0, monitor_status, obs

from groundstation import events as kinds
from groundstation.bus import encode
from groundstation.gpstime import NS_PER_S
from groundstation.live.fanout import Overflow, SinkSpec
from groundstation.live.replay import run_replay
from groundstation.records import Event, SatObs, Status
from groundstation.view.dashboard.state import StationView
from groundstation.view.summary import status_lines
from groundstation.view.watch import WatchState, render


def run(sats: list[SatObs], elevations: list[tuple[int, int, int]],
        events: tuple[Event, ...] = ()) -> Status:
    return monitor_status(sats, elevations, events=events)


def watch_text(status: Status) -> str:
    state = WatchState("st")
    state.on_payload("groundstation/st/status", encode("status", status))
    assert state.rejected == 0, state.last_rejection
    out = io.StringIO()
    Console(file=out, width=200, color_system=None).print(render(state))
    return out.getvalue()


def dashboard_doc(status: Status) -> dict[str, Any]:
    view = StationView("st")
    assert view.on_payload("groundstation/st/status", encode("status", status), 1.0)
    return view.snapshot(1.5)


GPS_SATS = [obs(GPS, sv) for sv in (2, 5, 7, 9, 12, 15, 20)]
GPS_ELEV = [(GPS, sv, 40 + sv) for sv in (2, 5, 7, 9, 12, 15, 20)]


def test_an_unidentified_glonass_measurement_is_no_satellite() -> None:
    """Before: "R255 -91 ... 51 clean" in the table and in the count (8 tracked)."""
    sats = [*GPS_SATS, obs(GLONASS, 3), obs(GLONASS, 255, cno=51)]
    elev = [*GPS_ELEV, (GLONASS, 3, 35), (GLONASS, 255, -91)]
    st = run(sats, elev)
    assert [s.sv for s in st.sats] == ["G02", "G05", "G07", "G09", "G12", "G15", "G20", "R03"]
    assert st.tracked == 8 and st.ppk_ready == 8 and st.unidentified == 1
    text = watch_text(st)
    assert "R255" not in text and "-91" not in text
    assert "1 GLONASS measurement without a satellite number (not counted)" in text
    doc = dashboard_doc(st)
    assert "R255" not in [s["sv"] for s in doc["sats"]]
    assert doc["ppk"]["tracked"] == 8
    assert doc["ppk"]["unidentified_text"] == (
        "1 GLONASS measurement without a satellite number (not counted)")
    assert "without a satellite number" in status_lines(st)[2]


def test_an_elevation_the_receiver_does_not_know_is_none_not_minus_91() -> None:
    st = run(GPS_SATS, [*GPS_ELEV[:-1], (GPS, 20, -91)])
    g20 = next(s for s in st.sats if s.sv == "G20")
    assert g20.elev_deg is None and g20.azim_deg is None
    assert st.below_mask == 0 and st.ppk_ready == 7  # unknown: not held against it
    assert " -91 " not in watch_text(st)


def test_satellites_below_the_mask_are_said_where_ppk_ready_is_shown() -> None:
    """Before: "PPK-ready 8 of 10 tracked" with all ten rows clean, the mask unsaid."""
    sats = [*GPS_SATS, *(obs(GPS, sv) for sv in (24, 29, 31))]
    elev = [*GPS_ELEV, (GPS, 24, 60), (GPS, 29, 9), (GPS, 31, 12)]
    st = run(sats, elev)
    assert all(s.state == "clean" for s in st.sats) and len(st.sats) == 10
    assert (st.tracked, st.ppk_ready, st.below_mask) == (10, 8, 2)
    assert st.elevation_mask_deg == 15.0
    line = status_lines(st)[2]
    assert "10 satellites tracked (2 below the 15° elevation mask), 8 PPK-ready" in line, line
    text = watch_text(st)
    assert " 8  of 10 tracked (2 below the 15° elevation mask), 5 needed" in text, text
    rows = [ln for ln in text.splitlines() if "below mask" in ln]
    assert [r.split()[1] for r in rows] == ["G29", "G31"], rows
    doc = dashboard_doc(st)
    assert doc["ppk"]["tracked_text"] == "10 tracked (2 below the 15° elevation mask)"


def test_a_station_conflict_is_an_alert_and_the_summary_names_it_once_cleared() -> None:
    """Before: the clash was an event only; the demo's summary ended with "alerts: none"."""
    clash = Event(kinds.STATION_CONFLICT, HOST0, "another daemon publishes as station 'st' "
                  "(1 other): every view mixes the two; rename one (station = ...)", "error",
                  {"others": ["x"], "instance": "y"})
    ended = Event(kinds.STATION_CONFLICT_ENDED, HOST0 + NS_PER_S,
                  "no other daemon publishes as station 'st' any more", "info", {"instance": "y"})
    standing = run(GPS_SATS, GPS_ELEV, events=(clash,))
    (alert,) = standing.alerts
    assert alert.startswith("station_conflict: another daemon publishes as station 'st'")
    assert status_lines(standing)[2].endswith(f"alerts: {alert}")
    # the dashboard shows the daemon's alert, not a second one of its own
    view = StationView("st")
    view.on_alive(True, "x")
    view.on_alive(True, "y")
    view.on_payload("groundstation/st/status", encode("status", standing), 1.0)
    assert view.snapshot(1.5)["alerts"] == [alert]
    cleared = run(GPS_SATS, GPS_ELEV, events=(clash, ended))
    assert cleared.alerts == ()
    line = status_lines(cleared, cleared=(alert,))[2]
    assert line.endswith(f"alerts: none (raised during the run, cleared since: {alert})"), line


def test_the_real_glonass_flight_never_shows_an_unidentified_satellite(
    shared_data: Path,
) -> None:
    """The NEO-M8P rover of 2018-10-09 (1 334 measurements with svId 255, NAV-SVINFO
    elevations of -91) through the live pipeline: no status lists R255 or an elevation below
    -90, and the unidentified measurements are counted apart."""
    sink = StatusEventCollector()
    rover = shared_data / "real/jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz"
    asyncio.run(run_replay(rover, speed=None,
                           sinks=(SinkSpec(sink, 1_000_000, Overflow.NEVER_DROP),)))
    statuses = [s for s in sink.items if isinstance(s, Status)]
    assert len(statuses) > 2000
    shown = [s for st in statuses for s in st.sats]
    assert not [s.sv for s in shown if s.sv.startswith("R255")]
    assert min(s.elev_deg for s in shown if s.elev_deg is not None) >= -90
    assert any(st.unidentified for st in statuses)
    assert all(st.tracked == len([s for s in st.sats if "/" not in s.sv
                                  and not s.sv.startswith("S")]) for st in statuses)
