"""The dashboard's state folding, timeline arithmetic, hub and HTTP server (fake bus, real HTTP)."""

from __future__ import annotations

import http.client
import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from peers import wait_until

from groundstation.bus import encode
from groundstation.config import ZenohSettings
from groundstation.view.dashboard.server import (
    Dashboard,
    DashboardSettings,
    Hub,
    station_of,
)
from groundstation.view.dashboard.state import (
    FileInfo,
    StationView,
    _session_start_unix_ns,
    _slots,
)

NS = 1_000_000_000
T0 = 1_432_886_400 * NS  # GPS time of the first epoch
HOST_MINUS_GPS = 362_426_000 * NS  # host clock ahead of GPS time (UNIX/GPS epochs, latency)
SID = "st_20250602T080000Z"


def status(
    last_s: float, *, first_s: float = 0.0, dropouts: list[tuple[float, float]] | None = None,
    current: tuple[float, float] | None = None, sid: str = SID, source_connected: bool = True,
    host_s: float | None = None, marks: int = 0,
) -> bytes:
    """A status payload at 5 Hz; times in seconds from T0."""
    def ns(s: float) -> int:
        return T0 + round(s * NS)

    drops = [{"start_t_gps_ns": ns(a), "end_t_gps_ns": ns(b),
              "missing_epochs": round((b - a) / 0.2) + 1, "duration_s": b - a + 0.2}
             for a, b in dropouts or []]
    cur = None if current is None else {"start_t_gps_ns": ns(current[0]),
                                        "end_t_gps_ns": ns(current[1]), "ongoing": True,
                                        "missing_epochs": 1, "duration_s": 1.0}
    host = ns(last_s if host_s is None else host_s) + HOST_MINUS_GPS
    return encode("status", {
        "station": "st", "t_host_ns": host, "session_id": sid,
        "link": {"epoch_interval_s": 0.2, "epochs": 1, "first_epoch_t_gps_ns": ns(first_s),
                 "last_epoch_t_gps_ns": ns(last_s), "recent_dropouts": drops,
                 "current_dropout": cur, "source_connected": source_connected,
                 "bytes_in": 1000, "completeness_60s": 1.0},
        "sats": [{"sv": "G05", "cno_dbhz": 44, "elev_deg": 40, "azim_deg": 120,
                  "state": "clean"}],
        "ppk_ready": 6, "tracked": 8, "half_cycle_fraction": 0.1,
        "marks": {"marks": marks, "missed": 0, "in_dropout": 0, "last_falling_t_gps_ns": None},
        "alerts": [], "recording": {"file": "/nonexistent/st_20250602T080000Z.mcap"},
    })


def event(kind: str, data: dict[str, Any], t_host_ns: int = 0) -> bytes:
    return encode("event", {"kind": kind, "t_host_ns": t_host_ns, "message": kind,
                            "severity": "warning", "data": data, "station": "st"})


def mark(index: int, t_s: float, rising: bool = False) -> bytes:
    return encode("timemark", {"index": index, "count": index, "station": "st",
                               "falling_t_gps_ns": T0 + round(t_s * NS), "new_rising": rising,
                               "new_falling": not rising})


def test_slots_counts_epoch_grid_points_in_half_open_ranges() -> None:
    iv = NS // 5
    assert _slots(T0, iv, T0, T0 + NS) == 5
    assert _slots(T0, iv, T0 - 10 * NS, T0 + 1) == 1
    assert _slots(T0, iv, T0 + 1, T0 + iv) == 0
    assert _slots(T0, iv, T0 + iv, T0 + iv + 1) == 1
    assert _slots(T0, iv, T0 + NS, T0) == 0


def test_session_start_from_session_id() -> None:
    assert _session_start_unix_ns("st_20250602T080000Z") == 1_748_851_200 * NS
    assert _session_start_unix_ns("st_20250602T080000Z-3fa9c1") == 1_748_851_200 * NS
    assert _session_start_unix_ns("no-time") is None


def test_stale_after_three_seconds_without_status() -> None:
    v = StationView("st")
    assert v.stale(0.0)
    assert v.on_payload("groundstation/st/status", status(100.0), now_s=10.0)
    assert not v.stale(12.9)
    assert v.stale(13.1)
    snap = v.snapshot(13.1)
    assert snap["stale"] and snap["has_status"] and snap["sats"][0]["sv"] == "G05"
    assert not v.on_payload("groundstation/st/ubx", b"\xb5b\x02\x10", now_s=13.2)


def test_timeline_buckets_count_received_against_expected() -> None:
    v = StationView("st")
    # session of 100 s; a dropout from 50.0 to 51.8 s (10 epochs missing)
    v.on_payload("k", status(100.0, dropouts=[(50.0, 51.8)]), now_s=0.0)
    tl = v.snapshot(0.0)["timeline"]
    assert tl["bucket_s"] == 5 and tl["span_s"] == 600
    start = tl["start_t_gps_ns"]
    assert (start - T0) % (5 * NS) == 0  # aligned to the session grid
    buckets = tl["buckets"]
    first = (T0 - start) // (5 * NS)
    assert all(b == [0, 0] for b in buckets[:first])
    assert buckets[first] == [25, 25]
    assert buckets[first + 10] == [25, 15]  # 50..55 s holds the 10 missing epochs
    assert sum(e for e, _ in buckets) == 501  # epochs 0..100 s at 5 Hz
    assert sum(e - r for e, r in buckets) == 10
    [[a, b, ongoing, missing]] = tl["dropouts"]
    assert not ongoing and missing == 10
    assert b - a == pytest.approx(2.0)
    assert tl["first_s"] == pytest.approx((T0 - start) / NS)


def test_dropout_started_event_shows_before_the_next_status() -> None:
    v = StationView("st")
    v.on_payload("k", status(100.0), now_s=0.0)
    assert v.snapshot(0.5)["timeline"]["dropouts"] == []
    v.on_payload("k", event("link.dropout_started", {"start_t_gps_ns": T0 + 100_200_000_000}),
                 now_s=0.6)
    [[a, b, ongoing, _]] = v.snapshot(0.7)["timeline"]["dropouts"]
    assert ongoing and b >= a
    # data returns: the daemon reports the closed dropout, the pending one goes
    v.on_payload("k", event("link.dropout", {"start_t_gps_ns": T0 + 100_200_000_000,
                                             "end_t_gps_ns": T0 + 101_000_000_000,
                                             "missing_epochs": 5}), now_s=1.2)
    snap = v.snapshot(1.3)
    [[_, _, ongoing, missing]] = snap["timeline"]["dropouts"]
    assert not ongoing and missing == 5
    assert snap["link"]["dropouts"] == 1 and snap["link"]["missing_epochs"] == 5
    v.on_payload("k", status(102.0, dropouts=[(100.2, 101.0)]), now_s=2.0)
    assert len(v.snapshot(2.0)["timeline"]["dropouts"]) == 1  # the same dropout, once


def test_current_dropout_in_status_is_ongoing_until_data_returns() -> None:
    v = StationView("st")
    v.on_payload("k", status(100.0), now_s=0.0)
    v.on_payload("k", status(100.0, current=(100.2, 101.0), host_s=101.0), now_s=1.0)
    snap = v.snapshot(1.0)
    assert [d[2] for d in snap["timeline"]["dropouts"]] == [True]
    v.on_payload("k", status(103.0, dropouts=[(100.2, 101.6)]), now_s=3.0)
    assert [d[2] for d in v.snapshot(3.0)["timeline"]["dropouts"]] == [False]


def test_marks_deduplicated_flagged_in_dropout_and_reset_with_the_session() -> None:
    v = StationView("st")
    v.on_payload("k", status(100.0), now_s=0.0)
    for i in range(3):
        v.on_payload("k", mark(i, 90.0 + i), now_s=0.1)
    v.on_payload("k", mark(1, 91.0), now_s=0.2)  # again, from the queryable
    v.on_payload("k", mark(3, 92.0, rising=True), now_s=0.2)  # the rising edge of mark 2
    v.on_payload("k", event("mark.in_dropout", {"t_gps_ns": T0 + 92 * NS}), now_s=0.3)
    snap = v.snapshot(0.5)
    assert snap["marks"]["received"] == 3
    assert [m[1] for m in snap["timeline"]["marks"]] == [False, False, True]
    assert snap["marks"]["last_age_s"] == pytest.approx(8.5, abs=0.01)
    assert snap["marks"]["last_utc"] is not None
    assert not v.session_changed
    v.on_payload("k", encode("session", {"state": "finished", "session_id": SID}), now_s=0.9)
    assert v.snapshot(0.9)["session"]["state"] == "finished"
    v.on_payload("k", status(5.0, sid="st_20250602T090000Z"), now_s=1.0)
    snap = v.snapshot(1.0)
    assert snap["marks"]["received"] == 0 and snap["timeline"]["marks"] == []
    assert v.session_changed  # the hub fetches the new session's marks again
    assert v.snapshot(1.0)["session"]["state"] == "recording"
    v.on_payload("k", mark(1, 4.0), now_s=1.1)  # index 1 again, but of the new session
    assert v.snapshot(1.2)["marks"]["received"] == 1


def test_source_outage_mapped_from_host_time() -> None:
    v = StationView("st")
    v.on_payload("k", status(100.0), now_s=0.0)
    lost_host = T0 + 100 * NS + HOST_MINUS_GPS
    v.on_payload("k", event("source.lost", {"start_ns": lost_host}), now_s=0.1)
    [[a, b, ongoing]] = v.snapshot(0.2)["timeline"]["outages"]
    assert ongoing
    v.on_payload("k", event("source.outage", {"start_ns": lost_host,
                                              "end_ns": lost_host + 4 * NS}), now_s=4.0)
    [[a, b, ongoing]] = v.snapshot(4.0)["timeline"]["outages"]
    assert not ongoing and b - a == pytest.approx(4.0)


def test_session_panel_uses_local_file_information() -> None:
    v = StationView("st")
    v.on_payload("k", status(100.0, host_s=100.0), now_s=0.0)
    seen: list[str] = []

    def probe(path: str) -> FileInfo:
        seen.append(path)
        return FileInfo(1234, 5 * 10**9, 10**10)

    sess = v.snapshot(0.0, file_info=probe)["session"]
    assert seen == ["/nonexistent/st_20250602T080000Z.mcap"]
    assert sess["size_bytes"] == 1234 and sess["disk_free_bytes"] == 5 * 10**9
    assert sess["id"] == SID and sess["state"] == "recording"
    assert sess["duration_s"] is not None


class FakeBus:
    """Records subscriptions; the test calls the callbacks as Zenoh would."""

    def __init__(self) -> None:
        self.subs: dict[str, Callable[[str, bytes], None]] = {}
        self.alive: dict[str, Callable[[str, bool], None]] = {}
        self.queries: list[str] = []
        self.replies: dict[str, list[tuple[str, bytes]]] = {}
        self.puts: list[tuple[str, bytes]] = []
        self.closed = False

    def subscribe(self, key_expr: str, callback: Callable[[str, bytes], None]) -> None:
        self.subs[key_expr] = callback

    def subscribe_liveliness(self, key_expr: str, callback: Callable[[str, bool], None]) -> None:
        self.alive[key_expr] = callback

    def get(self, selector: str, timeout_s: float = 2.0) -> list[tuple[str, bytes]]:
        self.queries.append(selector)
        return self.replies.get(selector, [])

    def put(self, key_expr: str, payload: bytes) -> None:
        self.puts.append((key_expr, payload))

    def close(self) -> None:
        self.closed = True


def test_station_of() -> None:
    assert station_of("groundstation/a/status") == "a"
    assert station_of("other/a/status") is None
    assert station_of("groundstation") is None


def test_hub_discovers_stations_and_catches_up_when_a_daemon_appears() -> None:
    bus = FakeBus()
    bus.replies["groundstation/b/q/status"] = [("groundstation/b/q/status", status(10.0))]
    hub = Hub(("a",), clock=lambda: 0.0)
    hub.attach(bus)
    try:
        assert set(bus.subs) == {f"groundstation/*/{leaf}"
                                 for leaf in ("status", "event", "timemark", "session", "solution",
                                              "rtk")}
        wait_until(lambda: "groundstation/a/q/timemarks" in bus.queries)
        assert hub.document(None)["station"] == "a"  # listed, nothing heard yet
        bus.alive["groundstation/*/alive/**"]("groundstation/b/alive/1a2b", True)
        wait_until(lambda: hub.views["b"].status is not None)
        names = [s["name"] for s in hub.stations()]
        assert names == ["a", "b"]
        doc = hub.document(None)
        assert doc["station"] == "b"  # the first station with data
        assert doc["view"]["has_status"] and doc["view"]["alive"] is True
        bus.subs["groundstation/*/status"]("groundstation/a/status", status(20.0))
        assert hub.document("a")["view"]["has_status"]
        assert hub.document("zz")["view"] is None
        bus.alive["groundstation/*/alive/**"]("groundstation/b/alive/1a2b", False)
        assert hub.document("b")["view"]["alive"] is False
        asked = bus.queries.count("groundstation/b/q/timemarks")
        bus.subs["groundstation/*/status"]("groundstation/b/status",
                                           status(1.0, sid="st_20250602T100000Z"))
        wait_until(lambda: bus.queries.count("groundstation/b/q/timemarks") > asked)
    finally:
        hub.close()


@pytest.fixture
def served() -> Iterator[tuple[Dashboard, FakeBus]]:
    bus = FakeBus()
    settings = DashboardSettings(stations=("st",), port=0, bus=ZenohSettings())
    dash = Dashboard(settings, bus_factory=lambda _s: bus)
    dash.start()
    yield dash, bus
    dash.close()
    assert bus.closed


def _get(dash: Dashboard, path: str) -> tuple[int, str, bytes]:
    host, port = dash.http.server_address[:2]
    conn = http.client.HTTPConnection(str(host), int(port), timeout=5)
    try:
        conn.request("GET", path)
        resp = conn.getresponse()
        return resp.status, resp.getheader("Content-Type") or "", resp.read()
    finally:
        conn.close()


def test_http_serves_the_packaged_page_and_nothing_else(
    served: tuple[Dashboard, FakeBus],
) -> None:
    dash, _ = served
    code, ctype, body = _get(dash, "/")
    assert code == 200 and ctype.startswith("text/html") and b"/static/app.js" in body
    assert b"http://" not in body.replace(b"http://www.w3.org", b"")  # no CDN
    for name, kind in (("app.js", "text/javascript"), ("style.css", "text/css")):
        code, ctype, body = _get(dash, f"/static/{name}")
        assert code == 200 and ctype.startswith(kind) and body
    for bad in ("/static/../server.py", "/static/state.py", "/nope", "/static/%2e%2e/x.js"):
        assert _get(dash, bad)[0] == 404, bad
    code, _, body = _get(dash, "/api/stations")
    assert code == 200 and json.loads(body)[0]["name"] == "st"


def test_event_stream_pushes_a_snapshot_on_change(served: tuple[Dashboard, FakeBus]) -> None:
    dash, bus = served
    host, port = dash.http.server_address[:2]
    conn = http.client.HTTPConnection(str(host), int(port), timeout=5)
    conn.request("GET", "/events?station=st")
    resp = conn.getresponse()
    assert resp.status == 200 and resp.getheader("Content-Type", "").startswith(
        "text/event-stream")
    docs: list[dict[str, Any]] = []

    def read() -> None:
        try:
            for raw in resp:
                line = raw.decode().rstrip("\n")
                if line.startswith("data: "):
                    docs.append(json.loads(line[6:]))
                if len(docs) >= 5:
                    return
        except (OSError, AttributeError, ValueError):  # the test closed the connection
            return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        wait_until(lambda: docs)
        assert docs[0]["station"] == "st" and not docs[0]["view"]["has_status"]
        t = time.monotonic()
        bus.subs["groundstation/*/status"]("groundstation/st/status", status(10.0))
        wait_until(lambda: any(d["view"]["has_status"] for d in docs))
        assert time.monotonic() - t < 0.5  # pushed on change, not on the next heartbeat
    finally:
        conn.close()
        reader.join(timeout=3)


def test_latest_report_is_linked_and_served(
    served: tuple[Dashboard, FakeBus], tmp_path: Path
) -> None:
    dash, bus = served
    out = tmp_path / "solutions" / "st" / "flight1"
    out.mkdir(parents=True)
    (out / "report.html").write_text("<!DOCTYPE html><title>r</title>")
    bus.subs["groundstation/*/status"]("groundstation/st/status", status(10.0))
    assert _get(dash, "/report?station=st")[0] == 404  # no report announced yet
    # A failed solve names no report; an ok one does.
    for body in ({"status": "failed", "reason": "x"},
                 {"status": "ok", "flight": "/rec/flight1.mcap", "report": str(out / "report.html"),
                  "report_pdf": None}):
        bus.subs["groundstation/*/solution"](
            "groundstation/st/solution", encode("solution", {"station": "st", **body}))
    code, _, raw = _get(dash, "/api/snapshot?station=st")
    report = json.loads(raw)["view"]["report"]
    assert report == {"url": "/report?station=st", "flight": "flight1.mcap", "pdf": False,
                      "t_host_ns": None, "verdict": None}  # (a solver before go_no_go)
    code, ctype, raw = _get(dash, report["url"])
    assert code == 200 and ctype.startswith("text/html") and raw.startswith(b"<!DOCTYPE html>")
    assert _get(dash, report["url"] + "&format=pdf")[0] == 404  # no PDF was written


def test_mark_ages_run_on_the_data_clock_of_a_replay() -> None:
    """``replay --speed 4``: statuses 1 s apart in data time arrive 0.25 s apart; a mark
    arrives between two statuses. Its age is taken on the data clock, never negative."""
    v = StationView("st")
    for k in range(8):
        v.on_payload("k", status(100.0 + k), now_s=k * 0.25)
    assert v.data_rate() == pytest.approx(4.0)
    rx = 7 * 0.25  # the last status: data time 107 s
    v.on_payload("k", mark(0, 107.3), now_s=rx + 0.1)  # 0.4 s of data time after it
    assert v.snapshot(rx + 0.1)["marks"]["last_age_s"] == pytest.approx(0.1, abs=0.05)
    assert v.snapshot(rx + 0.2)["marks"]["last_age_s"] == pytest.approx(0.5, abs=0.05)
    # at max speed a mark may be far ahead of the extrapolated clock: age 0, not negative
    v.on_payload("k", mark(1, 150.0), now_s=rx + 0.2)
    assert v.snapshot(rx + 0.2)["marks"]["last_age_s"] == 0.0
    # a live daemon's statuses come once a second: the clock runs at 1 despite jitter
    live = StationView("st")
    for k, jitter in enumerate((0.0, 0.08, -0.05, 0.1, 0.0)):
        live.on_payload("k", status(100.0 + k), now_s=k + jitter)
    assert live.data_rate() == 1.0


def test_a_replay_of_an_older_recording_starts_afresh() -> None:
    """A new session whose data time is earlier (a replay of an older recording after a
    live session): the previous session's marks go, and ages follow the new data clock."""
    v = StationView("st")
    for k in range(3):
        v.on_payload("k", status(1000.0 + k), now_s=float(k))
    v.on_payload("k", mark(0, 1001.5), now_s=2.1)
    assert v.snapshot(2.2)["marks"]["received"] == 1
    older = "st_replay-20250602T100000Z_20250601T080000Z"
    v.on_payload("k", status(10.0, sid=older, host_s=10.0), now_s=3.0)
    v.on_payload("k", mark(0, 9.0), now_s=3.1)
    snap = v.snapshot(3.1)
    assert snap["marks"]["received"] == 1
    assert snap["marks"]["last_t_gps_ns"] == T0 + 9 * NS
    assert snap["marks"]["last_age_s"] == pytest.approx(1.1, abs=0.05)
