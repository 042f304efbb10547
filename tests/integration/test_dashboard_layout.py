"""The dashboard's page in headless Chromium with many satellites and with a data clock far
from the computer's: what a surveyor saw with a real multi-GNSS replay and with the demo.

- With 22 satellites (a real replay had 22 to 25) the C/N0 panel's labels collided at 1366
  and 1024 px (the satellite names ran into each other, "G01G03G06...", and so did the
  values and the clean-phase seconds). No two of its labels may overlap, and every label
  stays inside the panel.
- During a demo (or a replay) the header's clock showed the computer's time and "last mark"
  the simulated time, side by side, neither saying which: the clock says "computer", the data's
  own time is shown under it with "data" when the two are more than a minute apart, and the
  last mark says it is the receiver's time. The header still fits at 1024 px.

The statuses are a real monitor's (``tests/statuses.py``), published on a Zenoh session of
the test's own to a real dashboard server.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from peers import free_port
from statuses import GLONASS, GPS, monitor_status, obs
from test_dashboard_chromium import CHROMIUM, HEADER_CUT, Chromium, wait_for

from groundstation import gpstime
from groundstation.bus import encode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.gpstime import NS_PER_S
from groundstation.records import Status
from groundstation.view.dashboard.server import Dashboard, DashboardSettings

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(),
                                reason="headless Chromium not installed (/usr/bin/chromium "
                                "absent; apt-get install chromium)")

STATION = "multi"
GPS_SVS = (1, 3, 6, 11, 12, 14, 17, 18, 19, 22, 23, 28, 31, 32)
GLONASS_SVS = (3, 4, 5, 11, 12, 18, 19, 20)

LABELS_OVERLAP = """(() => {
  const svg = document.getElementById("cno"), box = svg.getBoundingClientRect();
  const texts = Array.from(svg.querySelectorAll("text:not(.ref-label)"))
    .filter((t) => t.textContent.trim());
  const r = texts.map((t) => t.getBoundingClientRect());
  const bad = [];
  for (let i = 0; i < r.length; i++) {
    if (r[i].left < box.left - 0.5 || r[i].right > box.right + 0.5 ||
        r[i].top < box.top - 0.5 || r[i].bottom > box.bottom + 0.5)
      bad.push("outside: " + texts[i].textContent);
    for (let j = i + 1; j < r.length; j++) {
      const w = Math.min(r[i].right, r[j].right) - Math.max(r[i].left, r[j].left);
      const h = Math.min(r[i].bottom, r[j].bottom) - Math.max(r[i].top, r[j].top);
      if (w > 0.5 && h > 0.5) bad.push(texts[i].textContent + " / " + texts[j].textContent);
    }
  }
  return [texts.length, bad];
})()"""
"""Every pair of C/N0 labels whose boxes overlap, and every label outside the chart."""


def twenty_two_satellites(t0_gps_ns: int, host0_ns: int) -> Status:
    sats = [obs(GPS, sv, 30 + sv % 21) for sv in GPS_SVS] + [
        obs(GLONASS, sv, 35 + sv % 15) for sv in GLONASS_SVS]
    elev = [(GPS, sv, 10 + (7 * sv) % 75) for sv in GPS_SVS] + [
        (GLONASS, sv, 12 + (5 * sv) % 70) for sv in GLONASS_SVS]
    return monitor_status(sats, elev, t0_gps_ns=t0_gps_ns, host0_ns=host0_ns, station=STATION)


class Station:
    """The test's own Zenoh session, listening; publishes a status twice a second (the page
    is live while statuses keep coming)."""

    def __init__(self) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.bus = open_bus(ZenohSettings(listen=(self.endpoint,), connect=()))
        self.payload = b""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._talk, daemon=True)

    def show(self, status: Status) -> None:
        self.payload = encode("status", status)
        if not self._thread.is_alive():
            self._thread.start()

    def _talk(self) -> None:
        while not self._stop.is_set():
            self.bus.put(key(STATION, "status"), self.payload)
            self._stop.wait(0.5)

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        self.bus.close()


@pytest.fixture
def station() -> Iterator[Station]:
    s = Station()
    yield s
    s.close()


@pytest.fixture
def dashboard(station: Station) -> Iterator[str]:
    dash = Dashboard(DashboardSettings(stations=(STATION,), port=0, bus=ZenohSettings(
        listen=(), connect=(station.endpoint,))))
    dash.start()
    try:
        yield dash.url
    finally:
        dash.close()


def _page(url: str, width: int, height: int) -> Chromium:
    browser = Chromium(width, height)
    browser.send("Page.navigate", {"url": url})
    wait_for("page live", lambda: browser.eval("document.body?.dataset.state") == "live", 30)
    return browser


@pytest.mark.parametrize(("width", "height"), [(1366, 768), (1024, 600)])
def test_cno_labels_of_22_satellites_never_overlap(
    station: Station, dashboard: str, width: int, height: int, tmp_path: Path,
) -> None:
    host = time.time_ns()
    station.show(twenty_two_satellites(gpstime.unix_to_gps_ns(host) - 40 * NS_PER_S,
                                       host - 41 * NS_PER_S))
    browser = _page(dashboard, width, height)
    try:
        wait_for("22 bars", lambda: browser.eval(
            "document.querySelectorAll('#cno rect.bar').length") == 22, 15)
        browser.screenshot(tmp_path / f"cno-{width}x{height}.png")
        n, overlaps = browser.eval(LABELS_OVERLAP)
        assert n == 3 * 22  # C/N0, satellite and clean phase under every bar
        assert overlaps == [], f"at {width}x{height}: {overlaps}"
        names = browser.eval("Array.from(document.querySelectorAll('#cno .bar-sv'))"
                             ".map((t) => t.textContent)")
        assert names == sorted(f"G{sv:02d}" for sv in GPS_SVS) + sorted(
            f"R{sv:02d}" for sv in GLONASS_SVS)
        assert browser.console_errors() == [] and browser.eval("gsDashboard.errors") == []
    finally:
        browser.close()


def test_the_clocks_say_whose_time_they_show(station: Station, dashboard: str) -> None:
    """A flight three hours in the past (a replay, a simulated flight): the header shows the
    computer's clock and under it the data's, each named; live data shows one clock."""
    host = time.time_ns()
    past = gpstime.unix_to_gps_ns(host) - 3 * 3600 * NS_PER_S
    station.show(twenty_two_satellites(past - 40 * NS_PER_S, host - 41 * NS_PER_S))
    browser = _page(dashboard, 1024, 600)
    try:
        wait_for("the data clock", lambda: not browser.eval(
            "document.getElementById('data-clock').hidden"), 10)
        clock = browser.eval("document.getElementById('clock').innerText")
        computer, data = clock.split("\n")
        assert computer.startswith("computer ") and computer.endswith(" UTC"), clock
        assert data.startswith("data ") and data.endswith(" UTC"), clock
        shown = data.removeprefix("data ").removesuffix(" UTC")
        expected = gpstime.gps_to_datetime(past)
        h, m, _ = (int(x) for x in shown.split(":"))
        assert (h * 60 + m - expected.hour * 60 - expected.minute) % 1440 in (0, 1, 1439), clock
        title = browser.eval("document.getElementById('data-clock').title")
        assert "3 h 00 min behind this computer's clock" in title or \
            "3 h 01 min behind this computer's clock" in title, title
        assert browser.eval(
            "document.querySelector('#marks-panel .cell.wide .label').textContent") == \
            "last mark (receiver time, UTC)"
        assert browser.eval(f"{HEADER_CUT}([])") == []
        # live data: one clock, the computer's
        station.show(twenty_two_satellites(gpstime.unix_to_gps_ns(host) - 40 * NS_PER_S,
                                           host - 41 * NS_PER_S))
        wait_for("one clock", lambda: browser.eval(
            "document.getElementById('data-clock').hidden"), 10)
        assert browser.eval("document.getElementById('clock').innerText").startswith(
            "computer ")
        assert browser.console_errors() == [] and browser.eval("gsDashboard.errors") == []
    finally:
        browser.close()
