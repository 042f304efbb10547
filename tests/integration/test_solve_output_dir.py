"""A solve's outputs in its directory are one run's, whole.

The command line, in a subprocess, on a short simulated flight solved with the receiver's own
fix (no engine: a run of a few seconds): solving again into a directory that holds an earlier
result replaces that result whole (the earlier run's files this run does not write go too, as
listed in the earlier run's manifest), says so, and leaves the user's own files alone; Ctrl-C
during the run leaves the earlier result as it was and nothing of the new run. ``rinex`` into
a directory with an earlier conversion names the files it replaces.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from peers import cli_env

from groundstation.outpaths import MANIFEST_NAME, STAGING_PREFIX

# One worker runs this module's tests (pytest-xdist):
# its module fixture simulates two flights, made once.
pytestmark = pytest.mark.xdist_group("test_solve_output_dir")


def _cli(cwd: Path, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "groundstation.cli", *args], cwd=cwd,
                            env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _run(cwd: Path, *args: str) -> tuple[int, str, str]:
    proc = _cli(cwd, *args)
    out, err = proc.communicate(timeout=300)
    return proc.returncode, out, err


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two simulated flights (a.ubx, b.ubx) of different lengths in one folder."""
    d = tmp_path_factory.mktemp("outdir")
    for name, seconds in (("a.ubx", "60"), ("b.ubx", "90")):
        rc, _, err = _run(d, "simulate", "--out", name, "--duration", seconds,
                          "--faults", "none")
        assert rc == 0, err
    return d


def _solve(cwd: Path, flight: str, out: Path) -> tuple[int, str, str]:
    return _run(cwd, "solve", flight, "--source", "receiver", "--out-dir", str(out),
                "--no-progress")


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_solving_again_replaces_the_earlier_result_whole(flights: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    rc, _, err = _solve(flights, "a.ubx", out)
    assert rc == 0, err
    first_geo = (out / "geo.txt").read_bytes()
    # The earlier run had written files this run will not (an engine's work folder; photos
    # with EXIF tags): listed in its manifest, as an engine run lists them.
    (out / "rtklib" / "rover").mkdir(parents=True)
    (out / "rtklib" / "rover" / "a.obs").write_text("the earlier flight's rover\n")
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    manifest["files"].append("rtklib/rover/a.obs")
    (out / MANIFEST_NAME).write_text(json.dumps(manifest))
    # The user's own files: a folder of photos, a note, a stale note of an older version.
    (out / "photos").mkdir()
    (out / "photos" / "IMG_0001.JPG").write_bytes(b"\xff\xd8 the user's photo")
    (out / "notes.txt").write_text("the surveyor's notes\n")
    (out / "SOLVE_FAILED.txt").write_text("groundstation solve failed: \n")

    rc, stdout, err = _solve(flights, "b.ubx", out)
    assert rc == 0, err
    assert f"replacing the earlier result in {out}" in err, err
    assert (out / "geo.txt").read_bytes() != first_geo
    assert not (out / "rtklib").exists()  # no file of the earlier flight is left
    assert not (out / "SOLVE_FAILED.txt").exists()
    assert (out / "photos" / "IMG_0001.JPG").read_bytes() == b"\xff\xd8 the user's photo"
    assert (out / "notes.txt").read_text() == "the surveyor's notes\n"
    assert not [p for p in out.iterdir() if p.name.startswith(STAGING_PREFIX)]
    assert f"wrote      {out}/geo.txt" in stdout  # the final paths, not the staging folder's
    assert STAGING_PREFIX not in stdout and STAGING_PREFIX not in (out / "report.html").read_text()
    listed = set(json.loads((out / MANIFEST_NAME).read_text())["files"])
    assert listed == set(_tree(out)) - {MANIFEST_NAME, "photos/IMG_0001.JPG", "notes.txt"}


def test_no_pdf_writes_the_report_as_html_only_and_says_so(flights: Path,
                                                           tmp_path: Path) -> None:
    out = tmp_path / "out"
    rc, stdout, err = _run(flights, "solve", "a.ubx", "--source", "receiver", "--out-dir",
                           str(out), "--no-progress", "--no-pdf")
    assert rc == 0, err
    assert (out / "report.html").is_file() and not (out / "report.pdf").exists()
    assert "note       report.pdf not written: not asked for (--no-pdf" in stdout
    assert "wrote      " + str(out / "report.html") in stdout


def test_ctrl_c_leaves_the_earlier_result_as_it_was(flights: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    rc, _, err = _solve(flights, "a.ubx", out)
    assert rc == 0, err
    before = _tree(out)
    proc = _cli(flights, "solve", "b.ubx", "--source", "receiver", "--out-dir", str(out),
                "--no-progress")
    try:
        # Interrupt while the run is writing into its staging folder (it exists from the start
        # of the run until the end).
        while proc.poll() is None and not any(
                p.name.startswith(STAGING_PREFIX) for p in out.iterdir()):
            time.sleep(0.01)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode != 0, "the run finished before it could be interrupted"
    assert "Traceback" not in err
    assert _tree(out) == before  # the earlier geo.txt beside the earlier report.pdf
    assert sorted(p.name for p in out.iterdir()) == sorted(before)


def test_rinex_names_the_files_it_replaces(flights: Path, tmp_path: Path) -> None:
    out = tmp_path / "rnx"
    rc, _, err = _run(flights, "rinex", "a.ubx", "-o", str(out), "--rinex", "2.11",
                      "--progress", "never")
    assert rc == 0 and "replacing" not in err, err
    rc, _, err = _run(flights, "rinex", "a.ubx", "-o", str(out), "--rinex", "3.04",
                      "--progress", "never")
    assert rc == 0, err
    assert f"rinex: replacing the earlier a.obs, a.nav, a.marks.csv in {out}" in err, err
