"""``solve --rebase`` refuses what cannot be re-based with one line naming the option (exit 2)
and writes nothing: no such result, a folder without a solve's record, a solve's other options
given too, no new base, a result solved without a base, a recording that has gone."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from peers import cli_env

from groundstation.solve import record
from groundstation.solve.settings import SolveSettings
from groundstation.solve.trajectory import make_trajectory

XYZ = "3774696.5547,-596647.9083,5089485.6511"


def _result(d: Path, **settings: object) -> Path:
    """A finished result's record (as a solve leaves it) in ``d/done``."""
    (d / "rover.ubx").write_bytes(b"\xb5\x62")
    (d / "base.ubx").write_bytes(b"\xb5\x62")
    done = d / "done"
    done.mkdir()
    s = SolveSettings(**{"flight": d / "rover.ubx", "out_dir": done, "base": d / "base.ubx",
                         "base_ecef_m": (3774696.5547, -596647.9083, 5089485.6511),
                         **settings})  # type: ignore[arg-type]
    traj = make_trajectory([0, 200_000_000], np.zeros((2, 3)), [1, 1], source="rover.pos")
    record.write(s, traj, record.Interpolations(), None, done, done)
    return done


def _rebase(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "groundstation.cli", "solve", "--no-pdf", *args],
                          cwd=cwd, env=cli_env(), capture_output=True, text=True, timeout=120,
                          check=False)


@pytest.mark.parametrize(("args", "said"), [
    (["--rebase", "nowhere", "--base-xyz", XYZ, "--out-dir", "out"],
     "--rebase: nowhere: no such directory"),
    (["--rebase", "empty", "--base-xyz", XYZ, "--out-dir", "out"],
     "--rebase: empty: no solve.json in it"),
    (["--rebase", "done", "--base-xyz", XYZ, "--photos", "empty", "--out-dir", "out"],
     ("--rebase: takes only the new base position (with its sigma, antenna height and type) "
     "and --out-dir, --no-pdf; --photos was given")),
    (["--rebase", "done", "rover.ubx", "--base-xyz", XYZ, "--out-dir", "out"],
     ("--rebase: takes only the new base position (with its sigma, antenna height and type) "
     "and --out-dir, --no-pdf; the flight was given")),
    (["--rebase", "done", "--out-dir", "out"],
     "--rebase: give the new base position: --base-xyz X,Y,Z"),
    (["--out-dir", "out"], "flight: give the rover's recording"),
    (["rover.ubx", "--base", "base.ubx", "--base-xyz", XYZ], "--out-dir: give the output"),
])
def test_what_cannot_be_rebased_is_one_line_and_exit_2(
        tmp_path: Path, args: list[str], said: str) -> None:
    _result(tmp_path)
    (tmp_path / "empty").mkdir()
    listing = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    proc = _rebase(tmp_path, *args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and said in lines[0], proc.stderr
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == listing


def test_a_result_without_a_base_or_whose_recording_has_gone_is_refused(
        tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    _result(tmp_path / "a", base=None, base_ecef_m=None, positions=tmp_path / "a" / "x.pos")
    gone = _result(tmp_path / "b")
    (tmp_path / "b" / "rover.ubx").unlink()
    proc = _rebase(tmp_path, "--rebase", "a/done", "--base-xyz", XYZ)
    assert proc.returncode == 2, proc.stderr
    assert "was solved without a base position" in proc.stderr
    proc = _rebase(tmp_path, "--rebase", str(gone), "--base-xyz", XYZ)
    assert proc.returncode == 2, proc.stderr
    assert f"{tmp_path.resolve()}/b/rover.ubx: no longer there" in proc.stderr
    assert "flight.npz, which would stand for the recordings, is missing" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_a_move_too_large_for_the_baselines_is_refused(tmp_path: Path) -> None:
    """10 km baselines and a base moved 10 m: the directions to the satellites change enough
    (up to 5 mm on the baseline) that the shifted result would not be the solve's."""
    from groundstation.errors import ConfigError
    from groundstation.geodesy import enu_to_ecef

    base = (3774696.5547, -596647.9083, 5089485.6511)
    done = tmp_path / "done"
    done.mkdir()
    far = [enu_to_ecef((10_000.0 * k / 10, 0.0, 100.0), base) for k in range(11)]
    traj = make_trajectory([k * 200_000_000 for k in range(11)], np.array(far), [1] * 11)
    s = SolveSettings(flight=tmp_path / "r.ubx", out_dir=done, base=tmp_path / "b.ubx",
                      base_ecef_m=base)
    record.write(s, traj, record.Interpolations(), None, done, done)
    for step_m, refused in ((10.0, True), (1.0, False)):
        new = enu_to_ecef((step_m, 0.0, 0.0), base)
        rb = SolveSettings(flight=tmp_path / "r.ubx", out_dir=tmp_path / "o", base_ecef_m=new,
                           rebase=done, previous_bases=((base, "given with --base-xyz"),))
        if refused:
            with pytest.raises(ConfigError, match="off by up to 5 mm; solve again"):
                record.shifted_trajectory(rb, tmp_path / "stage")
        else:
            traj2, text = record.shifted_trajectory(rb, tmp_path / "stage")
            assert np.allclose(traj2.ecef_m - traj.ecef_m, np.array(new) - np.array(base))
            assert "east +1.0000, north +0.0000, up +0.0000 m" in text


def test_the_antenna_height_and_offset_it_was_solved_with_apply_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A result solved with the mark's coordinates, a 1.5 m antenna height and an ANTEX offset:
    re-based to new coordinates of the mark, the antenna stands as it stood (the surveyor
    gives the mark again, not the antenna); a height given again replaces it; a position file
    (the antenna's own position) takes neither."""
    import argparse

    from antex_file import antenna_block, write_antex

    from groundstation.commands import solve as cmd
    from groundstation.geodesy import ecef_to_llh, enu_rotation

    atx = write_antex(tmp_path / "a.atx", antenna_block("ANT1", "NONE", {"G01": (0, 0, 80.0)}))
    _result(tmp_path, base_antenna_height_m=1.5, base_antenna="ANT1", antex=atx)
    mark = np.array([3774696.5547 + 0.5, -596647.9083, 5089485.6511])

    def rebased(*extra: str) -> SolveSettings:
        parser = argparse.ArgumentParser()
        cmd.add_arguments(parser)
        return cmd.settings_from_args(parser.parse_args(
            ["--rebase", "done", *extra, "--out-dir", "out"]))

    monkeypatch.chdir(tmp_path)
    xyz = ",".join(f"{v:.4f}" for v in mark)
    lat, lon, _ = ecef_to_llh(*mark.tolist())
    rot = np.array(enu_rotation(lat, lon))
    s = rebased("--base-xyz", xyz)
    assert s.base_ecef_m is not None
    assert rot @ (np.array(s.base_ecef_m) - mark) == pytest.approx((0, 0, 1.58), abs=1e-4)
    assert (s.base_antenna_height_m, s.base_antenna) == (1.5, "ANT1")
    assert "1.5000 m above it" in s.base_given and "L1 phase-centre offset of ANT1" in s.base_given
    s = rebased("--base-xyz", xyz, "--base-antenna-height", "1.2")
    assert s.base_ecef_m is not None
    assert rot @ (np.array(s.base_ecef_m) - mark) == pytest.approx((0, 0, 1.28), abs=1e-4)
    position = tmp_path / "b.json"
    position.write_text(json.dumps({"ecef_m": mark.tolist()}))
    s = rebased("--base-position", str(position))
    assert s.base_ecef_m == pytest.approx(tuple(mark.tolist()))
    assert s.base_antenna_height_m is None and s.antex is None
