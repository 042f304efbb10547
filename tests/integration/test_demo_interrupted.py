"""An interrupted demo: the summary, then exit status 130 (README: "130 interrupted"; the
daemon commands, not the demo, take Ctrl-C as their normal end), and no "next: ... solve"
line for a flight cut short before its first mark."""

from __future__ import annotations

from pathlib import Path

from peers import interrupted_cli


def test_a_demo_interrupted_before_its_first_mark_exits_130_and_says_it_was_cut_short(
        tmp_path: Path) -> None:
    returncode, out, err = interrupted_cli(
        ["demo", "--flight", "600", "--speed", "1", "--no-zenoh", "--no-view"], cwd=tmp_path,
        ready=lambda: list((tmp_path / "flights").glob("*.mcap")),
        after_s=1.0)  # a few epochs of the static start: no mark yet
    assert returncode == 130, err
    assert "Traceback" not in err
    assert "next: groundstation solve" not in out, out
    assert "the flight was cut short (SIGINT after " in out, out
