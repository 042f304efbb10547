"""Position sources: every RTKLIB .pos form, the engines' configuration, the receiver's fix."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

from groundstation import gpstime
from groundstation.errors import ConfigError, InputError
from groundstation.geodesy import ecef_to_llh, llh_to_ecef
from groundstation.records import NavSolution
from groundstation.solve import engine, posfile
from groundstation.solve import positions as pos
from groundstation.solve.engine.protocol import EngineError, ToolMissingError
from groundstation.solve.engine.rnx2rtkp import Rnx2rtkpEngine, find_rnx2rtkp, rnx2rtkp_command
from groundstation.solve.trajectory import Q_SINGLE

XYZ = (3774698.5996, -596649.3002, 5089487.3800)
LAT, LON, H = ecef_to_llh(*XYZ)
T_GPS = gpstime.gps_ns(2022, 217_330_999_659_000)  # 2018/10/09 12:22:10.999659 GPST

XYZ_TEXT = """\
% program   : rnx2rtkp ver.EX 2.5.1
% ref pos   :   3774696.5547   -596647.9083   5089485.6511
%
%  GPST                         x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns   sdx(m)   sdy(m)   sdz(m)  sdxy(m)  sdyz(m)  sdzx(m) age(s)  ratio
2018/10/09 12:22:10.999659   3774698.5996   -596649.3002   5089487.3800   2  14   2.5988   1.7252   2.5642  -1.3743  -0.3307   1.9516   3.99    0.0
2018/10/09 12:22:11.999658   3774698.6113   -596649.3071   5089487.3631   1  14   0.0100   0.0100   0.0100   0.0000   0.0000   0.0000   4.99    5.1
"""  # noqa: E501


def test_xyz_with_header() -> None:
    t = posfile.parse_pos(XYZ_TEXT, source="x")
    assert len(t) == 2 and t.t_gps_ns[0] == T_GPS
    assert t.ecef_m[0] == pytest.approx(XYZ)
    assert t.quality.tolist() == [2, 1] and t.ns.tolist() == [14, 14]
    assert t.ratio[1] == pytest.approx(5.1)
    assert t.sd_enu_m[1] == pytest.approx([0.01, 0.01, 0.01], abs=1e-6)
    # Covariance terms are undone (sign * square) before rotating to east/north/up.
    assert 0.5 < t.sd_enu_m[0, 0] < 3.0


def test_llh_degrees_and_dms_and_tow_and_utc() -> None:
    deg = (
        "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   "
        "sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n"
        f"2018/10/09 12:22:10.999659 {LAT:.9f} {LON:.9f} {H:.4f} 1 9 0.01 0.02 0.03 0 0 0 0 9.9\n"
    )
    t = posfile.parse_pos(deg)
    assert t.ecef_m[0] == pytest.approx(XYZ, abs=1e-3)
    assert t.sd_enu_m[0] == pytest.approx([0.02, 0.01, 0.03])

    def dms(v: float) -> str:
        a = abs(v)
        d, m = int(a), int((a - int(a)) * 60)
        s = (a - d - m / 60) * 3600
        return f"{'-' if v < 0 else ''}{d} {m:02d} {s:08.5f}"

    dms_text = (
        "%  UTC                   latitude(d'\")   longitude(d'\")  height(m)   Q  ns   sdn(m)   "
        "sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n"
        f"2018/10/09 12:21:52.999659 {dms(LAT)} {dms(LON)} {H:.4f} 1 9 0.01 0.02 0.03 0 0 0 0 9.9\n"
    )
    t2 = posfile.parse_pos(dms_text)
    assert t2.t_gps_ns[0] == T_GPS  # UTC + 18 s leap seconds
    assert t2.ecef_m[0] == pytest.approx(XYZ, abs=2e-3)

    tow = (
        "%  GPST          x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns\n"
        f"2022 217330.999659 {XYZ[0]} {XYZ[1]} {XYZ[2]} 5 6\n"
    )
    t3 = posfile.parse_pos(tow)
    assert t3.t_gps_ns[0] == T_GPS and t3.quality[0] == 5
    assert np.isnan(t3.sd_enu_m[0]).all()


def test_enu_baseline_uses_the_reference_position() -> None:
    ref_llh = ecef_to_llh(3774696.5547, -596647.9083, 5089485.6511)
    text = (
        f"% ref pos   : {ref_llh[0]:.9f} {ref_llh[1]:.9f} {ref_llh[2]:.4f}\n"
        "%  GPST                    e-baseline(m)  n-baseline(m)  u-baseline(m)   Q  ns   sde(m)"
        "   sdn(m)   sdu(m)  sden(m)  sdnu(m)  sdue(m) age(s)  ratio\n"
        "2018/10/09 12:22:10.999659   10.0000   20.0000   -1.0000   1  14   0.0050   0.0060"
        "   0.0100   0.0000   0.0000   0.0000   0.00    3.2\n"
    )
    t = posfile.parse_pos(text)
    back = ecef_to_llh(*t.ecef_m[0])
    assert back[2] == pytest.approx(ref_llh[2] - 1.0, abs=1e-3)
    assert t.sd_enu_m[0] == pytest.approx([0.005, 0.006, 0.01])
    with pytest.raises(InputError):
        posfile.parse_pos(text.splitlines()[1:])


def test_headerless_rows_and_float_columns() -> None:
    # rtklibexplorer's style: Q and ns written as floats; here without any header at all.
    rows = (
        f"2018/10/09 12:22:10.999659 {LAT:.7f} {LON:.7f} {H:.7f} 1.0000000 25.0000000 "
        "0.0099 0.0099 0.0100 0 0 0 0 0 0.001 -0.002 0.027\n"
        f"2018/10/09 12:22:10.999659 {XYZ[0]} {XYZ[1]} {XYZ[2]} 2 9\n"
    )
    t = posfile.parse_pos(rows.splitlines()[:1])
    assert t.quality[0] == 1 and t.ns[0] == 25
    assert t.ecef_m[0] == pytest.approx(XYZ, abs=0.02)
    t2 = posfile.parse_pos(rows.splitlines()[1:])
    assert t2.ecef_m[0] == pytest.approx(XYZ)
    with pytest.raises(InputError):
        posfile.parse_pos("% only a header\n")
    with pytest.raises(InputError):
        posfile.parse_pos("2018/10/09 12:22:10 abc def ghi 1 2\n")


def test_read_pos_gz_and_sorting(tmp_path: Path) -> None:
    lines = XYZ_TEXT.splitlines()
    shuffled = "\n".join([*lines[:4], lines[5], lines[4], lines[4]]) + "\n"
    p = tmp_path / "x.pos.gz"
    p.write_bytes(gzip.compress(shuffled.encode()))
    t = posfile.read_pos(p)
    assert len(t) == 2 and np.all(np.diff(t.t_gps_ns) > 0)
    with pytest.raises(InputError):
        posfile.read_pos(tmp_path / "missing.pos")


def test_rnx2rtkp_options_and_command() -> None:
    opts, _ = engine.resolve_options(Rnx2rtkpEngine(), (1.0, 2.0, 3.0))
    assert opts["pos1-posmode"] == "kinematic" and opts["pos1-frequency"] == "l1"
    assert opts["pos1-navsys"] == "1" and opts["pos2-armode"] == "fix-and-hold"
    assert opts["pos1-soltype"] == "combined" and opts["pos1-elmask"] == "15"
    assert opts["ant2-postype"] == "xyz" and opts["ant2-pos1"] == "1.0000"
    assert "pos1-ephem" not in opts  # not a key: b34 ignored it without a word
    cmd = rnx2rtkp_command("rnx2rtkp", Path("c.conf"), Path("o.pos"), Path("r.obs"),
                           Path("b.obs"), [Path("n.nav")])
    assert cmd == ["rnx2rtkp", "-k", "c.conf", "-o", "o.pos", "r.obs", "b.obs", "n.nav"]


def test_missing_rnx2rtkp_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ToolMissingError, match="install RTKLIB"):
        find_rnx2rtkp("rnx2rtkp-that-does-not-exist")


def test_registry_and_config_errors() -> None:
    assert set(pos.POSITION_SOURCES) == {"pos", "rtklib", "receiver"}
    with pytest.raises(ConfigError) as err:
        pos.get_source("magic")
    assert "known" in str(err.value)
    with pytest.raises(ConfigError) as err2:
        pos.get_source("rtklib").trajectory(pos.SourceOptions(flight=Path("f.ubx")))
    assert err2.value.key == "--base"


def test_receiver_fix_is_flagged_metre_level() -> None:
    sols = [
        NavSolution("NAV-SOL", 217_331_000_000_000 + k * 200_000_000, 2022, 3, True, 9,
                    llh_to_ecef(LAT, LON, H + k), LAT, LON, H + k, None, None, 2.5)
        for k in range(5)
    ]
    sols.append(NavSolution("NAV-POSLLH", 217_332_000_000_000, None, -1, True, None,
                            XYZ, LAT, LON, H, 1.0, 2.0, 2.2))
    t = pos.get_source("receiver").trajectory(pos.SourceOptions(nav_solutions=tuple(sols)))
    assert t.metre_level and len(t) == 6 and set(t.quality.tolist()) == {Q_SINGLE}
    assert t.t_gps_ns[-1] == gpstime.gps_ns(2022, 217_332_000_000_000)
    assert t.sd_enu_m[-1, 2] == pytest.approx(2.0)
    with pytest.raises(InputError):
        pos.trajectory_from_nav([])


@pytest.mark.skipif(shutil.which("rnx2rtkp") is None,
                    reason="rnx2rtkp not installed (apt-get install rtklib)")
def test_rnx2rtkp_failure_is_reported(tmp_path: Path) -> None:
    bad = tmp_path / "r.obs"
    bad.write_text("not rinex\n")
    nav = tmp_path / "r.nav"
    nav.write_text("not rinex either\n")
    with pytest.raises(EngineError):
        engine.run_engine("rnx2rtkp", bad, bad, (1.0, 2.0, 3.0), tmp_path / "w")


def test_demo5_failure_is_reported(tmp_path: Path) -> None:
    bad = tmp_path / "r.obs"
    bad.write_text("not rinex\n")
    (tmp_path / "r.nav").write_text("not rinex either\n")
    with pytest.raises(EngineError, match="demo5"):
        engine.run_engine("demo5", bad, bad, (1.0, 2.0, 3.0), tmp_path / "w")
