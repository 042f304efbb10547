"""Marks are numbered by the receiver's own count, the one u-center and RTKLIB's event list show
(the count of the pulse's falling-edge record): the same number in inspect, marks.csv,
cameras.csv and the ``mark_NNNN`` names, on a real recording (jdesbonnet 2018-10-09)."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
from peers import cli_env

from groundstation.offline.rinex import read_obs3

pytestmark = pytest.mark.shared_data

ROVER = "real/jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz"
POS = "reference/rnx2rtkp_pos/jd_20181009_kin_vs_M8Pbase_svin.pos.gz"
TABLE = "reference/timtm2_tables/rover-20181009-1221.timtm2.csv"


def _cli(cwd: Path, *argv: str) -> str:
    proc = subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], cwd=cwd,
                          env=cli_env(), capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL, check=False)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(ln for ln in path.read_text().splitlines()
                               if not ln.startswith("#")))


def test_marks_are_numbered_by_the_receivers_count(shared_data: Path, tmp_path: Path) -> None:
    rover, table = shared_data / ROVER, shared_data / TABLE
    if not table.exists():
        pytest.skip(f"{table} is absent")
    # RTKLIB's event records: the count of each record with a new falling edge.
    records = _rows(table)
    rtklib = [int(r["count"]) for r in records if r["newFallingEdge"] == "1"]
    assert rtklib[0] == 0 and len(rtklib) == 589

    text = _cli(tmp_path, "inspect", str(rover))
    assert f"count {rtklib[0]} .. {rtklib[-1]} " in text

    _cli(tmp_path, "rinex", str(rover), "-o", "rx")
    (marks_csv,) = (tmp_path / "rx").glob("*.marks.csv")
    assert [int(r["count"]) for r in _rows(marks_csv)] == rtklib

    _cli(tmp_path, "solve", "--no-pdf",
         str(rover), "--positions", str(shared_data / POS), "--out-dir", "s",
         "--no-progress")
    cameras = _rows(tmp_path / "s" / "cameras.csv")
    assert [int(r["mark_count"]) for r in cameras] == rtklib
    geo = (tmp_path / "s" / "geo.txt").read_text().splitlines()[1:]
    assert [ln.split()[0] for ln in geo] == [f"mark_{n:04d}" for n in rtklib]


def test_marks_through_a_lossy_link_keep_their_pulses_numbers(shared_data: Path,
                                                              tmp_path: Path) -> None:
    """The same flight replayed as a LEA-6T through the seed link (fault seed 7): every mark
    that arrives has the number and falling edge of the same pulse as in the untouched
    recording. The camera's pulse rises first and lasts 1 s, two records each, and the link
    often cuts between them: a later pulse's rising-edge record completed the open mark
    before, and 13 photos took the pulse before theirs."""
    from groundstation.sim.faults import FaultConfig
    from groundstation.sim.rewrite import RewriteConfig, rewrite

    rover = shared_data / ROVER
    replay = tmp_path / "replay.ubx"
    replay.write_bytes(rewrite(rover, RewriteConfig(faults=FaultConfig.seed(), seed=7)).data)
    _cli(tmp_path, "rinex", str(rover), "-o", "untouched")
    text = _cli(tmp_path, "rinex", str(replay), "-o", "replay")
    (truth_csv,) = (tmp_path / "untouched").glob("*.marks.csv")
    truth = {r["count"]: r["falling_gps_tow_s"] for r in _rows(truth_csv)}
    got = _rows(tmp_path / "replay" / "replay.marks.csv")
    assert len(got) > 0.9 * len(truth)
    assert [(r["count"], r["falling_gps_tow_s"]) for r in got
            if truth.get(r["count"]) != r["falling_gps_tow_s"]] == []
    # RTKLIB would drop epochs after the marks that follow the link's gaps: said, and avoidable
    assert "come where the epochs' spacing changed (radio gaps)" in text
    _cli(tmp_path, "rinex", str(replay), "-o", "bare", "--no-events")
    _, epochs = read_obs3(tmp_path / "bare" / "replay.obs")
    assert epochs and all(ep.flag == 0 for ep in epochs)
    assert len(_rows(tmp_path / "bare" / "replay.marks.csv")) == len(got)
