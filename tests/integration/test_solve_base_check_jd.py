"""Wrong base coordinates and a base of another day, on a real flight (jdesbonnet 2018-10-09).

The surveyor's mistakes: ``--base-xyz`` of the 2018-10-04 base (5 km away) with the 2018-10-09
base recording is refused before the engine runs, with one line naming ``--base-xyz``, the
distance and where the base receiver's own fixes put the base (exit 2, nothing written). The
right coordinates of the 2018-10-04 base with that day's base recording pass the check, but the
engine positions nothing (the recordings do not overlap in time): one line saying so in the
user's terms, exit 1, nothing written.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from peers import cli_env

pytestmark = pytest.mark.shared_data

JD = "real/jdesbonnet__GNSS_RTK_data"
ROVER_1009 = "20181009/rover-20181009-1221.ubx.gz"
BASE_1009 = "20181009/base-20181009-1220.ubx.gz"
BASE_1004 = "20181004/base-20181004-1236.ubx.gz"
XYZ_1004 = "3774090.1383,-601663.0449,5089319.1992"  # the 2018-10-04 base, 5 km from 10-09's


def _solve(cwd: Path, data: Path, base: str, xyz: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "solve", str(data / JD / ROVER_1009),
         "--base", str(data / JD / base), "--base-xyz", xyz, "--out-dir", "out",
         "--no-progress"],
        cwd=cwd, env=cli_env(), capture_output=True, text=True, timeout=600, check=False)


def test_another_days_base_coordinates_are_refused_before_the_engine(
        shared_data: Path, tmp_path: Path) -> None:
    proc = _solve(tmp_path, shared_data, BASE_1009, XYZ_1004)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert len(lines) == 1, proc.stderr
    assert "--base-xyz: 5.05 km from where the base receiver's own" in lines[0], lines[0]
    assert "3774696.6,-596647.9,5089485.7" in lines[0]  # what the receiver's fixes say
    assert "no solution rows" not in proc.stderr and "dynamics" not in proc.stderr
    assert not (tmp_path / "out").exists()


def test_an_engine_that_positions_nothing_says_so_and_exits_1(
        shared_data: Path, tmp_path: Path) -> None:
    proc = _solve(tmp_path, shared_data, BASE_1004, XYZ_1004)
    assert proc.returncode == 1, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    said = ("engine positioned no epoch of rover-20181009-1221.ubx.gz against the base "
            "base-20181004-1236.ubx.gz")
    assert said in last, proc.stderr
    assert "overlap in time" in last and "--base-xyz" in last
    assert not last.endswith("no solution rows")  # not the .pos parser's words
    assert not (tmp_path / "out").exists()
