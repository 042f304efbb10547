"""The fuzz benchmarks, small: ``fuzz_framer.py`` (a few thousand seeded cases must raise nothing
and keep every framer invariant) and ``fuzz_valid_frames.py`` (valid-checksum frames with random
field values of every decoded type in a short simulated flight, live through a pty into
``groundstation run`` and offline through every command: no exit, no hang, no internal error,
every byte recorded, every mark on Zenoh). The full runs are in benchmarks/RESULTS.md."""

from __future__ import annotations

import subprocess
import sys

from peers import REPO


def test_fuzz_framer_and_decoder_smoke() -> None:
    proc = subprocess.run(
        [sys.executable, "benchmarks/fuzz_framer.py", "--cases", "3000", "--seed", "5",
         "--sim-s", "60"],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "cases: 3000 in" in proc.stdout
    assert "exceptions escaped: 0" in proc.stdout


def test_fuzz_valid_frames_live_and_offline_smoke() -> None:
    proc = subprocess.run(
        [sys.executable, "benchmarks/fuzz_valid_frames.py", "--per-type", "300", "--flight-s",
         "20", "--speed", "16", "--seed", "3", "--no-ppk", "--timeout-s", "120"],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "all checks passed" in proc.stdout, proc.stdout
    assert "3,300 fuzz frames of 11 types" in proc.stdout
