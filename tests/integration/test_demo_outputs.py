"""`groundstation demo`'s outputs are checked before the flight: the camera's own photos are
never replaced without --force, and a bad output path is one line, exit 2, nothing recorded."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from peers import cli_env

DEMO = ("demo", "--flight", "60", "--speed", "max", "--no-zenoh", "--seed", "2")


def _demo(cwd: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", *DEMO, *argv], cwd=cwd, env=cli_env(),
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, check=False)


def _tree(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else None
            for p in sorted(root.rglob("*"))}


def test_demo_refuses_to_replace_the_cameras_photos(tmp_path: Path) -> None:
    photos = tmp_path / "P"
    photos.mkdir()
    mine = b"\xff\xd8 a real camera's IMG_0002 \xff\xd9"
    (photos / "IMG_0002.JPG").write_bytes(mine)
    (photos / "IMG_0003.JPG").write_bytes(mine)
    before = _tree(tmp_path)
    proc = _demo(tmp_path, "--photos", "P", "--out-dir", "fl")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "--photos" in lines[0] and "P/IMG_0002.JPG exists" in lines[0]
    assert "IMG_0003.JPG" in lines[0] and "--force" in lines[0]
    assert proc.stdout == ""
    assert _tree(tmp_path) == before  # no flight, no recording, the photos untouched

    forced = _demo(tmp_path, "--photos", "P", "--out-dir", "fl", "--force")
    assert forced.returncode == 0, forced.stderr
    assert (photos / "IMG_0002.JPG").read_bytes() != mine
    assert list((tmp_path / "fl").glob("*.mcap"))


@pytest.mark.parametrize(("argv", "says"), [
    (("--photos", "afile"), "--photos: afile is not a directory"),
    (("--photos", "afile/sub"), "--photos: cannot create afile/sub"),
    (("--photos", "/proc/nope"), "--photos: cannot create /proc/nope"),
    (("--out-dir", "afile"), "--out-dir: afile is not a directory"),
    (("--out-dir", "/proc/nope"), "--out-dir: cannot create /proc/nope"),
], ids=["photos-file", "photos-under-file", "photos-proc", "out-dir-file", "out-dir-proc"])
def test_demo_checks_every_output_before_the_flight(tmp_path: Path, argv: tuple[str, ...],
                                                    says: str) -> None:
    (tmp_path / "afile").write_text("mine\n")
    out = () if "--out-dir" in argv else ("--out-dir", "fl")
    proc = _demo(tmp_path, *argv, *out)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert says in lines[0]
    assert "Traceback" not in proc.stderr
    assert _tree(tmp_path) == {"afile": b"mine\n"}  # nothing recorded, no directory made
