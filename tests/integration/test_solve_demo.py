"""The demo flight solved end to end: `groundstation demo`, then `groundstation solve` on its MCAP.

The demo writes the session MCAP, the base's stream and the simulator's truth; the test writes a
photo set (real EXIF, camera clock hours off) for the truth's exposures and runs the solve
command as a user would, with the base coordinates from the truth. Each output is then read the
way its consumer reads it. Both commands run with no RTKLIB program on PATH, as after a plain
``pip install``: the default engine is demo5 through pyrtklib5.
"""

from __future__ import annotations

import csv
import html.parser
import json
import math
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from exif import Image
from once import DemoFlight, cli_without_rtklib
from pyproj import CRS, Transformer

from groundstation.solve.outputs import CAMERAS_COLUMNS, PIX4D_COLUMNS, REFERENCE_COLUMNS
from groundstation.solve.photosim import photos_at_times, write_photo_set

# One worker runs this module's tests (pytest-xdist):
# its module fixture solves the demo flight (~10 s), made once.
pytestmark = pytest.mark.xdist_group("test_solve_demo")

OUTPUTS = ("cameras.csv", "geo.txt", "reference.csv", "pix4d.csv", "cameras.geojson",
           "report.html")
_cli = cli_without_rtklib


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory, demo_flight: DemoFlight) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("demo_solve")
    files = demo_flight.files  # (the demo made once for the run: conftest.py)
    truth = json.loads(files["truth"].read_text())
    # Photos for the exposures whose marks reached the recording: the demo's link faults may
    # lose a TIM-TM2 or the camera a pulse, which leaves that photo unpaired (test_solve_sim
    # checks those cases against the truth); here every photo must come out in every file.
    lost = {c - 1 for c in truth["fault_summary"].get("marks_lost_in_link", [])}
    truth["exposures"] = [e for k, e in enumerate(truth["exposures"])
                          if k not in lost and not e.get("missed")]
    photo_dir = d / "photos"
    write_photo_set(photos_at_times([e["falling_t_gps_ns"] for e in truth["exposures"]],
                                    clock_error_s=-(1 * 3600 + 51 * 60 + 2.6)), photo_dir)
    before = {p.name: p.read_bytes() for p in photo_dir.iterdir()}
    xyz = ",".join(f"{v:.4f}" for v in truth["base"]["ecef_m"])
    out = d / "out"
    t1 = time.monotonic()
    proc = _cli("solve", str(files["MCAP"]), "--base", str(files["base UBX"]), "--base-xyz", xyz,
                "--photos", str(photo_dir), "--lever-arm", "0.16,-0.03,0.57",
                "--interp", "smoother", "--exif", "--out", str(out), cwd=d)
    t_solve = time.monotonic() - t1
    assert proc.returncode == 0, proc.stderr
    print(f"\nsolve {t_solve:.1f} s")
    return {"out": out, "stdout": proc.stdout, "truth": truth, "photos": photo_dir,
            "before": before, "files": files}


def _table(path: Path) -> list[dict[str, str]]:
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    return list(csv.DictReader(lines))


def test_every_output_is_written_and_named(solved: dict[str, Any]) -> None:
    out: Path = solved["out"]
    for name in OUTPUTS:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
        assert f"wrote      {out / name}" in solved["stdout"]
    n = len(solved["truth"]["exposures"])
    assert f"{n} paired, 0 photos without mark, 0 marks without photo" in solved["stdout"]
    assert "positions  demo5 + integrity stage:" in solved["stdout"]
    assert "engine demo5: RTKLIB EX" in solved["stdout"]
    engine_json = json.loads((out / "rtklib" / "engine.json").read_text())
    assert engine_json["engine"] == "demo5" and engine_json["options"]["pos1-frequency"] == "l1"
    # The originals are untouched; the copies carry the camera position in EXIF GPS tags.
    photo_dir: Path = solved["photos"]
    assert {p.name: p.read_bytes() for p in photo_dir.iterdir()} == solved["before"]
    rows = {r["photo"]: r for r in _table(out / "cameras.csv")}
    copies = sorted((out / "photos").iterdir())
    assert [p.name for p in copies] == sorted(solved["before"])
    for p in copies:
        img = Image(p.read_bytes())
        lat = sum(v / 60**i for i, v in enumerate(img.gps_latitude))
        lon = sum(v / 60**i for i, v in enumerate(img.gps_longitude))
        assert img.gps_latitude_ref == "N" and img.gps_longitude_ref == "E"
        assert lat == pytest.approx(float(rows[p.name]["lat_deg"]), abs=1e-7)
        assert lon == pytest.approx(float(rows[p.name]["lon_deg"]), abs=1e-7)
        assert img.gps_altitude == pytest.approx(float(rows[p.name]["h_m"]), abs=1e-3)
        # the accuracy where photogrammetry tools read it: EXIF, and Pix4D's XMP
        horz = max(float(rows[p.name]["sd_e_m"]), float(rows[p.name]["sd_n_m"]))
        assert img.gps_horizontal_positioning_error == pytest.approx(horz, abs=1e-3)
        xmp = p.read_bytes()
        assert f'Camera:GPSXYAccuracy="{horz:.3f}"'.encode() in xmp
        assert f'Camera:GPSZAccuracy="{float(rows[p.name]["sd_u_m"]):.3f}"'.encode() in xmp


@pytest.mark.skipif(shutil.which("exiftool") is None,
                    reason="no exiftool (apt install libimage-exiftool-perl)")
def test_exiftool_reads_the_position_and_accuracy_of_every_copy(solved: dict[str, Any]) -> None:
    out: Path = solved["out"]
    rows = {r["photo"]: r for r in _table(out / "cameras.csv")}
    proc = subprocess.run(
        ["exiftool", "-json", "-n", "-GPSLatitude", "-GPSLongitude", "-GPSAltitude",
         "-GPSHPositioningError", "-XMP-Camera:GPSXYAccuracy", "-XMP-Camera:GPSZAccuracy",
         str(out / "photos")], capture_output=True, text=True, timeout=120, check=True)
    tags = json.loads(proc.stdout)
    assert len(tags) == len(rows) > 0
    for t in tags:
        r = rows[Path(t["SourceFile"]).name]
        assert t["GPSLatitude"] == pytest.approx(float(r["lat_deg"]), abs=1e-7)
        assert t["GPSLongitude"] == pytest.approx(float(r["lon_deg"]), abs=1e-7)
        assert t["GPSAltitude"] == pytest.approx(float(r["h_m"]), abs=1e-3)
        horz = max(float(r["sd_e_m"]), float(r["sd_n_m"]))
        assert t["GPSHPositioningError"] == pytest.approx(horz, abs=1e-3)
        assert t["GPSXYAccuracy"] == pytest.approx(horz, abs=1e-3)
        assert t["GPSZAccuracy"] == pytest.approx(float(r["sd_u_m"]), abs=1e-3)


def test_cameras_csv_against_truth(solved: dict[str, Any]) -> None:
    rows = _table(solved["out"] / "cameras.csv")
    assert tuple(rows[0].keys()) == CAMERAS_COLUMNS
    truth = solved["truth"]
    exp = truth["exposures"]
    assert [r["photo"] for r in rows] == [f"IMG_{k + 1:04d}.JPG" for k in range(len(exp))]
    epsg = int(solved["out"].joinpath("geo.txt").read_text().split()[0].removeprefix("EPSG:"))
    to_llh = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    to_out = Transformer.from_crs("EPSG:4979", f"EPSG:{epsg}", always_xy=True)
    err = []
    for r, e in zip(rows, exp, strict=True):
        assert abs(int(r["gps_week"]) * 604_800_000_000_000
                   + round(float(r["gps_tow_s"]) * 1e9) - e["falling_t_gps_ns"]) < 1_000
        lon, lat, h = to_llh.transform(*e["ecef_m"])
        x, y = to_out.transform(lon, lat)
        ant = (float(r["antenna_x_m"]), float(r["antenna_y_m"]), float(r["antenna_h_m"]))
        if r["quality_name"] == "fix":
            err.append(np.subtract(ant, (x, y, h)))
        # The lever arm moved the camera by |L| below the antenna (nadir camera assumed).
        d = np.subtract((float(r["x_m"]), float(r["y_m"]), float(r["h_m"])), ant)
        assert np.linalg.norm(d) == pytest.approx(math.dist((0, 0, 0), (0.16, -0.03, 0.57)),
                                                  abs=2e-3)
        assert r["attitude"] == "nadir-track"
    rms = float(np.sqrt(np.mean(np.sum(np.square(err), axis=1))))
    print(f"\ndemo flight: {len(err)} of {len(rows)} photos on fixed marks, antenna RMS "
          f"{rms * 100:.2f} cm against the truth")
    assert len(err) >= 0.9 * len(rows) and rms < 0.03


def test_geo_txt_reads_as_opendronemap_reads_it(solved: dict[str, Any]) -> None:
    # ODM: first line a projection (EPSG:N, proj4 or WGS84); then per image
    # "image_name geo_x geo_y [geo_z] [yaw pitch roll] [horz_accuracy vert_accuracy] [extras]",
    # separated by spaces; image names must be files of the image directory.
    lines = (solved["out"] / "geo.txt").read_text().splitlines()
    crs = CRS.from_user_input(lines[0])
    assert crs.is_projected and crs.to_epsg() is not None
    rows = {r["photo"]: r for r in _table(solved["out"] / "cameras.csv")}
    assert len(lines) - 1 == len(rows)
    for line in lines[1:]:
        f = line.split()
        assert len(f) == 9 and (solved["photos"] / f[0]).is_file()
        x, y, z, *_angles, horz, vert = (float(v) for v in f[1:])
        assert all(math.isfinite(v) for v in (x, y, z, horz, vert)) and horz > 0 and vert > 0
        assert (x, y, z) == pytest.approx(
            (float(rows[f[0]]["x_m"]), float(rows[f[0]]["y_m"]), float(rows[f[0]]["h_m"])),
            abs=1e-3)


def test_metashape_and_pix4d_csv_columns(solved: dict[str, Any]) -> None:
    rows = {r["photo"]: r for r in _table(solved["out"] / "cameras.csv")}
    ref_lines = (solved["out"] / "reference.csv").read_text().splitlines()
    assert ref_lines[0].startswith("# EPSG:")
    ref = list(csv.DictReader(ref_lines[1:]))
    assert tuple(ref[0].keys()) == REFERENCE_COLUMNS
    pix_lines = (solved["out"] / "pix4d.csv").read_text().splitlines()
    assert pix_lines[0].startswith("#") and "ellipsoidal" in pix_lines[0]  # PIX4Dmatic comment
    pix = list(csv.DictReader(pix_lines[1:], fieldnames=PIX4D_COLUMNS))
    assert tuple(pix[0].keys()) == PIX4D_COLUMNS
    assert [r["label"] for r in ref] == [r["imagename"] for r in pix] == list(rows)
    for m, p in zip(ref, pix, strict=True):
        c = rows[m["label"]]
        # Metashape: label, easting, northing, height; Pix4D: name, Y (northing), X (easting), Z.
        assert (float(m["x_east"]), float(m["y_north"]), float(m["z_height"])) == pytest.approx(
            (float(c["x_m"]), float(c["y_m"]), float(c["h_m"])), abs=1e-3)
        assert (float(p["X"]), float(p["Y"]), float(p["Z"])) == pytest.approx(
            (float(c["x_m"]), float(c["y_m"]), float(c["h_m"])), abs=1e-3)
        assert float(p["accuracy_horz"]) > 0 and float(p["accuracy_vert"]) > 0
        assert float(m["kappa_deg"]) == pytest.approx(float(c["kappa_deg"]), abs=1e-3)


def _positions(geom: dict[str, Any]) -> list[list[float]]:
    if geom["type"] == "Point":
        return [geom["coordinates"]]
    if geom["type"] in ("LineString", "MultiPoint"):
        return list(geom["coordinates"])
    raise AssertionError(f"unexpected geometry {geom['type']}")


def test_geojson_is_rfc7946(solved: dict[str, Any]) -> None:
    gj = json.loads((solved["out"] / "cameras.geojson").read_text())
    assert gj["type"] == "FeatureCollection" and "crs" not in gj  # RFC 7946: WGS84 only
    kinds: dict[str, int] = {}
    site_lat, site_lon = solved["truth"]["site_llh"][:2]
    for feat in gj["features"]:
        assert feat["type"] == "Feature" and isinstance(feat["properties"], dict)
        pts = _positions(feat["geometry"])
        if feat["geometry"]["type"] == "LineString":
            assert len(pts) >= 2
        for p in pts:
            assert len(p) == 3 and all(isinstance(v, float | int) for v in p)
            lon, lat = p[0], p[1]  # longitude first
            assert abs(lat - site_lat) < 0.05 and abs(lon - site_lon) < 0.05
        kind = feat["properties"]["kind"]
        kinds[kind] = kinds.get(kind, 0) + 1
    n = len(solved["truth"]["exposures"])
    assert kinds["photo"] == n and kinds["mark"] >= n and kinds["trajectory"] >= 1


class _Refs(html.parser.HTMLParser):
    """Every URL an HTML page would fetch (scripts, styles, images, frames, objects)."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []
        self.tags: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.add(tag)
        for name, value in attrs:
            if name in ("src", "href", "data") and value and not value.startswith(("#", "data:")):
                self.urls.append(value)


def test_report_html_is_self_contained(solved: dict[str, Any]) -> None:
    text = (solved["out"] / "report.html").read_text()
    refs = _Refs()
    refs.feed(text)
    assert refs.urls == []
    assert "url(http" not in text and "@import" not in text
    assert {"html", "svg"} <= refs.tags or {"html", "img"} <= refs.tags
    assert "demo5" in text and str(len(solved["truth"]["exposures"])) in text


def test_the_printed_notes_are_plain_words_with_the_engines_figures(
        solved: dict[str, Any]) -> None:
    """A surveyor reads the solve's printout: the engine's notes come in plain words with the
    figures of ``engine.json`` (which keeps the technical notes whole, as does the report)."""
    out: str = solved["stdout"]
    notes = [ln.removeprefix("note       ") for ln in out.splitlines()
             if ln.startswith("note       ")]
    printed = "\n".join(notes)
    for jargon in ("phase conditioning", "hidden found", "kept by doppler", "sqrt(s)",
                   "acceleration noise", "RTKLIB .pos (", "GPST", "chi-square", "Qf+Qb"):
        assert jargon not in printed, (jargon, printed)
    info = json.loads((solved["out"] / "rtklib" / "engine.json").read_text())
    t = info["conditioning"]["totals"]
    assert (f"carrier phase checked before solving: {t['receiver_slips']} cycle slips marked "
            f"by the receiver, {t['hidden_found']} more found where the phase was missing "
            f"(radio gaps, blank epochs); {t['repaired']} "
            f"phase jumps repaired, {t['half_resolved']} half-cycle ambiguities resolved, "
            f"{t['flagged']} breaks not bridged") in printed
    m = info["dynamics"]["measured"]
    used = " / ".join(info["dynamics"]["used"].values())
    assert (f"motion model set from how the rover moved: it sustained "
            f"{m['accel_h_m_s2']:.2f} m/s^2 horizontally and {m['accel_v_m_s2']:.2f} m/s^2 "
            "vertically") in printed
    assert f"engine setting {used} horizontal / vertical" in printed
    c = info["combination"]
    assert (f"forward and backward solutions merged: {c['both_fixed']} epochs fixed in both "
            f"directions, {c['demo5_rejected'] + c['chi2_rejected']} fixes set to float") \
        in printed
    assert "solution file in RTKLIB format (ECEF X/Y/Z, GPS time, date and time)" in printed
    # the technical detail stays whole in engine.json and in the report's notes
    assert any(n.startswith("phase conditioning: receiver slips") for n in info["notes"])
    report = (solved["out"] / "report.html").read_text(encoding="utf-8")
    assert "phase conditioning: receiver slips" in report and "m/s^2/sqrt(s)" in report
