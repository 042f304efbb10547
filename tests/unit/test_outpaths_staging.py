"""``outpaths.staged_output``: a run's outputs replace an earlier result whole, or not at all.

Real folders in ``tmp_path``: a completed run moves its files in and lists them; a run that
raises (Ctrl-C is a ``KeyboardInterrupt``) leaves the folder as it was; a failure while moving
into place (a user's folder where our file goes) moves everything back; a user's folder sharing
a name with one of ours keeps the user's files.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from groundstation import outpaths


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _run(out: Path, files: dict[str, str]) -> None:
    with outpaths.staged_output(out) as stage:
        for rel, text in files.items():
            (stage / rel).parent.mkdir(parents=True, exist_ok=True)
            (stage / rel).write_text(text)


def test_a_new_directory_gets_the_run_and_its_manifest(tmp_path: Path) -> None:
    out = tmp_path / "new"
    _run(out, {"geo.txt": "1", "rtklib/rover.pos": "p"})
    assert _tree(out) == {"geo.txt": b"1", "rtklib/rover.pos": b"p",
                          outpaths.MANIFEST_NAME: b'{"files":["geo.txt","rtklib/rover.pos"]}'}


@pytest.mark.parametrize("exc", [RuntimeError("engine failed"), KeyboardInterrupt()])
def test_a_run_that_raises_leaves_the_directory_as_it_was(tmp_path: Path,
                                                          exc: BaseException) -> None:
    out = tmp_path / "out"
    _run(out, {"geo.txt": "earlier", "report.pdf": "earlier report"})
    before = _tree(out)
    with pytest.raises(type(exc)), outpaths.staged_output(out) as stage:
        (stage / "geo.txt").write_text("new")
        raise exc
    assert _tree(out) == before and sorted(p.name for p in out.iterdir()) == sorted(before)
    with pytest.raises(RuntimeError), outpaths.staged_output(tmp_path / "fresh"):
        raise RuntimeError
    assert not (tmp_path / "fresh").exists()  # created by the run: removed with it


def test_the_earlier_runs_files_go_and_the_users_stay(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run(out, {"geo.txt": "day 1", "rtklib/rover/day1.obs": "o", "photos/IMG_1.JPG": "exif"})
    (out / "photos" / "mine.JPG").write_text("the user's")  # the user's, in a folder of ours
    (out / "notes.txt").write_text("the user's")
    _run(out, {"geo.txt": "day 2", "rtklib/rover/day2.obs": "o"})
    assert _tree(out) == {
        "geo.txt": b"day 2", "rtklib/rover/day2.obs": b"o", "photos/mine.JPG": b"the user's",
        "notes.txt": b"the user's",
        outpaths.MANIFEST_NAME: b'{"files":["geo.txt","rtklib/rover/day2.obs"]}'}


def test_a_failure_while_moving_into_place_moves_everything_back(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run(out, {"a.txt": "earlier a", "z/z.txt": "earlier z"})
    (out / "m.txt").mkdir()  # a user's folder where the new run's m.txt goes: rename fails
    (out / "m.txt" / "keep").write_text("the user's")
    before = _tree(out)
    with pytest.raises(OSError):
        _run(out, {"a.txt": "new a", "b/b.txt": "new b", "m.txt": "new m"})
    assert _tree(out) == before
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [outpaths.MANIFEST_NAME, "a.txt", "m.txt", "z"])
    assert json.loads((out / outpaths.MANIFEST_NAME).read_text())["files"] == [
        "a.txt", "z/z.txt"]


def test_records_naming_the_staging_folder_name_the_final_place(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with outpaths.staged_output(out) as stage:
        (stage / "rtklib").mkdir()
        (stage / "rtklib" / "rover.pos").write_text(f"% inp file  : {stage}/rtklib/rover.obs\n")
        (stage / "rtklib" / "rover.obs").write_text(f"{stage}: not a record, left alone\n")
        note = outpaths.unstaged(f"solution {stage / 'rtklib' / 'rover.pos'}", stage)
    assert note == f"solution {out / 'rtklib' / 'rover.pos'}"
    assert (out / "rtklib" / "rover.pos").read_text() == f"% inp file  : {out}/rtklib/rover.obs\n"
    assert (out / "rtklib" / "rover.obs").read_text() == f"{stage}: not a record, left alone\n"


def test_a_killed_runs_staging_folder_is_removed_by_the_next_run(tmp_path: Path) -> None:
    import subprocess
    import sys

    dead = subprocess.Popen([sys.executable, "-c", "pass"])  # a pid that is gone
    dead.wait()
    out = tmp_path / "out"
    stale = out / f"{outpaths.STAGING_PREFIX}{dead.pid}"
    (stale / "rtklib").mkdir(parents=True)
    (stale / "rtklib" / "rover.obs").write_text("half a killed run")
    live = out / f"{outpaths.STAGING_PREFIX}1"  # pid 1 is alive: another run's, left alone
    live.mkdir()
    _run(out, {"geo.txt": "new"})
    assert not stale.exists() and live.is_dir()
    assert (out / "geo.txt").read_text() == "new"
