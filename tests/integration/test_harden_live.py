"""Real processes, real ptys, real Zenoh on loopback: the station is not blinded or fooled.

- The out dir deleted mid-session (with and without rotation): ``recorder.vanished`` on the bus
  and in the log, and every frame sent after the deletion in the new parts.
- The device path re-pointed to a new device while the old tty stays open: the daemon notices
  and records the new device's bytes within 3 s.
- Two daemons with one station name: both raise the ``station_conflict`` alert.
- Poison time marks, events and statuses on the bus: the dashboard (real server, real Zenoh) and
  ``watch`` (a real process) keep working and count the bad messages.
"""

from __future__ import annotations

import http.client
import json
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from peers import Daemon, Pty, Received, free_port, wait_until
from poison import POISON
from statuses import drawn_status, run_watch
from streams import epoch_with_mark

from groundstation import jsonio
from groundstation.bus import Bus, decode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.sim.ptylink import PtyLink
from groundstation.storage.reading import Recording, part_info
from groundstation.ubx.build import build_frame
from groundstation.ubx.framer import UbxFramer
from groundstation.view.dashboard.server import Dashboard, DashboardSettings

WEEK = 2300
TOW0_MS = 400_000_000
SATS = [(3, 0), (7, 0), (11, 2), (19, 0), (23, 0), (27, 0)]


class Feeder:
    """A simulated receiver on a pty: 5 Hz epochs written in a thread until closed (the old
    device keeps talking); keeps every piece it wrote, in order.

    ``period_s`` is the pause between epochs: 0.2 is real time, 0.02 ten times that (so a
    rotation holds many). ``marks``: a time mark with every fifth epoch.
    """

    def __init__(self, link: PtyLink, period_s: float = 0.2, marks: bool = False) -> None:
        self.link = link
        self.period_s = period_s
        self.marks = marks
        self.sent: list[bytes] = []
        self.lock = threading.Lock()  # a piece is written and counted at once
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        k = 0
        while not self.stop.is_set():
            mark = k // 5 if self.marks and k % 5 == 0 else None
            data = epoch_with_mark(k, mark, SATS, WEEK, TOW0_MS)
            with self.lock:
                try:
                    self.link.write(data)
                except OSError:
                    return
                self.sent.append(data)
            k += 1
            time.sleep(self.period_s)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)


def test_repointed_device_path_is_reopened_and_recorded_within_3_s(
    tmp_path: Path, pty: Pty, daemons: list[Daemon],
) -> None:
    conf = tmp_path / "fast.toml"
    conf.write_text("[recorder]\nflush_interval_s = 0.2\n")
    out = tmp_path / "out"
    d = Daemon("--port", str(pty.link), "--station", "rp", "--out-dir", str(out), "--no-zenoh",
               "--config", str(conf))
    daemons.append(d)
    d.wait_for("connected")
    old = Feeder(pty)
    new = PtyLink()  # the new adapter; the old pty stays open and keeps sending
    try:
        time.sleep(1.5)
        marker = build_frame(0x7F, 0x42, b"NEW-DEVICE-" + os.urandom(8).hex().encode())
        tmp_link = pty.link.with_suffix(".repoint")
        os.symlink(os.ttyname(new.slave), tmp_link)
        os.replace(tmp_link, pty.link)  # udev moves the symlink
        t0 = time.monotonic()
        found = threading.Event()

        def feed_new() -> None:
            while not found.is_set():
                new.write(marker)
                time.sleep(0.1)

        writer = threading.Thread(target=feed_new, daemon=True)
        writer.start()

        def recorded() -> bool:
            return any(marker in p.read_bytes() for p in out.glob("*.ubx"))

        try:
            wait_until(recorded, timeout_s=3.0)
        finally:
            found.set()
            writer.join(timeout=2)
        elapsed = time.monotonic() - t0
        print(f"new device recorded {elapsed:.2f} s after the path was re-pointed")
        assert "now names another device" in d.stderr
        rc, _ = d.stop()
        assert rc == 0, d.stderr
    finally:
        d.kill()  # (gone already unless the test failed) before its ptys close
        old.close()
        new.close()


def _frames(data: bytes) -> list[bytes]:
    return [f.raw for f in UbxFramer().feed(data, 0)]


@pytest.mark.parametrize("rotate", [False, True], ids=["one_file", "rotating"])
def test_out_dir_deleted_mid_session_alerts_and_loses_nothing_after(
    tmp_path: Path, pty: Pty, daemons: list[Daemon], rotate: bool,
) -> None:
    conf = tmp_path / "rec.toml"
    conf.write_text("[recorder]\nflush_interval_s = 0.2\n"
                    + ("rotate_duration_s = 1.0\n" if rotate else ""))
    out = tmp_path / "out"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    zenoh = ["--no-zenoh"] if rotate else ["--zenoh-listen", endpoint]
    d = Daemon("--port", str(pty.link), "--station", "vd", "--out-dir", str(out),
               "--config", str(conf), *zenoh)
    daemons.append(d)
    d.wait_for("publishing on Zenoh" if not rotate else "connected")
    seen: list[dict[str, Any]] = []
    bus = None if rotate else open_bus(ZenohSettings(listen=(), connect=(endpoint,)))
    if bus is not None:
        for leaf in ("event", "session"):
            bus.subscribe(key("vd", leaf), lambda _k, payload: seen.append(decode(payload)))
    feeder = Feeder(pty, period_s=0.02, marks=True)
    try:
        wait_until(lambda: len(feeder.sent) > 100 and len(list(out.glob("*.mcap"))) >= 1
                   + rotate, timeout_s=20, what="a recording under way")
        old = sorted(out.glob("*"))
        with feeder.lock:
            before = len(feeder.sent)
        shutil.rmtree(out)
        with feeder.lock:
            after = len(feeder.sent)  # every piece from here on is written after the deletion
        # The daemon looks at every flush (0.2 s here). Generous all the same: one full suite
        # run on a quiet machine failed at 10 s with the daemon rotating its parts in the
        # deleted directory's place and no alert; not seen again in 16 runs under a hog. The
        # counts say whether the feeder stalled, if it fails again.
        try:
            d.wait_for("the recording vanished", timeout_s=30)
        except AssertionError as err:
            with feeder.lock:
                now = len(feeder.sent)
            raise AssertionError(f"{err}\nfeeder: {before} pieces before the deletion, "
                                 f"{after} after it, {now} now") from None
        wait_until(lambda: len(feeder.sent) > after + 100, timeout_s=20)
    finally:
        feeder.close()
    sent = feeder.sent
    tail = b"".join(sent[after:])

    def new_parts() -> bytes:
        first = min(out.glob("*.mcap"), key=lambda p: getattr(part_info(p), "part", 0))
        return b"".join(c for c, _ in Recording(first).chunks())

    # the daemon has recorded the last piece (MCAP flushed), then stops in order
    wait_until(lambda: new_parts().endswith(sent[-1]), timeout_s=10, what="all recorded")
    rc, stdout = d.stop()
    assert rc == 0, d.stderr
    assert "Traceback" not in d.stderr and "cannot write None" not in d.stderr
    got = new_parts()
    print(f"deleted after {before}-{after} of {len(sent)} pieces; new parts hold "
          f"{len(got)} bytes, {len(_frames(got))} frames")
    # every frame sent after the deletion is in the new parts, in order, byte for byte
    assert got.endswith(tail)
    assert len(_frames(got)) >= len(_frames(tail))
    assert _frames(got)[-len(_frames(tail)):] == _frames(tail)
    # the summary names only files that exist, and the deleted ones as lost
    wrote = [Path(line.split("wrote ", 1)[1]) for line in stdout.splitlines()
             if line.strip().startswith("wrote ")]
    lost = [Path(line.split("lost ", 1)[1].split(" (")[0]) for line in stdout.splitlines()
            if line.strip().startswith("lost ")]
    assert wrote and all(p.exists() for p in wrote), stdout
    assert {p.name for p in old} <= {p.name for p in lost}, stdout
    assert not any(p.exists() and p in wrote for p in lost)
    if rotate:
        assert len([p for p in wrote if p.suffix == ".mcap"]) >= 2  # rotated after, too
    if bus is not None:
        try:
            wait_until(lambda: any(m.get("kind") == "recorder.vanished" for m in seen),
                       timeout_s=5, what="recorder.vanished on the bus")
            assert any(m.get("kind") == "alert.raised"
                       and (m.get("data") or {}).get("alert") == "recording_failed"
                       for m in seen)
            # the session's last word names the files a solver can find, not the lost ones
            wait_until(lambda: any(m.get("type") == "session" and m.get("state") == "finished"
                                   for m in seen), timeout_s=5, what="session finished")
            final = next(m for m in seen if m.get("type") == "session"
                         and m.get("state") == "finished")
            assert final["files"] and all(Path(f).exists() for f in final["files"]), final
        finally:
            bus.close()


def test_two_daemons_with_one_station_name_both_alert(
    tmp_path: Path, pty: Pty, daemons: list[Daemon],
) -> None:
    second = Pty(tmp_path / "ttyGS1")
    e1, e2 = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    try:
        d1 = Daemon("--port", str(pty.link), "--station", "dup", "--out-dir",
                    str(tmp_path / "o1"), "--zenoh-listen", e1)
        daemons.append(d1)
        d1.wait_for("publishing on Zenoh")
        d2 = Daemon("--port", str(second.link), "--station", "dup", "--out-dir",
                    str(tmp_path / "o2"), "--zenoh-listen", e2, "--zenoh-connect", e1)
        daemons.append(d2)
        d2.wait_for("publishing on Zenoh")
        feeders = [Feeder(pty), Feeder(second)]
        bus = open_bus(ZenohSettings(listen=(), connect=(e1, e2)))
        got = Received(bus, key("dup", "**"))
        try:
            def conflicts() -> set[str]:
                return {m["data"]["instance"] for m in got.all()
                        if m.get("type") == "event" and m.get("kind") == "station.conflict"}

            def alerted() -> set[str]:
                """The daemons (by their out dir) whose status carries the alert."""
                return {Path(str((m.get("recording") or {}).get("file"))).parent.name
                        for m in got.all() if m.get("type") == "status"
                        and any("station_conflict" in a for a in m.get("alerts") or [])}

            # both daemons may have raised the event before this subscriber joined: the
            # alert in every status is what the views show
            wait_until(lambda: alerted() >= {"o1", "o2"} or len(conflicts()) == 2,
                       timeout_s=20)
            assert "another daemon publishes as station 'dup'" in d1.stderr + d2.stderr

            def session_ids() -> dict[str, object]:
                return {Path(str((m.get("recording") or {}).get("file"))).parent.name:
                        m.get("session_id") for m in got.all() if m.get("type") == "status"
                        and m.get("session_id")}

            # one station name, two sessions: never one id for both
            wait_until(lambda: {"o1", "o2"} <= set(session_ids()), timeout_s=10)
            sids = session_ids()
            assert sids["o1"] != sids["o2"], sids
        finally:
            bus.close()
            for f in feeders:
                f.close()
        for d in (d2, d1):
            rc, _ = d.stop()
            assert rc == 0, d.stderr
        assert "station.conflict" in d1.stderr or "another daemon" in d1.stderr
        assert "another daemon" in d2.stderr
    finally:
        second.close()


def _snapshot(dash: Dashboard) -> dict[str, Any]:
    host, port = dash.http.server_address[:2]
    conn = http.client.HTTPConnection(str(host), int(port), timeout=5)
    try:
        conn.request("GET", "/api/snapshot?station=p")
        doc: dict[str, Any] = json.loads(conn.getresponse().read())
        return doc
    finally:
        conn.close()


def test_poison_on_the_bus_is_counted_by_the_dashboard_and_watch(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pub: Bus = open_bus(ZenohSettings(listen=(endpoint,), connect=()))
    client = ZenohSettings(listen=(), connect=(endpoint,))
    dash = Dashboard(DashboardSettings(stations=("p",), port=0, bus=client))
    dash.start()
    stop = threading.Event()

    def talk() -> None:  # a good status every 0.3 s, the poison after each
        while not stop.is_set():
            pub.put(key("p", "status"), drawn_status(time.time_ns()))
            for k, payload in POISON:
                pub.put(k.replace("/st/", "/p/"), payload)
            time.sleep(0.3)

    talker = threading.Thread(target=talk, daemon=True)
    talker.start()
    try:
        watch = run_watch(endpoint, 4, tmp_path / "watch.txt")
        assert watch.returncode == 0, watch.stderr
        assert "Traceback" not in watch.stderr
        assert "LIVE" in watch.stdout and "G05" in watch.stdout
        assert "bad messages dropped" in watch.stdout
        wait_until(lambda: (_snapshot(dash)["view"] or {}).get("rejected", 0) >= len(POISON))
        doc = _snapshot(dash)
        view = doc["view"]
        assert view["has_status"] and not view["stale"] and view["sats"][0]["sv"] == "G05"
        assert view["rejected"] >= len(POISON)
        jsonio.dumps(doc)
    finally:
        stop.set()
        talker.join(timeout=5)
        dash.close()
        pub.close()


@pytest.mark.slow
@pytest.mark.skipif(not Path("/usr/bin/chromium").exists(),
                    reason="headless Chromium not installed (apt-get install chromium)")
def test_poison_does_not_break_the_page_in_chromium(tmp_path: Path) -> None:
    from test_dashboard_chromium import Chromium, wait_for

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pub: Bus = open_bus(ZenohSettings(listen=(endpoint,), connect=()))
    dash = Dashboard(DashboardSettings(stations=("p",), port=0,
                                       bus=ZenohSettings(listen=(), connect=(endpoint,))))
    dash.start()
    stop = threading.Event()

    def talk() -> None:
        while not stop.is_set():
            pub.put(key("p", "status"), drawn_status(time.time_ns()))
            for k, payload in POISON:
                pub.put(k.replace("/st/", "/p/"), payload)
            time.sleep(0.3)

    talker = threading.Thread(target=talk, daemon=True)
    talker.start()
    browser = Chromium()
    try:
        port = dash.http.server_address[1]
        browser.send("Page.navigate", {"url": f"http://127.0.0.1:{port}/?station=p"})
        wait_for("page live", lambda: browser.eval("document.body?.dataset.state") == "live", 15)
        wait_for("bad messages shown", lambda: "bad messages dropped" in (browser.eval(
            "document.getElementById('rejected').textContent") or ""), 10)
        # the page's own guard: a document with an event at 1e30 ns and nonsense satellites,
        # drawn and read in one evaluation (the next snapshot, 0.3 s away, redraws the events)
        errors, events = browser.eval(
            "render(Object.assign({}, gsDashboard.doc, {view: Object.assign({}, "
            "gsDashboard.doc.view, {events: [{t_host_ns: 1e30, kind: 'x', "
            "message: 'm'}], sats: 'bogus'})})); "
            "[gsDashboard.renderErrors, document.getElementById('events').textContent]")
        assert errors >= 1
        assert "--:--:--" in events
        n = browser.eval("gsDashboard.updates")
        wait_for("next snapshot drawn", lambda: browser.eval("gsDashboard.updates") > n, 5)
        wait_for("sky drawn again", lambda: browser.eval(
            "document.querySelectorAll('#sky .sat-group').length") == 1, 5)
        assert browser.eval("document.body.dataset.state") == "live"
        assert browser.console_errors() == [], browser.console_errors()
        browser.screenshot(tmp_path / "poisoned.png")
    finally:
        browser.close()
        stop.set()
        talker.join(timeout=5)
        dash.close()
        pub.close()
