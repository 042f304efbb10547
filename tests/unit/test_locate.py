"""The pieces of ``locate-base`` that need no engine: the stated sigma, the reference position
from a RINEX header, compressed RINEX made readable, and base position files for ``solve``."""

from __future__ import annotations

import json
from pathlib import Path

import hatanaka
import pytest

from groundstation.errors import ConfigError
from groundstation.solve.locate import (
    FLOAT_FLOOR_M,
    header_position,
    honest_sigma,
    navigation_beside,
    plain_rinex,
    read_base_position,
)

HEADER = (
    "     2.11           OBSERVATION DATA    G (GPS)             RINEX VERSION / TYPE\n"
    "3040                                                        MARKER NAME\n"
    " -3978242.4348  3382841.1715  3649902.7667                  APPROX POSITION XYZ\n"
    "     1    C1                                                # / TYPES OF OBSERV\n"
    "                                                            END OF HEADER\n"
    " 05  4  2  0  0  0.0000000  0  1G03\n"
    "  24801780.917\n"
)


def test_the_sigma_is_never_below_what_an_l1_static_baseline_is_good_to() -> None:
    formal = (0.0017, 0.0021, 0.0024)
    e, n, u = honest_sigma(formal, 3300.0, fixed=True)
    assert e == pytest.approx(0.0083) and n == pytest.approx(0.0083)
    assert u == pytest.approx(0.0166)
    assert honest_sigma((0.05, 0.001, 0.2), 3300.0, fixed=True) == pytest.approx(
        (0.05, 0.0083, 0.2))  # a larger formal sigma is kept
    assert honest_sigma(formal, 3300.0, fixed=False) == (FLOAT_FLOOR_M,) * 3
    assert honest_sigma((float("nan"),) * 3, 0.0, fixed=True) == pytest.approx(
        (0.005, 0.005, 0.010))


@pytest.mark.parametrize("compression", ["none", "gz", "Z"])
def test_a_reference_position_from_plain_and_compressed_headers(
        tmp_path: Path, compression: str) -> None:
    if compression == "none":
        path = tmp_path / "30400920.05o"
        path.write_text(HEADER)
    else:
        path = tmp_path / f"30400920.05d.{'gz' if compression == 'gz' else 'Z'}"
        path.write_bytes(hatanaka.compress(HEADER.encode(), compression=compression))
    assert header_position(path) == (-3978242.4348, 3382841.1715, 3649902.7667)
    plain = plain_rinex(path, tmp_path, "reference")
    assert plain.name.endswith(".obs") and plain.read_text() == HEADER


def test_no_header_position(tmp_path: Path) -> None:
    p = tmp_path / "x.05o"
    p.write_text(HEADER.replace("-3978242.4348  3382841.1715  3649902.7667",
                                "        0.0000        0.0000        0.0000"))
    assert header_position(p) is None


def test_navigation_files_of_the_same_station(tmp_path: Path) -> None:
    for name in ("30400920.05o", "30400920.05n.gz", "30400920.05g", "07590920.05n",
                 "3040_notes.txt", "3040MGEX_R_20050920000_01D_MN.rnx.gz"):
        (tmp_path / name).write_text("x")
    assert [p.name for p in navigation_beside(tmp_path / "30400920.05o")] == [
        "30400920.05g", "30400920.05n.gz", "3040MGEX_R_20050920000_01D_MN.rnx.gz"]


def test_base_position_files(tmp_path: Path) -> None:
    good = tmp_path / "base.json"
    good.write_text(json.dumps({"ecef_m": [-3976219.1866, 3382371.6045, 3652511.1441],
                                "sigma_enu_m": [0.0083, 0.0083, 0.0166],
                                "reference": "30400920.05d.gz", "baseline_m": 3312.5}))
    xyz, sd, how = read_base_position(good)
    assert xyz == (-3976219.1866, 3382371.6045, 3652511.1441)
    assert sd == (0.0083, 0.0083, 0.0166)
    assert how == "from base.json (located against 30400920.05d.gz, baseline 3.31 km)"
    cases = {"text.json": "not json", "list.json": "[1, 2]",
             "short.json": json.dumps({"ecef_m": [1.0, 2.0]}),
             "centre.json": json.dumps({"ecef_m": [1.0, 2.0, 3.0]})}
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ConfigError) as err:
            read_base_position(tmp_path / name)
        assert err.value.key == "--base-position", name
