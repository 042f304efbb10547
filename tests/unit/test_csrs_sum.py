"""A CSRS-PPP summary as the base position (``solve --base-position F.sum``): the global-frame
records read (not the NAD83 ones), degrees-minutes-seconds with the sign on the degrees (``-0``
too), 95 % sigmas as one sigma; a summary with NAD83 only, or none at all, is refused naming the
option."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from groundstation.errors import ConfigError
from groundstation.geodesy import ecef_to_llh, llh_to_ecef
from groundstation.solve.locate import read_base_position

XYZ = (3774696.5547, -596647.9083, 5089485.6511)  # jdesbonnet's 2018-10-09 base


def _dms(deg: float) -> str:
    a = abs(deg)
    d, rest = int(a), (a - int(a)) * 60
    m, s = int(rest), (rest - int(rest)) * 60
    return f"{'-' if deg < 0 else ''}{d:d} {m:02d} {s:08.5f}"


def _records(frame: str, lat: float, lon: float, h: float, off: float = 0.0) -> str:
    ep = "18:282:45000"
    return (f"POS LAT {frame} {ep}   {_dms(lat + 1e-4)}   {_dms(lat + off)}   -11.1  0.392\n"
            f"POS LON {frame} {ep}   {_dms(lon - 1e-4)}   {_dms(lon + off)}     6.6  0.196\n"
            f"POS HGT {frame} {ep}   {h + 2.0:14.4f}   {h:14.4f}   -2.0000  0.784\n")


def test_the_global_frame_position_and_one_sigma(tmp_path: Path) -> None:
    lat, lon, h = ecef_to_llh(*XYZ)
    path = tmp_path / "BASE.sum"
    path.write_text("HDR CSRS-PPP summary\n" + _records("NAD83(CSRS)", lat, lon, h, 2e-5)
                    + _records("IGS14", lat, lon, h))
    xyz, sd, how = read_base_position(path)
    assert math.dist(xyz, XYZ) < 0.001  # the IGS14 block, not the NAD83 one 2 m away
    assert sd == pytest.approx((0.1, 0.2, 0.4))  # 95 % / 1.96
    assert "NRCan CSRS-PPP, IGS14, epoch 2018.77" in how and "decimetres" in how


def test_a_position_west_of_greenwich_within_a_degree(tmp_path: Path) -> None:
    xyz0 = llh_to_ecef(51.5, -0.4, 50.0)  # longitude -0 24 00.0: the sign on a zero degree
    path = tmp_path / "b.sum"
    path.write_text(_records("IGb14", 51.5, -0.4, 50.0))
    xyz, _, _ = read_base_position(path)
    assert math.dist(xyz, xyz0) < 0.001


@pytest.mark.parametrize(("text", "said"), [
    (("POS LAT NAD83(CSRS) 18:282:45000 49 0 0.0 49 0 0.0 0 0.1\n"
      "POS LON NAD83(CSRS) 18:282:45000 -8 0 0.0 -8 0 0.0 0 0.1\n"
      "POS HGT NAD83(CSRS) 18:282:45000 80.0 80.0 0 0.1\n"), "frames found: NAD83(CSRS)"),
    ("CSRS-PPP\nnothing here\n", "frames found: none"),
])
def test_a_summary_without_a_global_position_is_refused(
        tmp_path: Path, text: str, said: str) -> None:
    path = tmp_path / "x.sum"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        read_base_position(path)
    assert err.value.key == "--base-position" and said in str(err.value)
