"""The solver on a real flight (jdesbonnet 2018-10-09) against RTKLIB's own positions at marks."""

from __future__ import annotations

import csv
import datetime as dt
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from groundstation import gpstime
from groundstation.cli import main
from groundstation.solve import exif
from groundstation.solve import interpolate as ip
from groundstation.solve.engine import run_engine
from groundstation.solve.flight import read_flight
from groundstation.solve.posfile import read_pos

pytestmark = pytest.mark.shared_data

JD = "real/jdesbonnet__GNSS_RTK_data/20181009"
REF = "reference/rnx2rtkp_pos"
BASE_XYZ = (3774696.5547, -596647.9083, 5089485.6511)  # "ref pos" of RTKLIB's solution


@pytest.fixture(scope="module")
def jd(shared_data: Path) -> dict[str, Path]:
    return {
        "rover": shared_data / JD / "rover-20181009-1221.ubx.gz",
        "base": shared_data / JD / "base-20181009-1220.ubx.gz",
        "pos": shared_data / REF / "jd_20181009_kin_vs_M8Pbase_svin.pos.gz",
        "events": shared_data / REF / "jd_20181009_kin_vs_M8Pbase_svin_events.pos.gz",
    }


def test_linear_marks_equal_rtklib_events_within_a_millimetre(jd: dict[str, Path]) -> None:
    rec = read_flight(jd["rover"])
    from groundstation.rules.marks import build_marks

    marks = build_marks(rec.timemarks)
    times = [ip.mark_time_ns(m.falling_t_gps_ns, m.rising_t_gps_ns, "falling") for m in marks]
    mp = ip.interpolate_linear(read_pos(jd["pos"]), times)
    ev = read_pos(jd["events"])
    t = mp.t_gps_ns
    # RTKLIB prints event times to the microsecond: pair each event with the mark within 1 µs.
    j = np.searchsorted(t, ev.t_gps_ns)
    cand = np.stack([np.clip(j - 1, 0, t.size - 1), np.clip(j, 0, t.size - 1)])
    best = cand[np.argmin(np.abs(t[cand] - ev.t_gps_ns), axis=0), np.arange(ev.t_gps_ns.size)]
    assert np.all(np.abs(t[best] - ev.t_gps_ns) <= 1000)
    d = np.linalg.norm(mp.ecef_m[best] - ev.ecef_m, axis=1)
    kept, ours = len(ev), mp.positioned
    dropped = sorted(set(range(len(marks))) - set(best.tolist()))
    print(f"marks {len(marks)}, RTKLIB events {kept}, ours positioned {ours}, "
          f"max difference {d.max() * 1000:.3f} mm, RTKLIB dropped {len(dropped)}: {dropped}")
    assert len(marks) == 589 and kept == 582
    assert d.max() < 0.001
    assert np.array_equal(mp.quality[best], ev.quality)
    assert ours == 589 and len(dropped) == 7
    assert np.all(np.isfinite(mp.ecef_m[dropped]))


def _photos_for_marks(
    mark_t: list[int], d: Path, clock_error_s: float, skip: set[int]
) -> dict[int, str]:
    """A JPEG per mark (except ``skip``), camera clock in local time (+01:00) and off by some."""
    d.mkdir()
    names = {}
    k = 0
    for i, t in enumerate(mark_t):
        if i in skip:
            continue
        k += 1
        cam_ns = gpstime.gps_to_unix_ns(t) + round((3600 + clock_error_s) * 1e9)
        sec, frac = divmod(cam_ns, 10**9)
        when = dt.datetime.fromtimestamp(sec, tz=dt.UTC).replace(tzinfo=None)
        name = f"IMG_{k:04d}.JPG"
        (d / name).write_bytes(exif.make_jpeg(when, subsec=f"{frac // 10**7:02d}"))
        names[i] = name
    return names


def test_solve_command_end_to_end(jd: dict[str, Path], tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    rec = read_flight(jd["rover"])
    from groundstation.rules.marks import build_marks

    marks = build_marks(rec.timemarks)
    t = [m.falling_t_gps_ns for m in marks]
    assert all(x is not None for x in t)
    skip = {5, 77, 300}
    names = _photos_for_marks([x for x in t if x is not None], tmp_path / "photos",
                              -(47 * 60 + 12.34), skip)
    photo_dir = tmp_path / "photos"
    before = {p.name: p.read_bytes() for p in photo_dir.iterdir()}
    eo = tmp_path / "eo.csv"
    eo.write_text("name,X,Y,Z,omega,phi,kappa\nIMG_0001.JPG,0,0,0,1.0,-2.0,95.0\n")
    out = tmp_path / "out"
    rc = main([
        "solve", "--no-pdf", str(jd["rover"]), "--positions", str(jd["pos"]),
        "--photos", str(photo_dir),
        "--lever-arm", "0.16,-0.03,0.57", "--eo", str(eo), "--epsg", "25829",
        "--interp", "smoother", "--exif", "--out", str(out), "--no-progress",
    ])
    assert rc == 0
    text = capsys.readouterr().out
    assert "586 paired" in text and "3 marks without photo" in text
    # cameras.csv: every photo, its own mark, the columns we promise.
    lines = [ln for ln in (out / "cameras.csv").read_text().splitlines() if not ln.startswith("#")]
    rows = list(csv.DictReader(lines))
    from groundstation.solve.outputs import CAMERAS_COLUMNS

    assert tuple(rows[0].keys()) == CAMERAS_COLUMNS
    by_photo = {r["photo"]: r for r in rows if r["photo"]}
    assert len(by_photo) == 586
    for i, name in names.items():
        assert int(by_photo[name]["mark"]) == i
    orphans = sorted(int(r["mark"]) for r in rows if not r["photo"])
    assert orphans == sorted(skip)
    assert by_photo["IMG_0001.JPG"]["attitude"] == "eo"
    assert by_photo["IMG_0002.JPG"]["attitude"] == "nadir-track"
    # The lever arm moved the camera by |L| from the antenna.
    r2 = by_photo["IMG_0002.JPG"]
    delta = np.array([float(r2["x_m"]) - float(r2["antenna_x_m"]),
                      float(r2["y_m"]) - float(r2["antenna_y_m"]),
                      float(r2["h_m"]) - float(r2["antenna_h_m"])])
    assert np.linalg.norm(delta) == pytest.approx(np.linalg.norm([0.16, -0.03, 0.57]), abs=1e-3)
    assert delta[2] == pytest.approx(-0.57, abs=1e-3)
    # geo.txt: projection line, then name x y z yaw pitch roll horz vert.
    geo = (out / "geo.txt").read_text().splitlines()
    assert geo[0] == "EPSG:25829" and len(geo) == 587
    f = geo[1].split()
    assert len(f) == 9 and f[0] in before and 400_000 < float(f[1]) < 700_000
    assert 5_800_000 < float(f[2]) < 6_000_000 and 0 <= float(f[4]) < 360  # yaw from kappa
    assert all(float(v) == 0 for v in f[5:7])  # nadir: pitch, roll
    ref = (out / "reference.csv").read_text().splitlines()
    assert ref[0].startswith("#") and ref[1].startswith("label,x_east,y_north,z_height")
    pix4d_header = (out / "pix4d.csv").read_text().splitlines()[0]
    assert pix4d_header.startswith("#imagename,Y,X,Z,accuracy_horz,accuracy_vert ; EPSG:25829")
    gj = json.loads((out / "cameras.geojson").read_text())
    kinds = {feat["properties"]["kind"] for feat in gj["features"]}
    assert gj["type"] == "FeatureCollection" and kinds == {"trajectory", "mark", "photo"}
    for feat in gj["features"]:
        geom = feat["geometry"]
        first = geom["coordinates"][0] if geom["type"] == "LineString" else geom["coordinates"]
        lon, lat = first[:2]
        assert -10 < lon < -8 and 53 < lat < 54
    html = (out / "report.html").read_text()
    assert html.count("<svg") >= 3 and "<script" not in html and "http://" not in \
        html.replace("http://www.w3.org/2000/svg", "")
    # EXIF copies written, originals untouched.
    assert len(list((out / "photos").iterdir())) == 586
    assert {p.name: p.read_bytes() for p in photo_dir.iterdir()} == before


def test_solve_refuses_to_write_into_the_photo_directory(
    jd: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "a.jpg").write_bytes(bytes.fromhex("ffd8ffd9"))  # a photo folder
    rc = main(["solve", "--no-pdf", str(jd["rover"]), "--positions", str(jd["pos"]), "--photos",
               str(tmp_path / "p"), "--out", str(tmp_path / "p" / "out"), "--no-progress"])
    assert rc == 2 and "--out" in capsys.readouterr().err


@pytest.mark.parametrize("engine", [
    "demo5",
    pytest.param("rnx2rtkp", marks=pytest.mark.skipif(
        shutil.which("rnx2rtkp") is None, reason="rnx2rtkp not installed (apt-get install rtklib)"
    )),
])
def test_rtklib_engine_on_the_real_flight(jd: dict[str, Path], tmp_path: Path, engine: str) -> None:
    out = run_engine(engine, jd["rover"], jd["base"], BASE_XYZ, tmp_path).pos_path
    ours = read_pos(out)
    ref = read_pos(jd["pos"])
    common, i, j = np.intersect1d(ours.t_gps_ns // 10**6, ref.t_gps_ns // 10**6,
                                  return_indices=True)
    both_fixed = (ours.quality[i] == 1) & (ref.quality[j] == 1)
    d = np.linalg.norm(ours.ecef_m[i][both_fixed] - ref.ecef_m[j][both_fixed], axis=1)
    print(f"{engine} on our RINEX: {len(ours)} epochs, {ours.fixed_fraction:.1%} fixed; reference "
          f"(GPS+GLONASS): {ref.fixed_fraction:.1%}; {both_fixed.sum()} common fixed epochs, "
          f"median difference {np.median(d) * 100:.1f} cm")
    assert len(ours) > 1500 and ours.fixed_fraction > 0.5
    assert both_fixed.sum() > 1000 and np.median(d) < 0.05


@pytest.mark.parametrize(("first", "count"), [(99, 50), (0, 5)])
def test_photo_subset_in_utc_is_not_shifted_by_whole_marks(
    jd: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str],
    first: int, count: int,
) -> None:
    # The surveyor's check: whole-second photos stamped with the UTC second of some marks. The
    # marks come every 2.0 s (a timer), so shifts by whole marks pair them as well; the camera
    # clock set to UTC names the right one and the solve says so.
    from groundstation.rules.marks import build_marks

    marks = build_marks(read_flight(jd["rover"]).timemarks)
    d = tmp_path / "photos"
    d.mkdir()
    for i in range(first, first + count):
        t = marks[i].falling_t_gps_ns
        assert t is not None
        sec = gpstime.gps_to_unix_ns(t) // 10**9
        when = dt.datetime.fromtimestamp(sec, tz=dt.UTC).replace(tzinfo=None)
        (d / f"IMG_{i + 1:04d}.JPG").write_bytes(exif.make_jpeg(when))
    out = tmp_path / "out"
    rc = main(["solve", "--no-pdf", str(jd["rover"]), "--positions", str(jd["pos"]),
               "--photos", str(d), "--out-dir", str(out), "--no-progress"])
    assert rc == 0
    text = capsys.readouterr().out
    assert f"{count} paired" in text
    # GPS - camera is the 18 leap seconds less the half second the photos are put into theirs.
    offset = next(ln for ln in text.splitlines() if ln.startswith("camera clock offset"))
    gps_minus_camera = float(offset.split(":")[1].split()[0])
    assert 17.0 < gps_minus_camera < 19.0, offset
    assert "18 s leap seconds (GPS - UTC)" in offset
    assert "camera clock set to UTC" in text and "ambiguous" not in text
    lines = [ln for ln in (out / "cameras.csv").read_text().splitlines() if not ln.startswith("#")]
    got = {r["photo"]: int(r["mark"]) for r in csv.DictReader(lines) if r["photo"]}
    assert got == {f"IMG_{i + 1:04d}.JPG": i for i in range(first, first + count)}
    assert f"GPS − camera {gps_minus_camera:+.2f}" in (out / "report.html").read_text()
