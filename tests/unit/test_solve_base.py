"""The base station's position forms and the checks that a base recording can be this flight's.

Forms: ECEF, latitude/longitude/ellipsoidal height, and either one as the ground mark plus a
vertical antenna height give the same antenna reference point. Pairing: a base of another day
(RINEX 2 and 3 written here, the demo flight's MCAP as the rover), the flight's own recording,
and a base a continent away are refused with one line that says why; the demo's own base passes.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from grids import needs_egm96
from once import DemoFlight
from peers import cli_env

from groundstation.errors import ConfigError
from groundstation.geodesy import ecef_to_enu, ecef_to_llh, llh_to_ecef
from groundstation.gpstime import gps_as_datetime, gps_calendar_ns
from groundstation.solve.base import (
    BASE_FAR_REFUSED_M,
    BASE_KEYS,
    OWN_FIX_FLOOR_ENU_M,
    OwnFixes,
    base_from_own_fixes,
    base_position,
    check_distance,
    check_pairing,
    compare_base,
    observation_times,
)
from groundstation.solve.outputs import absolute_sd

XYZ = (3774696.5547, -596647.9083, 5089485.6511)  # the 2018-10-09 base of the jdesbonnet data


def test_ecef_and_latitude_longitude_height_give_the_same_point() -> None:
    lat, lon, h = ecef_to_llh(*XYZ)
    xyz, how = base_position(None, (lat, lon, h))
    assert xyz is not None and "--base-llh" in how
    assert math.dist(xyz, XYZ) < 1e-6
    same, how = base_position(XYZ, None)
    assert same == XYZ and how == "given with --base-xyz"


@pytest.mark.parametrize("antenna_m", [0.0, 1.5, 2.137])
def test_a_ground_mark_and_an_antenna_height_give_the_antenna_point(antenna_m: float) -> None:
    lat, lon, h = ecef_to_llh(*XYZ)
    mark = llh_to_ecef(lat, lon, h - antenna_m)
    from_llh, how = base_position(None, (lat, lon, h - antenna_m), antenna_m)
    from_xyz, _ = base_position(mark, None, antenna_m)
    assert from_llh is not None and from_xyz is not None
    assert math.dist(from_llh, XYZ) < 1e-6 and math.dist(from_xyz, XYZ) < 1e-6
    e, n, u = ecef_to_enu(from_xyz, mark)  # straight up from the mark
    assert abs(e) < 1e-6 and abs(n) < 1e-6 and abs(u - antenna_m) < 1e-6
    assert f"{antenna_m:.4f} m above it" in how


@pytest.mark.parametrize(("xyz", "llh", "ant", "key", "says"), [
    (XYZ, (53.0, -9.0, 80.0), None, "--base-llh", "not --base-xyz and --base-llh"),
    (None, (253.0, -9.0, 80.0), None, "--base-llh", "latitude first"),
    (None, (53.0, -9.0, 3.8e6), None, "--base-llh", "ellipsoidal metres"),
    (None, None, 1.5, "--base-antenna-height", "needs the mark's position"),
    (XYZ, None, -1.0, "--base-antenna-height", "from the ground mark up"),
])
def test_impossible_base_positions_are_refused_by_name(
        xyz: tuple[float, float, float] | None, llh: tuple[float, float, float] | None,
        ant: float | None, key: str, says: str) -> None:
    with pytest.raises(ConfigError) as err:
        base_position(xyz, llh, ant)
    assert err.value.key == key and says in err.value.message


@pytest.mark.parametrize("crs", [
    32629,
    pytest.param("32629+5773", marks=needs_egm96),
])
def test_a_base_in_a_projected_crs_is_the_same_point(crs: int | str) -> None:
    """Easting, northing and height (above the geoid with a vertical CRS) as a surveyor has
    them give the antenna's ECEF position to well under a millimetre; the exports' own
    projection is the forward direction."""
    from groundstation.solve.outputs import Projector

    lat, lon, h = ecef_to_llh(*XYZ)
    p = Projector(crs)
    e, n = p.forward(np.array([lat]), np.array([lon]))
    height = float(p.heights(np.array([lat]), np.array([lon]), np.array([h]))[0])
    if crs != 32629:
        assert 50.0 < h - height < 65.0  # the geoid is about 57 m above the ellipsoid there
    got, how = base_position(None, None, en=(float(e[0]), float(n[0]), height), crs=crs)
    assert got is not None and math.dist(got, XYZ) < 1e-4
    assert f"EPSG:{crs}" in how and f"WGS84 {lat:.9f}" in how


@pytest.mark.parametrize(("kw", "key", "says"), [
    ({"en": (501190.0, 5903719.0, 30.0)}, "--base-crs", "go together"),
    ({"crs": 32629}, "--base-en", "go together"),
    ({"en": (500000.0, 5.0e6, 10.0), "crs": 4326}, "--base-crs", "not a projected CRS"),
    ({"en": (1e9, 1e9, 10.0), "crs": 32629}, "--base-crs", "outside WGS 84 / UTM zone 29N"),
    ({"en": (501190.0, 5903719.0, 30.0), "crs": 32629, "xyz": XYZ}, "--base-en", "one of"),
])
def test_impossible_projected_bases_are_refused_by_name(
        kw: dict[str, object], key: str, says: str) -> None:
    xyz = kw.pop("xyz", None)
    with pytest.raises(ConfigError) as err:
        base_position(xyz, None, **kw)  # type: ignore[arg-type]
    assert err.value.key == key and says in err.value.message, err.value


def test_the_configuration_names_its_own_keys() -> None:
    with pytest.raises(ConfigError) as err:
        base_position(None, None, 1.5, {k: f"stations.a.{v}" for k, v in BASE_KEYS.items()})
    assert err.value.key == "stations.a.base_antenna_height_m"
    assert "stations.a.base_xyz or stations.a.base_llh" in err.value.message


def _rinex(path: Path, version: int, t0_gps_ns: int, n: int, pr_m: float) -> Path:
    """A small RINEX observation file: ``n`` epochs a second apart, G05 with C1C/C1."""
    if version == 3:
        head = ["     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE",
                "G    2 C1C L1C                                              SYS / # / OBS TYPES"]
    else:
        head = ["     2.11           OBSERVATION DATA    G (GPS)             RINEX VERSION / TYPE",
                "     2    C1    L1                                          # / TYPES OF OBSERV"]
    lines = [*head, " " * 60 + "END OF HEADER"]
    for k in range(n):
        t = gps_as_datetime(t0_gps_ns + k * 1_000_000_000)
        sec = f"{t.second + t.microsecond / 1e6:10.7f}"
        if version == 3:
            lines.append(f"> {t:%Y %m %d %H %M} {sec}  0  1")
            lines.append(f"G05{pr_m + k:14.3f}  {1.0:14.3f}  ")
        else:
            lines.append(f" {t:%y %m %d %H %M}".replace(" 0", "  ") + f" {sec}  0  1G05")
            lines.append(f"{pr_m + k:14.3f}  {1.0:14.3f}  ")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("version", [2, 3])
def test_rinex_epochs_are_read_on_gps_time(tmp_path: Path, version: int) -> None:
    t0 = gps_calendar_ns(gps_as_datetime(1_223_122_844_003_000_000))
    obs = observation_times(_rinex(tmp_path / "b.obs", version, t0, 5, 2.1e7))
    assert obs.span == (t0, t0 + 4_000_000_000)
    assert len(obs.pseudoranges) == (5 if version == 3 else 0)  # RINEX 2: times only


def test_a_base_of_another_day_is_refused_with_both_spans(
        demo_flight: DemoFlight, tmp_path: Path) -> None:
    rover = observation_times(demo_flight.files["MCAP"])
    assert rover.span is not None
    for version in (2, 3):
        base = _rinex(tmp_path / f"other{version}.obs", version, rover.span[0] - 86_400 * 10**9 * 3,
                      60, 2.1e7)
        with pytest.raises(ConfigError) as err:
            check_pairing(demo_flight.files["MCAP"], base)
        assert err.value.key == "--base"
        assert "does not overlap the flight in time: flight " in err.value.message
        assert "(3.0 days apart)" in err.value.message, err.value.message


def test_the_flights_own_recording_is_refused_as_its_base(demo_flight: DemoFlight) -> None:
    with pytest.raises(ConfigError) as err:
        check_pairing(demo_flight.files["MCAP"], demo_flight.files["MCAP"])
    assert err.value.key == "--base" and "is the flight's own recording" in err.value.message


def test_the_demos_base_is_this_flights(demo_flight: DemoFlight) -> None:
    covered = check_pairing(demo_flight.files["MCAP"], demo_flight.files["base UBX"])
    assert covered == ""  # the base covers the whole flight: nothing to add


def test_a_base_a_continent_away_is_refused() -> None:
    fixes = [llh_to_ecef(53.28 + 1e-5 * k, -8.98, 150.0) for k in range(20)]
    near = llh_to_ecef(53.3, -8.9, 90.0)
    d = check_distance(near, fixes)
    assert d is not None and 5_000 < d < 7_000
    far = llh_to_ecef(49.0, 8.4, 160.0)
    with pytest.raises(ConfigError) as err:
        check_distance(far, fixes)
    assert err.value.key == "--base" and "1300 km from the flight" in err.value.message
    assert check_distance(far, []) is None  # a flight without fixes: not checked
    assert float(np.linalg.norm(np.subtract(far, near))) > BASE_FAR_REFUSED_M


def test_solve_refuses_the_flight_as_its_own_base_before_writing(
        demo_flight: DemoFlight, tmp_path: Path) -> None:
    mcap = demo_flight.files["MCAP"]
    base = json.loads(demo_flight.files["truth"].read_text())["base"]["ecef_m"]
    lat, lon, h = ecef_to_llh(*base)
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "solve", str(mcap), "--base", str(mcap),
         "--base-llh", f"{lat:.9f},{lon:.9f},{h:.3f}", "--out-dir", "out",
         "--no-progress"],
        cwd=tmp_path, env=cli_env(), capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert "--base: " in proc.stderr and "the flight's own recording" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_the_bases_sigma_adds_to_every_cameras_absolute_sigma() -> None:
    rel = np.array([[0.01, 0.012, 0.03], [0.5, 0.4, 1.2], [np.nan, np.nan, np.nan]])
    assert np.array_equal(absolute_sd(rel, None), rel, equal_nan=True)  # base taken as exact
    ab = absolute_sd(rel, (1.0, 1.0, 2.0))
    np.testing.assert_allclose(ab[0], np.hypot(rel[0], (1.0, 1.0, 2.0)))
    assert (ab[:2] >= (1.0, 1.0, 2.0)).all() and np.isnan(ab[2]).all()


def test_without_coordinates_the_bases_own_fixes_give_it_to_metres() -> None:
    rng = np.random.default_rng(7)
    lat, lon, h = ecef_to_llh(*XYZ)
    fixes = [llh_to_ecef(lat + e / 111_000, lon, h + u)
             for e, u in zip(rng.normal(0, 0.5, 600), rng.normal(0, 12.0, 600), strict=True)]
    xyz, sd, n = base_from_own_fixes(fixes)
    assert n == 600 and math.dist(xyz, XYZ) < 2.0
    assert sd[0] == OWN_FIX_FLOOR_ENU_M[0] and sd[1] == OWN_FIX_FLOOR_ENU_M[1]  # floors
    assert 11.0 < sd[2] < 13.0  # the scatter where it is larger
    with pytest.raises(ConfigError) as err:
        base_from_own_fixes(fixes[:1])
    assert err.value.key == "--base-xyz" and "no receiver fixes" in err.value.message


def test_the_base_check_names_the_form_given_and_what_the_difference_looks_like() -> None:
    """A height above the geoid given as ellipsoidal is 50-odd metres off in height only: the
    check says so; a base thousands of kilometres off is refused naming the option the user
    gave, with the likely swap."""
    lat, lon, h = ecef_to_llh(*XYZ)
    fixes = [XYZ, XYZ]
    low = llh_to_ecef(lat, lon, h - 57.5)
    text, doubtful = compare_base(fixes, low, "given with --base-en 1,2,3 in EPSG:32629")
    assert doubtful and "-57.5 m of the difference in height" in text and "32629+5773" in text
    assert f"they put the base at {lat:.6f}, {lon:.6f}, {h:.1f} m" in text
    swapped = llh_to_ecef(lon, lat, h)
    with pytest.raises(ConfigError) as err:
        compare_base(fixes, swapped, f"given with --base-llh {lon},{lat},{h}")
    assert err.value.key == "--base-llh" and "Latitude and longitude swapped?" in err.value.message
    with pytest.raises(ConfigError) as err:
        compare_base(fixes, swapped, "given with --base-xyz")
    assert err.value.key == "--base-xyz" and "swapped" not in err.value.message



def test_the_base_check_from_the_fixes_mean_kept_for_a_rebase_says_the_same() -> None:
    """A solve keeps the mean of the base receiver's fixes (``solve.json``): a re-base checks
    the new coordinates against it without reading the base recording, in the same words."""
    fixes = [(XYZ[0] + d, XYZ[1] - d, XYZ[2] + 2 * d) for d in (-3.0, 0.5, 1.0, 4.0)]
    x, y, z = np.mean(np.array(fixes), axis=0).tolist()
    kept = OwnFixes((x, y, z), len(fixes))
    for near in (XYZ, llh_to_ecef(*np.add(ecef_to_llh(*XYZ), (0.0, 0.0, 30.0)))):
        assert compare_base(kept, near, "given with --base-xyz") == compare_base(
            fixes, near, "given with --base-xyz")
    assert "(the base recording has no receiver fix)" in compare_base(
        OwnFixes(None, 0), XYZ, "given with --base-xyz")[0]
