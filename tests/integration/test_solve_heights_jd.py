"""Heights above EGM96 in every export and the report, on a real flight (jdesbonnet 2018-10-09).

``--epsg 32629+5773`` (UTM 29N + EGM96 height): every export's heights equal pyproj's
transformation of the camera's WGS84 position with the same grid within 1 mm, every file names
the height datum, and the GeoJSON (RFC 7946: WGS84) keeps ellipsoidal heights and says so.
Needs the EGM96 grid (Debian's proj-data, which CI installs); skipped with a reason without it.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from peers import cli_env

from groundstation.solve.outputs import SYSTEM_GRID_DIRS

pytestmark = pytest.mark.shared_data

JD = "real/jdesbonnet__GNSS_RTK_data"
XYZ_1009 = "3774696.5547,-596647.9083,5089485.6511"
EGM96 = "EGM96 height, orthometric (geoid grid us_nga_egm96_15.tif through PROJ)"


def _rows(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader([ln for ln in text.splitlines() if not ln.startswith("#")]))


@pytest.mark.skipif(not any((d / "egm96_15.gtx").is_file() for d in SYSTEM_GRID_DIRS),
                    reason="no EGM96 grid (apt install proj-data)")
def test_egm96_heights_in_every_export(shared_data: Path, tmp_path: Path) -> None:
    import pyproj
    from pyproj import Transformer

    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "solve",
         str(shared_data / JD / "20181009/rover-20181009-1221.ubx.gz"),
         "--base", str(shared_data / JD / "20181009/base-20181009-1220.ubx.gz"),
         "--base-xyz", XYZ_1009, "--epsg", "32629+5773", "--out-dir", str(out), "--no-progress"],
        cwd=tmp_path, env=cli_env(), capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr
    for d in SYSTEM_GRID_DIRS:
        pyproj.datadir.append_data_dir(str(d))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ref = Transformer.from_crs("EPSG:4979", "EPSG:32629+5773", always_xy=True,
                                   only_best=True)
    cams_text = (out / "cameras.csv").read_text()
    assert cams_text.splitlines()[0] == (
        f"# crs EPSG:32629+5773 (WGS 84 / UTM zone 29N + EGM96 height); h = {EGM96}")
    cams = [r for r in _rows(cams_text) if r["h_m"]]
    assert len(cams) == 589
    by_name = {}
    for r in cams:
        x, y, big_h = ref.transform(float(r["lon_deg"]), float(r["lat_deg"]),
                                    float(r["ellipsoidal_h_m"]))
        assert abs(big_h - float(r["h_m"])) <= 0.0011, r
        assert abs(x - float(r["x_m"])) <= 0.0011 and abs(y - float(r["y_m"])) <= 0.0011
        assert 57.3 < float(r["ellipsoidal_h_m"]) - float(r["h_m"]) < 57.7  # EGM96 at Galway
        by_name[f"mark_{int(r['mark_count']):04d}"] = float(r["h_m"])
    geo = (out / "geo.txt").read_text().splitlines()
    assert geo[0] == "EPSG:32629+5773"
    for line in geo[1:]:
        name, _x, _y, z = line.split()[:4]
        assert float(z) == pytest.approx(by_name[name], abs=1e-9)
    ref_csv = (out / "reference.csv").read_text()
    assert ref_csv.splitlines()[0].endswith(f"z = {EGM96}")
    for r in _rows(ref_csv):
        assert float(r["z_height"]) == pytest.approx(by_name[r["label"]], abs=1e-9)
    pix4d = (out / "pix4d.csv").read_text().splitlines()
    assert pix4d[0].endswith(f"Z = {EGM96}")
    for line in pix4d[1:]:
        name, _y, _x, z = line.split(",")[:4]
        assert float(z) == pytest.approx(by_name[name], abs=1e-9)
    assert f"<th>Heights</th><td>{EGM96}</td>" in (out / "report.html").read_text()
    gj = json.loads((out / "cameras.geojson").read_text())
    assert gj["height_datum"] == "WGS84 ellipsoidal"
