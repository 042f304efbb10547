"""Heights in the output: ellipsoidal, above a geoid grid the user gives, or above the geoid of a
compound CRS's vertical part, never ellipsoidal heights under a vertical CRS's label.

The geoid grid is written here (GTX: a header and a float grid, as NOAA defines it) with a
geoid that rises 1 m per degree north and 0.5 m per degree east, so the heights PROJ gives
through it can be checked against the plane by hand. EGM96 (Debian's proj-data, which CI
installs) is checked against pyproj's own transformation with the same grid.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from grids import needs_egm96

from groundstation.config import SOLVER_STATION_KEYS, convert
from groundstation.errors import ConfigError
from groundstation.solve.outputs import ELLIPSOIDAL, Projector


def _plane_geoid(path: Path) -> Path:
    """A GTX grid over 50-56 N, 12-6 W: N = 50 + (lat - 50) + 0.5 (lon + 12) metres."""
    lat0, lon0, step, rows, cols = 50.0, -12.0, 0.25, 25, 25
    values = [50.0 + r * step + 0.5 * c * step for r in range(rows) for c in range(cols)]
    path.write_bytes(struct.pack(">4d2i", lat0, lon0 % 360.0, step, step, rows, cols)
                     + struct.pack(f">{rows * cols}f", *values))
    return path


def test_heights_stay_ellipsoidal_without_a_vertical_crs() -> None:
    p = Projector(32629)
    assert not p.vertical and p.height_datum == ELLIPSOIDAL
    h = p.heights(np.array([53.28]), np.array([-8.98]), np.array([100.0]))
    assert h.tolist() == [100.0]


def test_heights_above_a_geoid_grid_the_user_gives(tmp_path: Path) -> None:
    p = Projector(32629, _plane_geoid(tmp_path / "plane.gtx"))
    assert p.height_datum == "orthometric height above the geoid grid plane.gtx"
    lat = np.array([53.28, 51.013, 55.5, np.nan])
    lon = np.array([-8.98, -11.2, -6.6, -8.0])
    h = np.array([100.0, 20.0, 300.0, 50.0])
    n = 50.0 + (lat - 50.0) + 0.5 * (lon + 12.0)
    out = p.heights(lat, lon, h)
    np.testing.assert_allclose(out[:3], (h - n)[:3], atol=1e-3)
    assert np.isnan(out[3])  # no position, no height


def test_a_geoid_grid_that_misses_the_flight_is_refused(tmp_path: Path) -> None:
    p = Projector(32633, _plane_geoid(tmp_path / "plane.gtx"))
    with pytest.raises(ConfigError) as err:
        p.heights(np.array([48.2]), np.array([16.4]), np.array([200.0]))
    assert err.value.key == "--geoid" and "does not cover 48.20000, 16.40000" in err.value.message


@pytest.mark.parametrize(("epsg", "geoid", "key", "says"), [
    (5773, None, "--epsg", "has no horizontal coordinates"),
    (9707, "plane.gtx", "--geoid", "already names its heights"),
    (32629, "missing.gtx", "--geoid", "no such file"),
    (32629, "not-a-grid.gtx", "--geoid", "PROJ cannot read it as a geoid grid"),
    (99999, None, "--epsg", "unknown EPSG code"),
])
def test_impossible_height_settings_are_refused(
        tmp_path: Path, epsg: int, geoid: str | None, key: str, says: str) -> None:
    _plane_geoid(tmp_path / "plane.gtx")
    (tmp_path / "not-a-grid.gtx").write_text("not a grid\n")
    with pytest.raises(ConfigError) as err:
        Projector(epsg, tmp_path / geoid if geoid else None)
    assert err.value.key == key and says in err.value.message, err.value.message


def test_a_vertical_crs_is_never_labelled_over_ellipsoidal_heights() -> None:
    """EGM2008's grid is not in Debian's proj-data: refused, or (where PROJ has it) heights
    that are not the ellipsoidal ones."""
    try:
        p = Projector("32629+3855")
    except ConfigError as err:
        assert err.key == "--epsg" and "us_nga_egm08_25.tif" in err.message
        assert "never written under a vertical CRS's label" in err.message
        return
    h = p.heights(np.array([53.28]), np.array([-8.98]), np.array([100.0]))
    assert abs(float(h[0]) - 100.0) > 10.0  # the geoid is ~57 m there


def test_compound_codes_are_read_from_the_configuration() -> None:
    key = SOLVER_STATION_KEYS["epsg"]
    assert convert(key, "epsg", "EPSG:32629+5773", from_text=True) == "32629+5773"
    assert convert(key, "epsg", "9707", from_text=True) == 9707
    for bad in ("32629+57+73", "utm", "32629+"):
        with pytest.raises(ConfigError, match="horizontal\\+vertical"):
            convert(key, "epsg", bad, from_text=True)


@needs_egm96
@pytest.mark.parametrize("epsg", [9707, "32629+5773"])
def test_egm96_heights_equal_pyprojs_with_the_same_grid(epsg: int | str) -> None:
    from pyproj import Transformer

    p = Projector(epsg)  # appends Debian's grid directory to pyproj's search path
    assert p.height_datum.startswith("EGM96 height, orthometric (geoid grid us_nga_egm96_15")
    lat = np.array([53.28, 53.29, -33.9, 64.1])
    lon = np.array([-8.98, -8.97, 18.4, -21.9])
    h = np.array([100.0, 140.0, 30.0, 80.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a missing grid must not pass as a ballpark
        ref = Transformer.from_crs("EPSG:4979", f"EPSG:{epsg}", always_xy=True, only_best=True)
        x, y, big_h = ref.transform(lon, lat, h)
    np.testing.assert_allclose(p.heights(lat, lon, h), big_h, atol=1e-3)
    assert abs(float(h[0] - big_h[0]) - 57.48) < 0.05  # EGM96 near Galway
    if epsg == "32629+5773":
        ex, ey = p.forward(lat[:2], lon[:2])
        np.testing.assert_allclose(ex, x[:2], atol=1e-3)
        np.testing.assert_allclose(ey, y[:2], atol=1e-3)
