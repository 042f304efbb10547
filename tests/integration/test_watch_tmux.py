"""``groundstation watch`` in a real 80x24 terminal (tmux): ALERTS on screen, not cut off.

The daemon reads a pty fed with the simulated stream for a few seconds, then the feed stops:
``no data`` and the dropout alert are raised while the satellite table is full. The watch runs
inside a detached tmux session of exactly 80 columns and 24 lines; ``capture-pane`` is what a
field user would see.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from peers import REPO, Daemon, Pty, free_port

from groundstation.pacing import paced
from groundstation.sim.stream import SimConfig, simulate

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None,
                                reason="tmux not installed (apt-get install tmux)")


def _feed(pty: Pty, seconds: float) -> None:
    sim = simulate(SimConfig(duration_s=200, with_base=False))
    t0 = sim.rover_chunks[0][0]
    chunks = [c for c in sim.rover_chunks if t0 + 100e9 <= c[0] < t0 + (100 + seconds) * 1e9]
    for _, chunk in paced(chunks, 1.0):
        with contextlib.suppress(OSError):
            pty.write(chunk)


def test_watch_at_80x24_shows_alerts(tmp_path: Path, pty: Pty, daemons: list[Daemon]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    daemon = Daemon("--port", str(pty.link), "--station", "tm", "--out-dir", str(tmp_path),
                    "--zenoh-listen", endpoint)
    daemons.append(daemon)
    daemon.wait_for("publishing on Zenoh")
    feeder = threading.Thread(target=_feed, args=(pty, 6.0), daemon=True)
    feeder.start()
    session = f"gs-watch-{os.getpid()}"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join((str(REPO), os.environ.get(
        "PYTHONPATH", ""))), "TERM": "xterm-256color"}
    cmd = (f"{sys.executable} -m groundstation.cli watch --station tm --connect {endpoint} "
           "--duration 40")
    subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", "80", "-y", "24", cmd],
                   check=True, env=env, cwd=REPO)
    try:
        deadline = time.monotonic() + 30
        screen = ""
        while time.monotonic() < deadline:
            screen = subprocess.run(["tmux", "capture-pane", "-p", "-t", session],
                                    capture_output=True, text=True, check=False).stdout
            if "no data from the source" in screen and "G" in screen:
                break
            time.sleep(0.5)
        (tmp_path / "watch-80x24.txt").write_text(screen)
        lines = screen.splitlines()
        assert len(lines) <= 24 and all(len(x) <= 80 for x in lines)
        assert any("ALERTS" in x for x in lines), screen
        assert "no data from the source" in screen, screen
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], check=False,
                       capture_output=True)
        feeder.join(timeout=10)
