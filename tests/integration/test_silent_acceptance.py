"""Inputs that cannot give a useful result: each gives a clear line and an exit status.

Exit statuses (README "Exit status"): 2 for a bad option or configuration (names the option),
1 for an input that cannot be used (a JPEG or an empty file instead of a recording, a flight
without marks, a solve that positions nothing). A doubtful base is a warning with exit 0: the
solution may still be usable, and the report says how far off the base is; a base kilometres
off (another day's coordinates) is refused before the engine runs (exit 2, names --base-xyz).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from groundstation.ubx.framer import UbxFramer

# One worker runs this module's tests (pytest-xdist):
# its module fixture simulates a flight, made once.
pytestmark = pytest.mark.xdist_group("test_silent_acceptance")

# A JPEG as a camera writes it: SOI, APP1 (Exif) with NUL bytes in it.
JPEG = (b"\xff\xd8\xff\xe1\x00\x16Exif\x00\x00II*\x00\x08\x00\x00\x00\x00\x00"
        + bytes(64) + b"\xff\xd9")


def _cli(*args: str, cwd: Path, timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    root = Path(__file__).resolve().parents[2]
    path = os.pathsep.join((str(root), os.environ.get("PYTHONPATH", "")))
    env = {**os.environ, "PYTHONPATH": path}
    return subprocess.run([sys.executable, "-m", "groundstation.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout_s, check=False)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A short simulated flight (5 marks), its base stream and the base's true position."""
    d = tmp_path_factory.mktemp("silent")
    proc = _cli("simulate", "--out", "f.ubx", "--base-out", "b.ubx", "--truth", "t.json",
                "--duration", "120", "--faults", "none", cwd=d)
    assert proc.returncode == 0, proc.stderr
    (d / "photo.jpg").write_bytes(JPEG)
    (d / "empty.ubx").write_bytes(b"")
    return {"dir": d, "flight": d / "f.ubx", "base": d / "b.ubx", "truth": d / "t.json"}


def _base_xyz(flight: dict[str, Path], up_m: float = 0.0) -> str:
    from groundstation import jsonio

    x, y, z = jsonio.loads(flight["truth"].read_bytes())["base"]["ecef_m"]
    return f"{x},{y},{z + up_m}"


@pytest.mark.parametrize("name", ["photo.jpg", "empty.ubx"])
@pytest.mark.parametrize("command", [["inspect"], ["replay", "--no-zenoh"],
                                     ["run", "--no-zenoh", "--file"]])
def test_no_ubx_frames_is_an_error(flight: dict[str, Path], command: list[str],
                                   name: str) -> None:
    proc = _cli(*command, name, cwd=flight["dir"])
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "no UBX frames in this file" in proc.stderr
    assert ("a JPEG image" if name.endswith("jpg") else "empty file") in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (flight["dir"] / "flights").exists()  # run refused before recording anything


def test_photos_folder_without_jpegs_exits_2(flight: dict[str, Path]) -> None:
    d = flight["dir"] / "nophotos"
    d.mkdir(exist_ok=True)
    (d / "notes.txt").write_text("no photos here\n")
    proc = _cli("solve", "--no-pdf", "f.ubx", "--base", "b.ubx", "--base-xyz", _base_xyz(flight),
                "--photos", "nophotos", "--out-dir", "o_photos", "--no-progress",
                cwd=flight["dir"])
    assert proc.returncode == 2, proc.stderr
    assert "--photos: nophotos: no JPEG files" in proc.stderr


def test_base_xyz_given_as_lat_lon_h_exits_2(flight: dict[str, Path]) -> None:
    proc = _cli("solve", "--no-pdf",
                "f.ubx", "--base", "b.ubx", "--base-xyz", "49.0146,8.4004,166.5",
                "--out-dir", "o_llh", "--no-progress", cwd=flight["dir"])
    assert proc.returncode == 2, proc.stderr
    assert "--base-xyz" in proc.stderr and "latitude,longitude,height" in proc.stderr
    assert "give those with --base-llh" in proc.stderr  # the option that takes them
    assert not (flight["dir"] / "o_llh").exists()


def test_base_100_m_off_warns(flight: dict[str, Path]) -> None:
    proc = _cli("solve", "--no-pdf",
                "f.ubx", "--base", "b.ubx", "--base-xyz", _base_xyz(flight, 100.0),
                "--out-dir", "o_off", "--no-progress", cwd=flight["dir"])
    assert proc.returncode == 0, proc.stderr
    assert "WARNING base coordinates" in proc.stdout and "100." in proc.stdout
    assert "base coordinates doubtful" in proc.stderr
    # The engine's records name its files where they are, not the run's staging folder.
    out = flight["dir"] / "o_off"
    records = [p for p in out.rglob("*") if p.suffix in (".pos", ".json", ".html")]
    assert len(records) >= 3 and (out / "rtklib" / "engine.json").is_file()
    assert not [p for p in records if b".groundstation-staging-" in p.read_bytes()]
    assert ".groundstation-staging-" not in proc.stdout
    assert "<code>pos1-posmode = kinematic</code>" in (out / "report.html").read_text()  # read


def test_flight_without_marks_exits_2(flight: dict[str, Path]) -> None:
    framer = UbxFramer()
    kept = b"".join(f.raw for f in framer.feed(flight["flight"].read_bytes(), 0)
                    if (f.cls, f.id) != (0x0D, 0x03))  # TIM-TM2 out
    (flight["dir"] / "nomarks.ubx").write_bytes(kept)
    proc = _cli("solve", "--no-pdf",
                "nomarks.ubx", "--base", "b.ubx", "--base-xyz", _base_xyz(flight),
                "--out-dir", "o_nomarks", "--no-progress", cwd=flight["dir"])
    assert proc.returncode == 2, proc.stderr
    assert "no camera marks in this flight" in proc.stderr and "TIM-TM2" not in proc.stderr


def test_solve_that_positions_nothing_exits_1(flight: dict[str, Path]) -> None:
    # A .pos from another day: every mark falls outside it, so every export would be empty.
    # (GPST 2001-01-01 00:00:00 is 23:59:47 UTC the day before: 13 leap seconds.)
    (flight["dir"] / "other_day.pos").write_text(
        "%  GPST                      x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns\n"
        "2001/01/01 00:00:00.000   4146349.2471    612312.5498   4791750.8505   1   8\n"
        "2001/01/01 00:00:01.000   4146349.2471    612312.5498   4791750.8505   1   8\n",
        encoding="ascii")
    proc = _cli("solve", "--no-pdf", "f.ubx", "--positions", "other_day.pos", "--out-dir", "o_none",
                "--no-progress", cwd=flight["dir"])
    assert proc.returncode == 1, proc.stdout + proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    spans = "the positions (other_day.pos) span 2000-12-31 23:59:47 - 23:59:48 UTC, the marks "
    assert "0 positioned" in last and spans in last and "no overlap" in last, proc.stderr
    assert not (flight["dir"] / "o_none").exists()  # no empty exports left behind


def test_base_kilometres_off_is_refused_before_any_work(flight: dict[str, Path]) -> None:
    proc = _cli("solve", "--no-pdf",
                "f.ubx", "--base", "b.ubx", "--base-xyz", _base_xyz(flight, 5000.0),
                "--out-dir", "o_5km", "--no-progress", cwd=flight["dir"])
    assert proc.returncode == 2, proc.stderr
    assert "configuration error: --base-xyz: 5.00 km from where the base receiver's own" \
        in proc.stderr
    assert "rnx2rtkp" not in proc.stderr and "engine" not in proc.stderr
    assert not (flight["dir"] / "o_5km").exists()


def test_positions_given_a_photo_says_so(flight: dict[str, Path]) -> None:
    proc = _cli("solve", "--no-pdf", "f.ubx", "--positions", "photo.jpg", "--out-dir", "o_jpg",
                "--no-progress", cwd=flight["dir"])
    assert proc.returncode == 2
    assert "photo.jpg: not an RTKLIB .pos text file (binary data)" in proc.stderr
    assert "\ufffd" not in proc.stderr and "JFIF" not in proc.stderr and "Exif" not in proc.stderr


@pytest.mark.parametrize(("argv", "env", "named"), [
    (["watch", "--connect", "foo:bar", "--duration", "1"], {}, "zenoh.connect: 'foo:bar'"),
    (["run", "--port", "/dev/null", "--zenoh-listen", "foo", "--duration", "1"], {},
     "zenoh.listen: 'foo'"),
    (["run", "--port", "/dev/null", "--duration", "1"], {"GROUNDSTATION_SOURCE_BAUD": "fast"},
     "source.baud"),
    (["run", "--port", "/dev/null", "--duration", "1"], {"GROUNDSTATION_SORUCE_BAUD": "9600"},
     "GROUNDSTATION_SORUCE_BAUD: unknown environment variable"),
])
def test_bad_configuration_exits_2_naming_the_key(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, argv: list[str], env: dict[str, str],
    named: str,
) -> None:
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    proc = _cli(*argv, cwd=tmp_path, timeout_s=60)
    assert proc.returncode == 2, proc.stderr
    assert named in proc.stderr and "Traceback" not in proc.stderr
    assert "JSON5" not in proc.stderr  # not Zenoh's own parser error


def test_inspect_says_what_it_measures(flight: dict[str, Path], shared_data: Path) -> None:
    from dataclasses import replace

    from groundstation.commands.inspect import format_summary
    from groundstation.offline.inspect import TimeMarkSummary, inspect_path

    s = inspect_path(flight["flight"])
    text = format_summary(replace(s, timemarks=TimeMarkSummary()))
    assert "marks     none: no camera marks in this recording" in text  # not all zeros
    assert "0 falling edges" not in text
    mcap = format_summary(replace(s, format="mcap", file_bytes=1234))
    assert f"(mcap, 1,234 bytes on disk, {s.bytes:,} bytes of receiver stream)" in mcap
    rover = shared_data / "real/jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz"
    if not rover.exists():
        pytest.skip(f"{rover} not present")
    real = format_summary(inspect_path(rover))
    assert "R255" not in real
    assert "measurements of GLONASS satellites the receiver had not identified yet" in real
    pos = shared_data / "real/tridge__pyUblox/data/6P-raw-PPP.ubx"
    gaps = format_summary(inspect_path(pos))
    assert "after week 1729 tow 249844.999 (21:23:48.999 UTC): 2 missing" in gaps


def test_kappa_is_the_same_in_a_geographic_crs(flight: dict[str, Path]) -> None:
    """κ from the track in metres: EPSG:4326 and the UTM zone agree (to the grid convergence),
    where degree differences gave 48.6 instead of 59.5 deg; geo.txt carries it as yaw."""
    import csv

    kappas = []
    for epsg, out in (("4326", "o_geo"), (None, "o_utm")):
        extra = ["--epsg", epsg] if epsg else []
        proc = _cli("solve", "--no-pdf",
                    "f.ubx", "--base", "b.ubx", "--base-xyz", _base_xyz(flight),
                    "--out-dir", out, "--no-progress", *extra, cwd=flight["dir"])
        assert proc.returncode == 0, proc.stderr
        rows = list(csv.DictReader(
            line for line in (flight["dir"] / out / "cameras.csv").read_text().splitlines()
            if not line.startswith("#")))
        kappas.append([float(r["kappa_deg"]) for r in rows])
    geo, utm = kappas
    assert len(geo) == len(utm) >= 3
    for a, b in zip(geo, utm, strict=True):
        assert abs((a - b + 180) % 360 - 180) < 1.0, (geo, utm)
