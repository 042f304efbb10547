"""``locate-base`` on the GEONET pair of RTKLIB's test data (2005-04-02, 3.3 km apart).

0759 is our base, 3040 the reference station at its published position; 3040's RINEX is given
Hatanaka-compressed and gzipped (made here with the ``hatanaka`` package), its navigation file
gzipped beside it. RTKLIB's static result for 0759 is (-3976219.187, 3382371.605, 3652511.142).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import hatanaka
import numpy as np
import pytest
from peers import cli_env

from groundstation.geodesy import ecef_to_enu

pytestmark = pytest.mark.shared_data

GEONET = "real/tomojitakasu__RTKLIB/test/data/rinex"
REF_XYZ = "-3978241.958,3382840.234,3649900.853"  # 3040, published
RTKLIB_0759 = (-3976219.187, 3382371.605, 3652511.142)


def _reference(shared: Path, tmp: Path) -> Path:
    """3040's observations as a CORS download looks: Hatanaka + gzip, navigation gzipped."""
    src = shared / GEONET
    ref = tmp / "30400920.05d.gz"
    ref.write_bytes(hatanaka.compress((src / "30400920.05o").read_bytes(), compression="gz"))
    (tmp / "30400920.05n.gz").write_bytes(
        hatanaka.compress((src / "30400920.05n").read_bytes(), compression="gz"))
    return ref


def _cli(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "groundstation.cli", "locate-base", *args],
                          cwd=cwd, env=cli_env(), capture_output=True, text=True, timeout=600,
                          check=False)


def test_the_geonet_base_within_3_cm_of_rtklib_with_a_sigma_that_covers_it(
        shared_data: Path, tmp_path: Path) -> None:
    ref = _reference(shared_data, tmp_path)
    proc = _cli(tmp_path, str(shared_data / GEONET / "07590920.05o"), "--reference", str(ref),
                f"--reference-xyz={REF_XYZ}", "--json", "--out", "base.json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert json.loads((tmp_path / "base.json").read_text()) == doc
    xyz = tuple(doc["ecef_m"])
    assert np.linalg.norm(np.subtract(xyz, RTKLIB_0759)) < 0.03
    diff = ecef_to_enu(RTKLIB_0759, xyz)
    assert all(abs(d) <= s for d, s in zip(diff, doc["sigma_enu_m"], strict=True)), (diff, doc)
    assert doc["fixed"] and doc["fixed_share"] > 0.5 and doc["epochs"] == 120
    assert abs(doc["baseline_m"] - 3300) < 100
    assert doc["reference_from"] == "given with --reference-xyz"


def test_without_coordinates_the_header_position_is_used_and_said(
        shared_data: Path, tmp_path: Path) -> None:
    ref = _reference(shared_data, tmp_path)
    proc = _cli(tmp_path, str(shared_data / GEONET / "07590920.05o"), "--reference", str(ref))
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("base position  ECEF -3976219.")
    assert "from the APPROX POSITION XYZ of its RINEX header" in proc.stdout
    assert any(ln.startswith("sigma          east 0.00") for ln in lines), proc.stdout
    assert "solution       fixed; " in proc.stdout


def test_mistakes_get_one_line_and_write_nothing(shared_data: Path, tmp_path: Path) -> None:
    ref = _reference(shared_data, tmp_path)
    base = str(shared_data / GEONET / "07590920.05o")
    other_day = str(shared_data / "real/jdesbonnet__GNSS_RTK_data/20181009/"
                    "base-20181009-1220.ubx.gz")
    (tmp_path / "kept.json").write_text("{}")
    cases = [
        (("nope.05o", "--reference", str(ref)), "BASE: nope.05o: no such file"),
        ((base, "--reference", "missing.crx.gz"), "--reference: missing.crx.gz: no such file"),
        ((base, "--reference", str(ref), "--reference-xyz", "35.7,139.5,60"),
         "--reference-xyz:"),
        ((base, "--reference", str(ref), "--out", "kept.json"),
         "--out: kept.json exists: refusing to overwrite it without --force"),
        ((other_day, "--reference", str(ref)), "does not overlap the base in time"),
        ((base, "--reference", str(ref), "--out", "no/such/dir/base.json"), "does not exist"),
    ]
    for args, says in cases:
        proc = _cli(tmp_path, *args)
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stderr.count("\n") == 1 and says in proc.stderr, (args, proc.stderr)
    assert (tmp_path / "kept.json").read_text() == "{}"
    assert not (tmp_path / "no").exists()
