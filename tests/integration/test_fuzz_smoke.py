"""The fuzz benchmark, small: a few thousand seeded cases must raise nothing and keep every
framer invariant (the full run of 100 000 cases is in benchmarks/RESULTS.md)."""

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
