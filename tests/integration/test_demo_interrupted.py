"""An interrupted demo: the summary, then exit status 130 (README: "130 interrupted"; the
daemon commands, not the demo, take Ctrl-C as their normal end), and no "next: ... solve"
line for a flight cut short before its first mark."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from peers import cli_env


def test_a_demo_interrupted_before_its_first_mark_exits_130_and_says_it_was_cut_short(
        tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "demo", "--flight", "600", "--speed", "1",
         "--no-zenoh", "--no-view"],
        cwd=tmp_path, env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not list((tmp_path / "flights").glob("*.mcap")) and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)  # a few epochs of the static start: no mark yet
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert "next: groundstation solve" not in out, out
    assert "the flight was cut short (SIGINT after " in out, out
