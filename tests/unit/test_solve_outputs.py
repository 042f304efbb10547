"""Output formats (cameras.csv, geo.txt, Metashape/Pix4D CSV, GeoJSON, report) and CLI errors."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from groundstation.cli import main
from groundstation.errors import ConfigError
from groundstation.solve import outputs, report, report_data
from groundstation.solve.interpolate import FLAG_GAP, FLAG_NOT_FIXED

T = 2022 * 604_800 * 10**9 + 217_373_138_511_198


@pytest.fixture()
def out() -> outputs.SolveOutput:
    proj = outputs.Projector(25832)
    lat = np.array([50.0, 50.0001, math.nan])
    lon = np.array([9.0, 9.0001, math.nan])
    x, y = proj.forward(lat, lon)
    rows = (
        outputs.CameraRow("IMG_0001.JPG", 0, 3, T, lat[0], lon[0], 150.0, x[0], y[0],
                          0.01, 0.02, 0.03, 1, 0, 0.0, 0.0, 45.0, "nadir-track"),
        outputs.CameraRow("IMG_0002.JPG", 1, 5, T + 10**9, lat[1], lon[1], 151.0, x[1], y[1],
                          0.2, 0.1, 0.4, 2, FLAG_GAP | FLAG_NOT_FIXED),
        outputs.CameraRow("IMG_0003.JPG", -1, -1, -1, lat[2], lon[2], math.nan, x[2], y[2],
                          math.nan, math.nan, math.nan, 0, 0),
        outputs.CameraRow("", 2, 7, T + 2 * 10**9, 50.0002, 9.0002, 152.0, 1.0, 2.0,
                          0.01, 0.01, 0.02, 1, 0),
    )
    llh = np.array([[50.0, 9.0, 150.0], [50.0001, 9.0001, 151.0], [50.0002, 9.0002, 152.0]])
    return outputs.SolveOutput(
        rows=rows, epsg=25832, crs_name=proj.name, projected=True,
        trajectory_llh=llh, trajectory_quality=np.array([1, 1, 2]),
        trajectory_t_gps_ns=np.array([T, T + 10**9, T + 2 * 10**9]),
        mark_llh=llh, mark_t_gps_ns=np.array([T, T + 10**9, T + 2 * 10**9]),
        notes=("a note",),
    )


def test_projector_round_trip_and_utm_zone() -> None:
    p = outputs.Projector(25832)
    assert p.projected and "UTM zone 32N" in p.name
    x, y = p.forward(np.array([50.0]), np.array([9.0]))
    assert x[0] == pytest.approx(500_000.0, abs=0.01)  # 9°E is the central meridian
    lat, lon = p.inverse(x, y)
    assert lat[0] == pytest.approx(50.0) and lon[0] == pytest.approx(9.0)
    assert outputs.utm_epsg(53.28, -9.06) == 32629
    assert outputs.utm_epsg(-33.9, 18.4) == 32734
    with pytest.raises(ConfigError) as err:
        outputs.Projector(999999)
    assert err.value.key == "--epsg"


def test_cameras_csv(out: outputs.SolveOutput) -> None:
    text = outputs.cameras_csv(out)
    assert text.startswith("# crs EPSG:25832")
    rows = list(csv.DictReader(ln for ln in text.splitlines() if not ln.startswith("#")))
    assert tuple(rows[0]) == outputs.CAMERAS_COLUMNS
    assert rows[0]["gps_week"] == "2022" and rows[0]["gps_tow_s"] == "217373.138511198"
    assert rows[0]["utc"] == "2018-10-09T12:22:35.138511198Z"
    assert rows[1]["flags"] == "gap;not_fixed" and rows[1]["quality_name"] == "float"
    assert rows[2]["x_m"] == "" and rows[2]["mark"] == ""
    assert rows[3]["photo"] == "" and rows[3]["mark_count"] == "7"


def test_cameras_csv_and_the_report_say_what_mark_and_mark_count_are(
    out: outputs.SolveOutput,
) -> None:
    """``mark`` and ``mark_count`` differ after the first mark that never arrived (here 0/3,
    1/5, 2/7): the file's own header and the report's marks section say which is which and
    why, not only the README."""
    header = [ln for ln in outputs.cameras_csv(out).splitlines() if ln.startswith("#")]
    lines = [ln for ln in header if "mark_count" in ln]
    assert len(lines) == 1, header
    said = lines[0]
    for words in ("mark is the row's index among the marks received",
                  "mark_count is the receiver's own number of the pulse", "TIM-TM2",
                  "mark_NNNN", "They differ after a mark that never arrived"):
        assert words in said, said
    inp = report_data.ReportInput(
        flight="f.ubx", engine_name="E", engine_version="", engine_options={},
        position_source="p", base_name=None, base_ecef_m=None, base_check="none",
        base_doubtful=False, epsg=out.epsg, crs_name=out.crs_name, projected=True,
        lever_arm_m=None, shutter_delay_ms=0.0, edge="falling", interp="linear", max_gap_s=1.0,
        rows=out.rows, marks_total=3, marks_duplicate=0, track_t_gps_ns=out.trajectory_t_gps_ns,
        track_x_m=np.array([500000.0, 500007.0, 500014.0]),
        track_y_m=np.array([5538000.0, 5538011.0, 5538022.0]),
        track_quality=np.array([1, 2, 5]), photos_total=3, photos_unmatched=(),
        pair_t_gps_ns=out.trajectory_t_gps_ns[:2], pair_residual_s=np.array([0.01, -0.02]),
        pair_window_s=0.1, lever_residual_m=np.array([0.001, 0.2]),
        lever_outlier=np.array([False, True]), notes=(),
    )
    html = report.render_html(inp)
    assert "coordinate epoch 20" in html  # the flight's, as a decimal year
    legend = html[html.index('<section class="positions">'):html.index('id="marks"')]
    # the report's column is "count" (cameras.csv's mark_count)
    assert "count (mark_count in cameras.csv) is the receiver&#x27;s own number" in legend
    assert "They differ after a mark that never arrived" in legend


def test_geo_txt(out: outputs.SolveOutput) -> None:
    lines = outputs.geo_txt(out).splitlines()
    assert lines[0] == "EPSG:25832"
    assert len(lines) == 3  # unpositioned photos and marks without photo are left out
    f = lines[1].split()
    assert f[0] == "IMG_0001.JPG" and len(f) == 9
    assert float(f[1]) == pytest.approx(500_000.0, abs=0.01)
    # yaw = compass direction of the image x axis = 90 - kappa (kappa 45 here); nadir
    assert f[4:7] == ["45.00", "0", "0"] and f[7] == "0.020" and f[8] == "0.030"


def test_reference_and_pix4d(out: outputs.SolveOutput) -> None:
    ref = outputs.reference_csv(out).splitlines()
    assert ref[0].startswith("# EPSG:25832")
    assert ref[1] == ",".join(outputs.REFERENCE_COLUMNS)
    assert ref[2].startswith("IMG_0001.JPG,500000.000,")
    assert ref[2].endswith(",0.0000,0.0000,45.0000,none")
    pix = outputs.pix4d_csv(out).splitlines()
    # PIX4Dmatic: no header row, the column names in a '#' comment (with CRS and datum)
    assert pix[0].startswith("#imagename,Y,X,Z,accuracy_horz,accuracy_vert ; EPSG:25832")
    assert "WGS84 ellipsoidal" in pix[0] and len(pix) == 3
    name, y, x = pix[1].split(",")[:3]
    assert name == "IMG_0001.JPG" and float(x) < float(y)


def test_geojson_is_valid_rfc7946(out: outputs.SolveOutput) -> None:
    gj = json.loads(outputs.geojson(out))
    assert gj["type"] == "FeatureCollection" and gj["height_datum"] == "WGS84 ellipsoidal"
    kinds = [f["properties"]["kind"] for f in gj["features"]]
    assert kinds.count("trajectory") == 2 and kinds.count("mark") == 3
    assert kinds.count("photo") == 2
    for f in gj["features"]:
        assert f["type"] == "Feature" and f["geometry"]["type"] in ("Point", "LineString")
        coords = f["geometry"]["coordinates"]
        pts = coords if f["geometry"]["type"] == "LineString" else [coords]
        for lon, lat, _h in pts:
            assert lon == pytest.approx(9.0, abs=0.01) and lat == pytest.approx(50.0, abs=0.01)


def test_write_all_and_report(out: outputs.SolveOutput, tmp_path: Path) -> None:
    paths = outputs.write_all(out, tmp_path / "o")
    assert sorted(p.name for p in paths) == sorted(outputs.WRITERS)
    t = out.trajectory_t_gps_ns
    inp = report_data.ReportInput(
        flight="f.ubx", engine_name="E", engine_version="", engine_options={"a": "<b>"},
        position_source="p", base_name=None, base_ecef_m=None, base_check="none",
        base_doubtful=False, epsg=out.epsg, crs_name=out.crs_name, projected=True,
        lever_arm_m=None, shutter_delay_ms=0.0, edge="falling", interp="linear", max_gap_s=1.0,
        rows=out.rows, marks_total=3, marks_duplicate=0, track_t_gps_ns=t,
        track_x_m=np.array([500000.0, 500007.0, 500014.0]),
        track_y_m=np.array([5538000.0, 5538011.0, 5538022.0]),
        track_quality=np.array([1, 2, 5]), photos_total=3,
        photos_unmatched=(("IMG_0003.JPG", "no time"),), pair_t_gps_ns=t[:2],
        pair_residual_s=np.array([0.01, -0.02]), pair_window_s=0.1,
        lever_residual_m=np.array([0.001, 0.2]), lever_outlier=np.array([False, True]),
        notes=("<n>",),
    )
    c = report_data.counts(inp)
    assert (c["fixed"], c["float"], c["not_positioned"], c["photos_matched"],
            c["photos_unmatched"], c["orphan_marks"], c["marks_bridging_gap"]) == (2, 1, 1, 2,
                                                                                 1, 1, 1)
    html = report.render_html(inp)
    # Trajectory, quality, sigmas, timing, lever arm; escaped text; no script, no link.
    assert html.count("<svg") == 5 and "&lt;n&gt;" in html and "&lt;b&gt;" in html
    assert "<script" not in html and "http" not in html
    assert "1 photo(s) without a time mark: IMG_0003.JPG" in html
    assert "No lever arm applied" in html
    assert report_data.utc_text(T) == "2018-10-09 12:22:35.138"
    assert report_data.gps_text(T) == "2022 217373.138"
    # Photo pairing: the clock offset as GPS - camera with its parts; an ambiguous pairing
    # is a warning the reviewer reads first after the base.
    amb = "photo pairing ambiguous: 3 camera clock offsets pair the photos about equally well"
    inp = replace(inp, clock_offset_s=17.63, clock_leap_s=18, pairing_warnings=(amb,))
    assert report_data.warnings(inp)[0] == "P" + amb[1:]
    html = report.render_html(inp)
    assert "GPS − camera +17.630 s = 18 s leap seconds (GPS − UTC) -0.370 s (UTC − camera)" in html
    # A re-base keeps every figure a rigid move leaves as it was, read back from the page: the
    # map only when it is drawn from the base (in the CRS's own coordinates it moves)
    kept = report.figures_in(html)
    assert {k.split("@")[0] for k in kept} == {"quality", "sigmas", "timing", "lever"}
    assert all(svg.startswith("<svg") and svg.rstrip().endswith("</svg>") for svg in kept.values())
    from_base = replace(inp, map_origin=(500010.0, 5538010.0))
    page = report.render_html(from_base)
    assert "Easting from the base (m)" in page and "E 500010.000, N 5538010.000 m" in page
    kept = report.figures_in(page)
    assert {k.split("@")[0] for k in kept} == {"trajectory-from-base", "quality", "sigmas",
                                               "timing", "lever"}
    mark = {k: f'<svg class="fig" aria-label="{k}"><text>kept {k}</text></svg>' for k in kept}
    again = report.render_html(replace(from_base, kept_figures=mark))
    assert report.figures_in(again) == mark  # taken as they were, none drawn again
    # the flight and its base moved alike: every figure kept; anything else changed (a row's
    # grade, a residual): the figures that show it are drawn again
    moved = replace(from_base, map_origin=(500011.0, 5538009.5), kept_figures=mark,
                    track_x_m=from_base.track_x_m + 1.0, track_y_m=from_base.track_y_m - 0.5)
    assert report.figures_in(report.render_html(moved)) == mark
    other = replace(from_base, kept_figures=mark, lever_residual_m=np.array([0.002, 0.2]),
                    rows=(replace(from_base.rows[0], grade="float"), *from_base.rows[1:]))
    redrawn = {k.split("@")[0] for k, svg in report.figures_in(report.render_html(other)).items()
               if svg not in mark.values()}
    assert redrawn == {"trajectory-from-base", "quality", "lever"}


def test_output_dir_inside_photos_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as err:
        outputs.check_output_dir(tmp_path / "p" / "o", [tmp_path / "p"])
    assert err.value.key == "--out"
    outputs.check_output_dir(tmp_path / "o", [tmp_path / "p"])


@pytest.mark.parametrize(
    ("extra", "option"),
    [
        ([], "--positions"),
        (["--base", "B", "--base-sigma", "1"], "--base-sigma"),
        (["--positions", "P", "--interp", "cubic"], "--interp"),
        (["--positions", "P", "--edge", "up"], "--edge"),
        (["--positions", "P", "--max-gap", "-1"], "--max-gap"),
        (["--positions", "P", "--lever-arm", "1,2"], "--lever-arm"),
        (["--positions", "P", "--epsg", "utm"], "--epsg"),
        (["--positions", "P", "--shutter-delay-ms", "x"], "--shutter-delay-ms"),
        (["--positions", "missing.pos"], "--positions"),
    ],
)
def test_bad_arguments_exit_2_naming_the_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], option: str
) -> None:
    pos = tmp_path / "P"
    pos.write_text("x\n")
    (tmp_path / "B").write_text("x\n")
    args = [a if a not in ("P", "B") else str(tmp_path / a) for a in extra]
    rc = main(["solve", "--no-pdf", str(tmp_path / "f.ubx"), "--out", str(tmp_path / "o"), *args])
    assert rc == 2
    assert option in capsys.readouterr().err
