"""The dashboard end to end in headless Chromium: simulator -> pty -> daemon -> Zenoh ->
``groundstation dashboard`` -> the page.

The page loads without console errors, values update, a dropout injected into the stream is on
the timeline while the stream is still silent, with the epochs it missed, a daemon that ends
normally shows "session finished", a restarted one is live again, and a killed one shows as
stale with the daemon gone without touching the page. Every wait is on the page's content with
a generous timeout, never a time window. At 1366x768 and 1024x600 no panel text is cut.
Chromium is driven over the DevTools protocol on a pipe
(``--remote-debugging-pipe``: NUL-separated JSON on fds 3 and 4, no websocket needed).
Screenshots at 1366x768 go to the test's tmp dir.
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import queue
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from peers import Daemon, Pty, free_port

from groundstation.pacing import paced
from groundstation.sim.stream import SimConfig, simulate

CHROMIUM = Path("/usr/bin/chromium")
RXM_RAW_HEADER = b"\xb5\x62\x02\x10"
STATION = "dash"
WIDTH, HEIGHT = 1366, 768
STALE_AFTER_S = 3.0
"""The page's STALE_AFTER_S (app.js)."""
SKIP_S = 100.0
"""Start the stream this far into the simulated flight: the camera starts soon after."""

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="headless Chromium not installed (/usr/bin/chromium absent; "
                       "apt-get install chromium)"),
]


def _high_fd(fd: int) -> int:
    """Move a pipe end above 10 so that the child's dup2 onto 3 and 4 cannot clobber it."""
    new = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
    os.close(fd)
    return new


class Chromium:
    """Headless Chromium with the DevTools protocol on a pipe; one page attached (flat mode)."""

    def __init__(self, width: int = WIDTH, height: int = HEIGHT) -> None:
        self.profile = tempfile.mkdtemp(prefix="gs-chromium-")
        to_r, self._to_w = map(_high_fd, os.pipe())
        self._from_r, from_w = map(_high_fd, os.pipe())

        def child_fds() -> None:
            os.dup2(to_r, 3)
            os.dup2(from_w, 4)

        self.proc = subprocess.Popen(
            [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", "--hide-scrollbars", f"--user-data-dir={self.profile}",
             "--remote-debugging-pipe", f"--window-size={width},{height}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            close_fds=False, preexec_fn=child_fds,
        )
        os.close(to_r)
        os.close(from_w)
        self._next_id = 0
        self._lock = threading.Lock()
        self._pending: dict[int, queue.Queue[dict[str, Any]]] = {}
        self.events: list[dict[str, Any]] = []
        self._reader = threading.Thread(target=self._pump, daemon=True)
        self._reader.start()
        self.session = ""
        target = self.send("Target.createTarget", {"url": "about:blank"})
        self.session = self.send("Target.attachToTarget",
                                 {"targetId": target["targetId"], "flatten": True})["sessionId"]
        for domain in ("Runtime.enable", "Log.enable", "Page.enable"):
            self.send(domain)
        self.send("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})

    def _pump(self) -> None:
        buf = b""
        while True:
            try:
                data = os.read(self._from_r, 1 << 16)
            except OSError:
                return
            if not data:
                return
            buf += data
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                msg = json.loads(raw)
                if "id" in msg:
                    waiter = self._pending.pop(msg["id"], None)
                    if waiter is not None:
                        waiter.put(msg)
                else:
                    self.events.append(msg)

    def send(self, method: str, params: dict[str, Any] | None = None,
             timeout_s: float = 10.0) -> dict[str, Any]:
        with self._lock:
            self._next_id += 1
            ident = self._next_id
        waiter: queue.Queue[dict[str, Any]] = queue.Queue()
        self._pending[ident] = waiter
        msg: dict[str, Any] = {"id": ident, "method": method, "params": params or {}}
        if self.session:
            msg["sessionId"] = self.session
        os.write(self._to_w, json.dumps(msg).encode() + b"\0")
        reply = waiter.get(timeout=timeout_s)
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error']}")
        result: dict[str, Any] = reply["result"]
        return result

    def eval(self, expression: str) -> Any:
        res = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True})
        if "exceptionDetails" in res:
            raise RuntimeError(f"{expression}: {res['exceptionDetails']}")
        return res["result"].get("value")

    def screenshot(self, path: Path) -> None:
        data = self.send("Page.captureScreenshot", {"format": "png"})["data"]
        path.write_bytes(base64.b64decode(data))

    def console_errors(self) -> list[str]:
        """Exceptions, console.error calls and error log entries (failed loads included)."""
        out = []
        for ev in list(self.events):
            method, p = ev.get("method"), ev.get("params", {})
            if method == "Runtime.exceptionThrown":
                out.append(json.dumps(p.get("exceptionDetails"))[:500])
            elif method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                out.append(json.dumps(p.get("args"))[:500])
            elif method == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
                out.append(str(p["entry"].get("text")) + " " + str(p["entry"].get("url")))
        return out

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.send("Browser.close", timeout_s=3)
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=5)
        for fd in (self._to_w, self._from_r):
            with contextlib.suppress(OSError):
                os.close(fd)
        shutil.rmtree(self.profile, ignore_errors=True)


class Feeder:
    """The simulated rover stream into the pty in real time; can hold its breath (a dropout)
    or pause while the daemon is down."""

    def __init__(self, pty: Pty) -> None:
        sim = simulate(SimConfig(duration_s=300, with_base=False))
        t0 = sim.rover_chunks[0][0]
        self.chunks = [c for c in sim.rover_chunks if c[0] >= t0 + SKIP_S * 1e9]
        self.pty = pty
        self.silent_until = 0.0
        self.silence_started: float | None = None
        self.skipped_epochs = 0
        """RXM-RAW headers in the chunks not written (the epochs a dropout misses)."""
        self.paused = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="feeder", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        for _, chunk in paced(self.chunks, 1.0):
            if self._stop.is_set():
                return
            now = time.monotonic()
            if now < self.silent_until or self.paused.is_set():
                if self.silence_started is None:
                    self.silence_started = now
                self.skipped_epochs += chunk.count(RXM_RAW_HEADER)
                continue
            with contextlib.suppress(OSError):
                self.pty.write(chunk)

    def drop(self, seconds: float) -> None:
        self.silence_started = None
        self.silent_until = time.monotonic() + seconds

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


PANELS_CUT = """((strict) => {
  const cut = [];
  for (const id of ["ppk-panel", "marks-panel", "alerts-panel", "session-panel"]) {
    const panel = document.getElementById(id);
    const box = panel.getBoundingClientRect();
    const inner = box.bottom - parseFloat(getComputedStyle(panel).borderBottomWidth);
    for (const el of panel.querySelectorAll(
        "h2, #alerts li, .label, .big, .mid, .detail, .kv th, .kv td, .rec")) {
      if (!el.textContent.trim()) continue;
      const r = el.getBoundingClientRect();
      // (on a large screen the file name may end in an ellipsis: its full text is in its
      // title; every other value, and on a small screen the file too, is whole)
      const mayCut = !strict && el.id === "sess-file";
      const wide = !mayCut && el.scrollWidth > el.clientWidth + 1;
      if (r.bottom > inner + 0.5 || r.right > box.right + 0.5 || wide)
        cut.push(id + " " + (el.id || el.className) + ": " + el.textContent.trim().slice(0, 40));
    }
  }
  return cut;
})"""
"""Panel texts that do not fit: their box ends below or right of the panel's, or overflows.
Call it with ``true`` for a small screen (every value whole, the file name too)."""

HEADER_CUT = """((ellipsisOk) => {
  const cut = [];
  const width = document.documentElement.clientWidth;
  if (document.scrollingElement.scrollWidth > width)
    cut.push("page scrolls sideways: " + document.scrollingElement.scrollWidth + " > " + width);
  for (const id of ["station", "badge", "badge-detail", "alert-count", "clock"]) {
    const el = document.getElementById(id);
    const r = el.getBoundingClientRect();
    const wide = !ellipsisOk.includes(id) && el.scrollWidth > el.clientWidth + 1;
    if (r.right > width + 0.5 || wide) cut.push(id + ": " + el.textContent.trim().slice(0, 40));
  }
  return cut;
})"""
"""Header items that do not fit the window or are cut (but those named in the argument, which
may end in an ellipsis) and a page wider than the window. Live, the badge detail is whole: on a
small screen its session id is hidden, not cut."""


def wait_for(what: str, cond: Callable[[], Any], timeout_s: float, poll_s: float = 0.05) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        value = cond()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s} s")
        time.sleep(poll_s)


@pytest.fixture
def chromium() -> Iterator[Chromium]:
    browser = Chromium()
    yield browser
    browser.close()


def test_dashboard_in_headless_chromium(
    tmp_path: Path, pty: Pty, daemons: list[Daemon], chromium: Chromium,
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    daemon_args = ("--port", str(pty.link), "--station", STATION,
                   "--out-dir", str(tmp_path / "out"), "--zenoh-listen", endpoint)
    daemon = Daemon(*daemon_args)
    daemons.append(daemon)
    http_port = free_port()
    dashboard = Daemon("--port", str(http_port), "--connect", endpoint, "--station", STATION,
                       "--station", "spare", command="dashboard")
    daemons.append(dashboard)
    daemon.wait_for("connected")
    daemon.wait_for("publishing on Zenoh")
    feeder = Feeder(pty)
    feeder.start()
    dashboard.wait_for("dashboard on http://")
    try:
        chromium.send("Page.navigate", {"url": f"http://127.0.0.1:{http_port}/"})

        # live, values update, the panels are drawn
        wait_for("page live", lambda: chromium.eval("document.body?.dataset.state") == "live", 15)
        t1 = chromium.eval("gsDashboard.doc.view.t_host_ns")
        wait_for("status moves on",
                 lambda: chromium.eval("gsDashboard.doc.view.t_host_ns") != t1, 3)
        # (the monitor learns the epoch rate from the first epochs: on a busy machine the
        # first statuses may come before it)
        wait_for("the epoch rate shown", lambda: chromium.eval(
            "document.getElementById('link-rate').textContent") != "-", 15)
        assert chromium.eval("document.getElementById('link-rate').textContent") == "5 Hz"
        n_sats = chromium.eval("gsDashboard.doc.view.sats.length")
        assert n_sats >= 5
        assert chromium.eval("document.querySelectorAll('#sky .sat-group').length") == n_sats
        assert chromium.eval("document.querySelectorAll('#cno rect.bar').length") == n_sats
        assert chromium.eval("document.querySelectorAll('#timeline rect.tl-ok').length") > 0
        options = chromium.eval("Array.from(document.querySelectorAll('#station option'))"
                                ".map(o => o.value)")
        assert options == [STATION, "spare"]
        wait_for("camera marks counted",
                 lambda: int(chromium.eval(
                     "document.getElementById('marks-count').textContent") or 0) >= 3, 20)
        assert chromium.eval("document.querySelectorAll('#timeline line.mark').length") >= 3
        assert chromium.eval("document.querySelectorAll('#timeline rect.dropout').length") == 0
        # the PPK-ready number says what it counts: the daemon's [monitor] clean_phase_s
        assert chromium.eval("document.getElementById('ppk-title').textContent") == \
            "PPK-ready (clean phase >= 30 s)"
        assert chromium.eval("document.getElementById('ppk-min').textContent") == "5"
        chromium.screenshot(tmp_path / "1-live.png")

        # a dropout in the stream: the page shows it while the stream is still silent (the
        # stream stays silent until it does: a condition on the page, not a time window that
        # a loaded machine misses)
        feeder.skipped_epochs = 0
        feeder.paused.set()
        wait_for("dropout on the timeline while the stream is silent", lambda: chromium.eval(
            "document.querySelectorAll('#timeline rect.dropout.ongoing').length"), 20, 0.02)
        assert "DROPOUT" in chromium.eval("document.getElementById('link-now').textContent")
        chromium.screenshot(tmp_path / "2-dropout.png")
        wait_for("a dropout of 2 s or more", lambda: feeder.skipped_epochs >= 10, 20)
        feeder.paused.clear()
        # the stream returns: the dropout stays on the timeline, closed, with its epochs
        wait_for("dropout closed", lambda: chromium.eval(
            "document.querySelectorAll('#timeline rect.dropout:not(.ongoing)').length"), 20)
        missing = chromium.eval(
            "Number(document.querySelector('#timeline rect.dropout').dataset.missing)")
        skipped = feeder.skipped_epochs
        assert abs(missing - skipped) <= 2, (missing, skipped)  # frames cut at either end

        # the daemon ends normally, an alert standing (the stream silent): "session finished",
        # not a red STALE / "daemon gone"; the station reads finished, not live, and the alerts
        # are shown as those at the end, not as live ones
        feeder.paused.set()
        wait_for("an alert raised", lambda: chromium.eval(
            "document.querySelectorAll('#alerts li:not(.none)').length") >= 1, 15)
        rc, _ = daemon.stop(signal.SIGTERM)
        assert rc == 0, daemon.stderr
        wait_for("finished", lambda: chromium.eval("document.body?.dataset.state") == "finished",
                 6)
        assert chromium.eval("document.getElementById('badge').textContent") == \
            "SESSION FINISHED"
        time.sleep(STALE_AFTER_S + 0.5)  # the selector ages between pushes too
        option = chromium.eval("document.querySelector('#station option').textContent")
        assert option.startswith(STATION) and "finished" in option, option
        assert "live" not in option and "stale" not in option and "⚠" not in option, option
        assert chromium.eval("document.getElementById('alerts-title').textContent") == \
            "Alerts at the end"
        n_alerts = chromium.eval("document.querySelectorAll('#alerts li.ended').length")
        assert n_alerts == len(chromium.eval("gsDashboard.doc.view.alerts")) >= 1
        assert chromium.eval("document.getElementById('alert-count').textContent").endswith(
            "at end")
        assert chromium.eval("document.body?.dataset.state") == "finished"
        assert "daemon gone" not in chromium.eval(
            "document.getElementById('badge-detail').textContent")
        # no frozen dropout, and not "receiving" either (it read so after the end, 2026-11-29)
        assert chromium.eval("document.getElementById('link-now').textContent") == "ended"
        chromium.screenshot(tmp_path / "3-finished.png")

        # the daemon comes back: live again, without reloading the page
        daemon = Daemon(*daemon_args)
        daemons.append(daemon)
        daemon.wait_for("connected")
        feeder.paused.clear()
        wait_for("live again", lambda: chromium.eval("document.body?.dataset.state") == "live",
                 20, 0.2)
        wait_for("marks of the new session", lambda: chromium.eval(
            "(m => m.received > 0 && Math.abs(m.received - m.marks) <= 1)"
            "(gsDashboard.doc.view.marks)"), 10)  # a mark may arrive before the status
        chromium.screenshot(tmp_path / "4-back.png")

        # the daemon dies (no "finished"): stale, and the daemon is gone
        daemon.kill()
        wait_for("stale", lambda: chromium.eval("document.body?.dataset.state") == "stale", 8)
        wait_for("daemon gone", lambda: "daemon gone" in chromium.eval(
            "document.getElementById('badge-detail').textContent"), 15)
        assert chromium.eval("document.getElementById('badge').textContent") == "STALE"
        chromium.screenshot(tmp_path / "5-stale.png")

        assert chromium.eval("gsDashboard.errors") == []
        assert chromium.console_errors() == []
    finally:
        feeder.stop()
        print(f"screenshots in {tmp_path}")
    dashboard.stop(signal.SIGTERM)
    assert dashboard.proc.returncode == 0, dashboard.stderr


@pytest.mark.parametrize(("width", "height"), [(1366, 768), (1024, 600), (1920, 1080)])
def test_alerts_visible_on_small_screens(
    tmp_path: Path, pty: Pty, daemons: list[Daemon], width: int, height: int,
) -> None:
    """A dropout long enough for alerts, with every panel drawn: the ALERTS panel lies inside
    the viewport at 1366x768, 1024x600 and 1920x1080, no panel text is cut, the header fits
    the window (no sideways scrolling, the clock whole) live and after the session finished
    (the widest badge). Screenshots go to $UX_SHOTS (default the tmp dir)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    daemon = Daemon("--port", str(pty.link), "--station", STATION,
                    "--out-dir", str(tmp_path / "out"), "--zenoh-listen", endpoint)
    daemons.append(daemon)
    http_port = free_port()
    dashboard = Daemon("--port", str(http_port), "--connect", endpoint, "--station", STATION,
                       command="dashboard")
    daemons.append(dashboard)
    daemon.wait_for("publishing on Zenoh")
    feeder = Feeder(pty)
    feeder.start()
    dashboard.wait_for("dashboard on http://")
    shots = Path(os.environ.get("UX_SHOTS") or tmp_path)
    shots.mkdir(parents=True, exist_ok=True)
    browser = Chromium(width, height)
    try:
        browser.send("Page.navigate", {"url": f"http://127.0.0.1:{http_port}/"})
        wait_for("page live", lambda: browser.eval("document.body?.dataset.state") == "live", 15)
        wait_for("satellites drawn", lambda: browser.eval(
            "document.querySelectorAll('#sky .sat-group').length") >= 5, 10)
        # a mark received: its panel shows the longest texts ("08:01:40.123  (3 s ago)")
        wait_for("a mark shown", lambda: "ago" in browser.eval(
            "document.getElementById('marks-last').textContent"), 30)
        feeder.drop(8.0)
        wait_for("an alert raised", lambda: browser.eval(
            "document.querySelectorAll('#alerts li:not(.none)').length") >= 1, 15)
        time.sleep(0.5)
        browser.screenshot(shots / f"dashboard-{width}x{height}-alert.png")
        box = browser.eval(
            "(() => { const r = document.getElementById('alerts-panel')"
            ".getBoundingClientRect(); return [r.top, r.bottom, r.left, r.right, "
            "window.innerWidth, window.innerHeight]; })()")
        top, bottom, left, right, vw, vh = box
        assert (vw, vh) == (width, height)
        assert top >= 0 and bottom <= vh and left >= 0 and right <= vw, box
        text = browser.eval("document.getElementById('alerts').textContent")
        assert "dropout" in text or "no data" in text, text
        # every line of the panels the operator reads in a glance is inside its panel
        small = width < 1100
        problems = browser.eval(f"{PANELS_CUT}({str(small).lower()})")
        problems += ["live " + h for h in browser.eval(f"{HEADER_CUT}([])")]
        # the session ends normally: SESSION FINISHED, the widest badge, still fits
        feeder.paused.set()
        rc, _ = daemon.stop(signal.SIGTERM)
        assert rc == 0, daemon.stderr
        wait_for("finished", lambda: browser.eval("document.body?.dataset.state") == "finished",
                 10)
        browser.screenshot(shots / f"dashboard-{width}x{height}-finished.png")
        # (its explanation may end in an ellipsis: its whole text is in its title)
        problems += ["finished " + h for h in browser.eval(f"{HEADER_CUT}(['badge-detail'])")]
        assert problems == [], f"text cut at {width}x{height}: {problems}"
        assert browser.eval("document.getElementById('badge-detail').title").startswith(
            "the daemon ended the session normally")
        assert browser.console_errors() == []
    finally:
        browser.close()
        feeder.stop()
    dashboard.stop(signal.SIGTERM)
