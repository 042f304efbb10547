"""A solve that fails after it started writing leaves no half outputs in its directory.

The command line, in a subprocess, on a flight whose engine run fails after the rover and base
were converted to RINEX (``good.ubx`` and ``base.ubx`` hold observations but no ephemerides): a
directory the
run created is gone; in a directory that existed, everything is as it was, byte for byte (the
run wrote into a staging folder, removed with it), and no failure note or staging folder is
left.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from peers import cli_env
from streams import flight_stream

BASE_XYZ = "4146349.2471,612312.5498,4791750.8505"


def _solve(cwd: Path, out: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "solve", "good.ubx", "--base", "base.ubx",
         "--base-xyz", BASE_XYZ, "--out-dir", out, "--no-progress"],
        cwd=cwd, env=cli_env(), capture_output=True, text=True, timeout=120, check=False)


def _workspace(root: Path) -> None:
    data, _ = flight_stream(10)
    (root / "good.ubx").write_bytes(data)
    # another receiver (its clock 300 m off), no ephemerides either: the engine fails
    (root / "base.ubx").write_bytes(flight_stream(10, pr_offset_m=300.0)[0])


def test_a_failed_run_removes_the_directory_it_created(tmp_path: Path) -> None:
    _workspace(tmp_path)
    proc = _solve(tmp_path, "new/out")
    assert proc.returncode == 1 and "no navigation data" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "new" / "out").exists()
    assert (tmp_path / "new").is_dir()  # the parent was created by mkdir -p; not ours to judge


def test_a_failed_run_in_an_existing_directory_keeps_the_earlier_files(tmp_path: Path) -> None:
    _workspace(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "cameras.csv").write_text("earlier run\n")
    proc = _solve(tmp_path, "out")
    assert proc.returncode == 1, proc.stderr
    assert sorted(p.name for p in out.rglob("*")) == ["cameras.csv"]  # rtklib/ removed
    assert (out / "cameras.csv").read_text() == "earlier run\n"


def test_a_failed_run_leaves_an_earlier_result_untouched(tmp_path: Path) -> None:
    _workspace(tmp_path)
    out = tmp_path / "out"
    (out / "rtklib" / "rover").mkdir(parents=True)
    earlier = {"rtklib/rover/good.obs": "earlier run\n", "geo.txt": "earlier geo\n",
               "report.pdf": "earlier report\n"}
    for rel, text in earlier.items():
        (out / rel).write_text(text)
    proc = _solve(tmp_path, "out")
    assert proc.returncode == 1 and "no navigation data" in proc.stderr, proc.stderr
    left = {p.relative_to(out).as_posix(): p.read_text() for p in out.rglob("*") if p.is_file()}
    assert left == earlier  # nothing rewritten, nothing added (no SOLVE_FAILED.txt, no stage)
    assert sorted(p.name for p in out.iterdir()) == ["geo.txt", "report.pdf", "rtklib"]
