"""``solve`` without ``--photos``: the exports carry one row per positioned mark, named by the
receiver's mark count, and the report lists the marks the receiver missed.

The simulator's flight with a base and missed marks (the camera fired, the receiver's count
went on, no TIM-TM2 arrived), solved by the command line as a surveyor types it.
"""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from peers import cli_env

# One worker runs this module's tests (pytest-xdist):
# its module fixture simulates and solves a flight (~8 s), made once.
pytestmark = pytest.mark.xdist_group("test_solve_without_photos")


def _cli(cwd: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], cwd=cwd,
                          env=cli_env(), capture_output=True, text=True, timeout=300,
                          check=False)


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("no_photos")
    (d / "faults.toml").write_text("missed_mark_prob = 0.3\n")
    sim = _cli(d, "simulate", "--out", "f.ubx", "--base-out", "b.ubx", "--truth", "t.json",
               "--duration", "300", "--faults", "faults.toml", "--seed", "3")
    assert sim.returncode == 0, sim.stderr
    truth = json.loads((d / "t.json").read_text())
    xyz = ",".join(f"{v:.4f}" for v in truth["base"]["ecef_m"])
    proc = _cli(d, "solve", "--no-pdf",
                "f.ubx", "--base", "b.ubx", "--base-xyz", xyz, "--out", "out",
                "--no-progress")
    assert proc.returncode == 0, proc.stderr
    # The receiver's count at each exposure's falling edge is the exposures before it (from 0,
    # as u-center and RTKLIB show it); the missed ones have no record.
    missed = [k for k, e in enumerate(truth["exposures"]) if e.get("missed")]
    sent = [k for k, e in enumerate(truth["exposures"]) if not e.get("missed")]
    assert missed, "the faults file must make the receiver miss marks"
    return {"out": d / "out", "stdout": proc.stdout, "missed": missed, "sent": sent}


def test_exports_carry_every_positioned_mark_by_its_count(solved: dict[str, Any]) -> None:
    out: Path = solved["out"]
    names = [f"mark_{n:04d}" for n in solved["sent"]]
    geo = (out / "geo.txt").read_text().splitlines()
    assert [ln.split()[0] for ln in geo[1:]] == names
    with (out / "reference.csv").open() as f:
        ref = list(csv.DictReader(row for row in f if not row.startswith("#")))
    assert [r["label"] for r in ref] == names
    pix = (out / "pix4d.csv").read_text().splitlines()
    assert [ln.split(",")[0] for ln in pix[1:]] == names
    assert "no photos given: marks named mark_NNNN" in solved["stdout"]


def test_the_printout_says_what_its_words_mean(solved: dict[str, Any]) -> None:
    """A newcomer's findings: "arcs-and-engine", "smoother interpolation" and "no attitude
    for some photos" (with no photo at all) said nothing to a surveyor."""
    from groundstation.solve.integrity.grade import CHECK_TEXT

    out = solved["stdout"]
    grades = next(ln for ln in out.splitlines() if ln.startswith("grades "))
    checks = next(ln for ln in out.splitlines() if ln.startswith("checks "))
    named = re.findall(r"[(,] ?([a-z:-]+) \d+", grades)
    assert named and all(f"{c}: {CHECK_TEXT[c]}" in checks for c in named), (grades, checks)
    assert ("interpolation smoothed trajectory between fixed epochs, straight line elsewhere "
            "(--interp)") in out
    assert "no attitude given (--eo): nadir camera assumed" in out
    assert "some photos" not in out


def test_report_names_the_marks_and_lists_the_missed_ones(solved: dict[str, Any]) -> None:
    text = (solved["out"] / "report.html").read_text(encoding="utf-8")
    assert "without a photo" not in text  # no photos were given: none are missing
    assert "No photos given: marks named mark_NNNN" in text
    section = text[text.index('<section class="positions">'):]
    # the faults file makes the receiver leave marks out; the link loses nothing
    said = re.search(r'<p class="marks-missed" data-cause="receiver">(\d+) time mark\(s\) not '
                     r"reported by the receiver[^<]*number\(s\) ([-\d, ]+)\.</p>", section)
    assert said is not None, section[:2000]
    assert int(said.group(1)) == len(solved["missed"])
    listed = [n for item in said.group(2).split(", ")
              for n in range(int(item.split("-")[0]), int(item.split("-")[-1]) + 1)]
    assert listed == solved["missed"]
    assert 'data-cause="link"' not in section
    assert f'data-count="marks_not_reported">{len(solved["missed"])}<' in text
    assert 'data-count="marks_lost_on_link">0<' in text
