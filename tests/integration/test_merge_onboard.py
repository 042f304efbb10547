"""A radio recording and an on-board log of the same flight, merged frame by frame.

The simulator's stream before the link faults is the on-board log (an SD-card logger on the
receiver's second UART), after them the radio's recording. Merged, every epoch and every mark
of the on-board log is there once, and the solve from the merge equals the solve from the
on-board log alone.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
from once import cli_without_rtklib

from groundstation.offline.merge import merge
from groundstation.sim.faults import FaultConfig
from groundstation.sim.profiles import DEFAULT_FAULTS, sim_config
from groundstation.sim.stream import simulate
from groundstation.solve.flight import read_flight

pytestmark = pytest.mark.xdist_group("test_merge_onboard")


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("merge")
    result = simulate(sim_config("seed", duration_s=600, seed=23, severity=0.5,
                                 faults=FaultConfig.load(DEFAULT_FAULTS["seed"])))
    (d / "radio.ubx").write_bytes(result.rover_bytes)
    (d / "onboard.ubx").write_bytes(b"".join(m.raw for m in result.rover_messages))
    (d / "b.ubx").write_bytes(result.base_bytes)
    xyz = ",".join(f"{v:.4f}" for v in result.truth["base"]["ecef_m"])
    out = {}
    for name, flights in {"onboard": ["onboard.ubx"], "merged": ["radio.ubx", "onboard.ubx"],
                          "radio": ["radio.ubx"]}.items():
        proc = cli_without_rtklib("solve", "--no-pdf",
                                  *flights, "--base", "b.ubx", "--base-xyz", xyz,
                                  "--out-dir", name, "--no-progress", cwd=d)
        assert proc.returncode == 0, proc.stderr
        out[name] = proc.stdout
    return {"dir": d, "stdout": out, "truth": result.truth}


def _rows(out: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(ln for ln in (out / "cameras.csv").read_text().splitlines()
                               if not ln.startswith("#")))


def test_the_merge_has_every_epoch_and_mark_of_the_onboard_log_once(
        flight: dict[str, Any], tmp_path: Path) -> None:
    d = flight["dir"]
    report = merge([d / "radio.ubx", d / "onboard.ubx"], tmp_path / "m.ubx")
    merged, onboard, radio = (read_flight(p) for p in (
        tmp_path / "m.ubx", d / "onboard.ubx", d / "radio.ubx"))
    assert sorted(merged.epoch_t_gps_ns) == sorted(onboard.epoch_t_gps_ns)
    assert len(set(merged.epoch_t_gps_ns)) == len(merged.epoch_t_gps_ns)  # each once
    assert merged.timemarks == onboard.timemarks
    assert len(radio.epoch_t_gps_ns) < len(onboard.epoch_t_gps_ns)  # the link lost some
    radio_share, onboard_share = report.copies
    assert radio_share.epochs_only_here == 0
    assert onboard_share.epochs_only_here == (len(onboard.epoch_t_gps_ns)
                                              - len(radio.epoch_t_gps_ns))
    assert "onboard.ubx:" in report.text() and "only there" in report.text()


def test_the_solve_from_the_merge_equals_the_solve_from_the_onboard_log(
        flight: dict[str, Any]) -> None:
    d = flight["dir"]
    merged, onboard, radio = (_rows(d / n) for n in ("merged", "onboard", "radio"))
    assert merged == onboard
    assert len([r for r in radio if r["mark"]]) < len([r for r in onboard if r["mark"]])
    assert "merged 2 recordings of the receiver" in flight["stdout"]["merged"]
    # the merge's note, in the report too
    assert "merged 2 recordings" in (d / "merged" / "report.html").read_text()
    json.dumps(flight["truth"]["exposures"][0])  # the truth is at hand for a reader


def test_inspect_and_rinex_take_the_copies_merged(flight: dict[str, Any]) -> None:
    """``inspect`` and ``rinex`` with both copies see the on-board log's epochs and marks, and
    say what each copy supplied."""
    d = flight["dir"]
    got = {}
    for name, flights in {"onboard": ["onboard.ubx"], "merged": ["radio.ubx", "onboard.ubx"]
                          }.items():
        proc = cli_without_rtklib("inspect", *flights, "--json", cwd=d)
        assert proc.returncode == 0, proc.stderr
        got[name] = json.loads(proc.stdout)
    assert got["merged"]["epochs"] == got["onboard"]["epochs"]
    assert got["merged"]["timemarks"] == got["onboard"]["timemarks"]
    assert got["merged"]["merged_from"].startswith("merged 2 recordings of the receiver")
    text = cli_without_rtklib("inspect", "radio.ubx", "onboard.ubx", cwd=d).stdout
    assert "radio.ubx + onboard.ubx (merged)" in text and "groundstation-merge-" not in text
    for name, flights in {"onboard": ["onboard.ubx"], "merged": ["radio.ubx", "onboard.ubx"]
                          }.items():
        proc = cli_without_rtklib("rinex", *flights, "--out-dir", f"rinex-{name}", cwd=d)
        assert proc.returncode == 0, proc.stderr
        got[name] = proc.stdout
    assert "radio_merged.obs" in got["merged"] and "merged 2 recordings" in got["merged"]
    epochs = [ln.split(": ")[1].split(" epochs")[0] for run in (got["onboard"], got["merged"])
              for ln in run.splitlines() if ".obs: " in ln]
    assert epochs[0] == epochs[1], epochs
    assert (d / "rinex-merged" / "radio_merged.obs").is_file()
    # another receiver's recording (the base) or the same file twice is not a copy: refused,
    # one line, nothing written
    for flights, says in ((["radio.ubx", "b.ubx"], "another receiver's recording"),
                          (["radio.ubx", "radio.ubx"], "given twice")):
        for cmd in (["inspect"], ["rinex", "--out-dir", "rinex-wrong"]):
            proc = cli_without_rtklib(*cmd[:1], *flights, *cmd[1:], cwd=d)
            assert proc.returncode == 2 and says in proc.stderr, proc.stderr
            assert len(proc.stderr.strip().splitlines()) == 1
    assert not (d / "rinex-wrong").exists()
