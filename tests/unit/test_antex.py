"""The base antenna's L1 phase-centre offset from an ANTEX file: the antenna found by type and
radome (NONE when none is written), G01's north/east/up in mm as east/north/up in metres, the
position moved by it; an antenna not in the file, one without an L1 calibration, a file that
is not ANTEX, and the type without the file (or the reverse) are refused naming the option."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from antex_file import antenna_block, write_antex

from groundstation.errors import ConfigError
from groundstation.geodesy import ecef_to_llh, enu_rotation
from groundstation.solve.antex import l1_offset, rinex_antenna
from groundstation.solve.base import base_position

XYZ = (3774696.5547, -596647.9083, 5089485.6511)


@pytest.fixture
def atx(tmp_path: Path) -> Path:
    return write_antex(
        tmp_path / "test.atx",
        antenna_block("GOODANT1", "NONE", {"G01": (1.20, -0.80, 66.40), "G02": (0, 0, 60.0)}),
        antenna_block("GOODANT1", "SCIS", {"G01": (0.0, 0.0, 70.0)}),
        antenna_block("L2ONLY", "NONE", {"G02": (0.0, 0.0, 50.0)}))


def test_the_offset_by_type_and_radome(atx: Path) -> None:
    assert l1_offset(atx, "GOODANT1") == pytest.approx((-0.0008, 0.0012, 0.0664))
    assert l1_offset(atx, "goodant1 NONE") == pytest.approx((-0.0008, 0.0012, 0.0664))
    assert l1_offset(atx, "GOODANT1 SCIS")[2] == pytest.approx(0.070)


def test_the_base_position_moves_by_the_offset(atx: Path) -> None:
    xyz, how = base_position(XYZ, None, 1.5, antenna="GOODANT1 NONE", antex_file=atx)
    assert xyz is not None
    lat, lon, _ = ecef_to_llh(*XYZ)
    enu = np.array(enu_rotation(lat, lon)) @ (np.array(xyz) - np.array(XYZ))
    assert enu == pytest.approx((-0.0008, 0.0012, 1.5 + 0.0664), abs=1e-6)
    assert "L1 phase-centre offset of GOODANT1 NONE in test.atx: north/east/up 1.2/-0.8/66.4" \
        in how and "1.5000 m above it" in how


@pytest.mark.parametrize(("kwargs", "key", "said"), [
    ({"antenna": "NOSUCH NONE"}, "--base-antenna", "NOSUCH NONE is not in test.atx (3 antennas"),
    ({"antenna": "GOODANT NONE"}, "--base-antenna",
     "of a similar name: GOODANT1 NONE, GOODANT1 SCIS"),
    ({"antenna": "L2ONLY"}, "--base-antenna", "L2ONLY NONE has no GPS L1 (G01) calibration"),
    ({"antenna": "GOODANT1", "antex_file": None}, "--base-antenna", "goes with --antex FILE"),
    ({"antenna": None}, "--antex", "needs the base antenna's type: --base-antenna TYPE"),
])
def test_what_cannot_give_an_offset_is_refused(
        atx: Path, kwargs: dict[str, object], key: str, said: str) -> None:
    args: dict[str, object] = {"antex_file": atx, **kwargs}
    with pytest.raises(ConfigError) as err:
        base_position(XYZ, None, **args)  # type: ignore[arg-type]
    assert err.value.key == key and said in str(err.value), str(err.value)


def test_a_file_that_is_not_antex(tmp_path: Path) -> None:
    path = tmp_path / "x.atx"
    path.write_text("hello\n")
    with pytest.raises(ConfigError, match="not an ANTEX file"):
        l1_offset(path, "GOODANT1")


def test_the_type_in_a_rinex_header(tmp_path: Path) -> None:
    path = tmp_path / "base.obs"
    path.write_text(f"{'     3.04           OBSERVATION DATA    G':<60}RINEX VERSION / TYPE\n"
                    f"{'1234':<20}{'GOODANT1        NONE':<20}{'':<20}ANT # / TYPE\n"
                    f"{'':<60}END OF HEADER\n")
    assert rinex_antenna(path) == "GOODANT1        NONE"
    assert math.isclose(l1_offset(write_antex(tmp_path / "a.atx", antenna_block(
        "GOODANT1", "NONE", {"G01": (0, 0, 10.0)})), rinex_antenna(path) or "")[2], 0.01)
