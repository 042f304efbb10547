"""Two processes on loopback: the daemon publishes on Zenoh, this test subscribes.

Every time mark arrives (count continuity), status comes at 1 Hz, a late joiner gets all earlier
marks from the queryable, and `groundstation watch` shows the station and then that it is stale.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from peers import REPO, Daemon, Pty, Received, Screen, cli_env, free_port, wait_until
from streams import epoch_with_mark

from groundstation.bus import Bus, decode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.view.watch import STALE_AFTER_S

STATION = "zt"
WEEK = 2300
TOW0_MS = 400_000_000
SATS = [(3, 0), (7, 0), (11, 2), (19, 0), (23, 0), (27, 0)]


class Collector(Received):
    """Every message of the station, by its type."""

    def __init__(self, bus: Bus) -> None:
        super().__init__(bus, key(STATION, "**"))

    def of(self, kind: str) -> list[dict[str, object]]:
        return self.all(lambda m: m.get("type") == kind)


def start_daemon(tmp_path: Path, pty: Pty, daemons: list[Daemon], endpoint: str) -> Daemon:
    d = Daemon("--port", str(pty.link), "--station", STATION, "--out-dir", str(tmp_path / "out"),
               "--zenoh-listen", endpoint)
    daemons.append(d)
    d.wait_for("connected")
    d.wait_for("publishing on Zenoh")
    return d


def fly(pty: Pty, epochs: int) -> None:
    """5 Hz epochs in real time, a camera mark in every other epoch."""
    for k in range(epochs):
        pty.write(epoch_with_mark(k, k // 2 if k % 2 == 0 else None, SATS, WEEK, TOW0_MS))
        time.sleep(0.2)


@pytest.mark.slow
def test_marks_status_and_late_joiner(tmp_path: Path, pty: Pty, daemons: list[Daemon]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    d = start_daemon(tmp_path, pty, daemons, endpoint)
    bus = open_bus(ZenohSettings(listen=(), connect=(endpoint,)))
    try:
        col = Collector(bus)
        wait_until(lambda: bus.get(key(STATION, "q/status"), timeout_s=1.0) or col.of("status"))
        fly(pty, 40)
        wait_until(lambda: len(col.of("timemark")) >= 20, timeout_s=5)
        marks = col.of("timemark")
        assert [m["count"] for m in marks] == list(range(20))
        assert [m["index"] for m in marks] == list(range(20))
        assert all(m["schema"] == 1 and m["station"] == STATION for m in marks)
        # mark 3 was written in epoch 6: falling edge 40 ms + 6000 ns after it
        assert marks[3]["falling_t_gps_ns"] == WEEK * 604_800 * 10**9 + (TOW0_MS + 1240) * 10**6 \
            + 6000
        # the status after the last mark (the monitor states it at its next 1 s tick, once the
        # burst holding the mark reached it: up to a few hundred ms after the subscriber)
        wait_until(lambda: col.of("status")[-1]["marks"]["marks"] == 20,  # type: ignore[index]
                   timeout_s=5)
        statuses = col.of("status")
        times = [int(s["t_host_ns"]) for s in statuses]  # type: ignore[call-overload]
        gaps = [(b - a) / 1e9 for a, b in zip(times, times[1:], strict=False)]
        assert len(statuses) >= 6
        assert all(0.8 <= g <= 1.3 for g in gaps), gaps
        last = statuses[-1]
        assert last["marks"]["marks"] == 20  # type: ignore[index]
        assert last["link"]["epoch_interval_s"] == 0.2  # type: ignore[index]
        assert {s["sv"] for s in last["sats"]} == {"G03", "G07", "G11", "G19", "G23", "G27"}  # type: ignore[attr-defined]
    finally:
        bus.close()

    late = open_bus(ZenohSettings(listen=(), connect=(endpoint,)))
    try:
        wait_until(lambda: late.get(key(STATION, "q/status"), timeout_s=1.0))
        replies = late.get(key(STATION, "q/timemarks"), timeout_s=3.0)
        assert [decode(p)["count"] for _, p in replies] == list(range(20))
        col2 = Collector(late)
        wait_until(lambda: col2.of("status"), 5, "a status through the late subscription")
        rc, _ = d.stop(signal.SIGTERM)
        assert rc == 0, d.stderr
        wait_until(lambda: any(s.get("state") == "finished" for s in col2.of("session")), 5)
        fin = next(s for s in col2.of("session") if s.get("state") == "finished")
        assert fin["marks"] == 20
        assert str(fin["files"][0]).endswith(".mcap")  # type: ignore[index]
    finally:
        late.close()


@pytest.mark.slow
def test_watch_shows_live_then_stale(tmp_path: Path, pty: Pty, daemons: list[Daemon]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    d = start_daemon(tmp_path, pty, daemons, endpoint)
    flight = threading.Thread(target=fly, args=(pty, 25), daemon=True)
    flight.start()
    watch = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "watch", "--station", STATION,
         "--connect", endpoint, "--duration", "4"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={"COLUMNS": "120", "PATH": "/usr/bin:/bin"},
    )
    out, err = watch.communicate(timeout=30)
    assert watch.returncode == 0, err
    (tmp_path / "watch-live.txt").write_text(out)
    assert "LIVE" in out and "STALE" not in out
    for text in ("LINK", "5 Hz", "G03", "G11", "PPK-ready", "MARKS", "ALERTS"):
        assert text in out, text
    flight.join()
    # The second watch draws on a real terminal, so the test sees when it shows the station
    # live and stops the daemon only then (a fixed 2 s was too short for a watch starting on
    # a loaded machine: it came up after the daemon had gone).
    master, slave = os.openpty()
    watch = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "watch", "--station", STATION,
         "--connect", endpoint],
        cwd=REPO, stdin=subprocess.DEVNULL, stdout=slave, stderr=subprocess.PIPE, text=True,
        env=cli_env(TERM="xterm-256color", COLUMNS="120", LINES="40"),
    )
    os.close(slave)
    screen = Screen(master)
    try:
        wait_until(lambda: "LIVE" in screen.text(), 60, "the watch showing the station live")
        shown = len(screen.text())
        rc, _ = d.stop(signal.SIGTERM)
        assert rc == 0
        wait_until(lambda: "SESSION FINISHED" in screen.text()[shown:], 30,
                   "the watch showing the session finished")
        # as long again as a silence takes to turn the screen STALE: a finished session stays
        # finished, never "daemon gone"
        time.sleep(STALE_AFTER_S)
    finally:
        watch.send_signal(signal.SIGINT)  # Ctrl-C: the watch draws its last screen and exits
        _, err = watch.communicate(timeout=30)
        screen.close()
    out = screen.text()[shown:]
    (tmp_path / "watch-stale.txt").write_text(out)
    assert watch.returncode == 0, err
    # A normal end (SIGTERM): the daemon said "finished", so no red STALE / "daemon gone".
    assert "SESSION FINISHED" in out and "daemon gone" not in out
