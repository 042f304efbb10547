"""RTKLIB accepts the simulator's output: convbin RINEX, single-point and PPK against the truth."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from groundstation.gnss.ephemeris import GPS_PI
from groundstation.records import RawEpoch
from groundstation.sim.stream import SimConfig, SimResult, simulate
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import iter_frames

# One worker runs this module's tests (pytest-xdist): its module fixture simulates a flight,
# made once.
pytestmark = [pytest.mark.skipif(
    shutil.which("convbin") is None or shutil.which("rnx2rtkp") is None,
    reason="RTKLIB (convbin, rnx2rtkp) not installed: apt-get install rtklib",
), pytest.mark.xdist_group("test_sim_rtklib")]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[SimResult, Path]:
    d = tmp_path_factory.mktemp("rtklib")
    result = simulate(SimConfig(duration_s=300.0, seed=2))
    (d / "rover.ubx").write_bytes(result.rover_bytes)
    (d / "base.ubx").write_bytes(result.base_bytes)
    for name in ("rover", "base"):
        subprocess.run(
            ["convbin", "-r", "ubx", "-v", "2.11", "-od", "-os", "-o", f"{name}.obs",
             "-n", f"{name}.nav", f"{name}.ubx"],
            cwd=d, check=True, capture_output=True, timeout=60,
        )
    return result, d


def _epochs_in_rinex(path: Path) -> int:
    body = path.read_text().split("END OF HEADER", 1)[1].splitlines()
    return sum(1 for line in body if len(line) > 32 and line[28] == "0" and line[0] == " "
               and line[1:3].strip().isdigit() and line[3] == " ")


def _read_nav(path: Path) -> list[dict[str, Any]]:
    lines = path.read_text().split("END OF HEADER", 1)[1].splitlines()[1:]
    out = []
    for i in range(0, len(lines) - 7, 8):
        rec = lines[i : i + 8]

        def vals(line: str, first: int) -> list[float]:
            return [float(line[first + 19 * k : first + 19 * (k + 1)].replace("D", "E"))
                    for k in range(4 if first == 3 else 3) if line[first + 19 * k :].strip()]

        head = vals(rec[0], 22)
        body = [v for line in rec[1:] for v in vals(line, 3)]
        out.append({"sv": int(rec[0][:2]), "af0": head[0], "af1": head[1], "af2": head[2],
                    "o": body})
    return out


def _pos(path: Path) -> np.ndarray[Any, np.dtype[np.float64]]:
    rows = [ln.split() for ln in path.read_text().splitlines() if ln and not ln.startswith("%")]
    return np.array([[float(x) for x in r[:6]] for r in rows])


def _errors(result: SimResult, sol: np.ndarray[Any, np.dtype[np.float64]]
            ) -> np.ndarray[Any, np.dtype[np.float64]]:
    traj = result.truth["trajectory"]
    t = np.array(traj["t_gps_ns"]) / 1e9
    ts = sol[:, 0] * 604800 + sol[:, 1]
    ref = np.stack([np.interp(ts, t, np.array(traj[k])) for k in ("x_m", "y_m", "z_m")], axis=1)
    return np.asarray(np.linalg.norm(sol[:, 2:5] - ref, axis=1), dtype=np.float64)


def test_convbin_epoch_count_matches_our_decoder(run: tuple[SimResult, Path]) -> None:
    result, d = run
    for name, data in (("rover", result.rover_bytes), ("base", result.base_bytes)):
        decoder = Decoder()
        ours = sum(isinstance(decoder.decode(f), RawEpoch) for f in iter_frames(data))
        assert _epochs_in_rinex(d / f"{name}.obs") == ours == 1501


def test_convbin_nav_equals_simulated_ephemerides(run: tuple[SimResult, Path]) -> None:
    result, d = run
    nav = _read_nav(d / "rover.nav")
    assert len(nav) >= 8
    for rec in nav:
        sims = result.constellation.ephemerides[rec["sv"]]
        o = rec["o"]
        eph = next(e for e in sims if e.iode == int(o[0]))
        expected = [
            eph.iode, eph.crs_m, eph.delta_n_rad_s, eph.m0_rad, eph.cuc_rad, eph.e, eph.cus_rad,
            eph.sqrt_a_sqrt_m, eph.toe_s, eph.cic_rad, eph.omega0_rad, eph.cis_rad, eph.i0_rad,
            eph.crc_m, eph.omega_rad, eph.omega_dot_rad_s, eph.idot_rad_s,
        ]
        assert np.allclose(o[:17], expected, rtol=1e-11, atol=1e-20), rec["sv"]
        assert np.allclose([rec["af0"], rec["af1"], rec["af2"]],
                           [eph.af0_s, eph.af1_s_s, eph.af2_s_s2], rtol=1e-11, atol=1e-25)
        assert o[18] == eph.week and o[22] == pytest.approx(eph.tgd_s, rel=1e-11)
        assert o[23] == eph.iodc and o[21] == eph.health
        assert GPS_PI == 3.1415926535898


CONF_COMMON = """\
pos1-frequency     =l1
pos1-elmask        =15
pos1-ionoopt       =brdc
pos1-tropopt       =saas
pos1-navsys        =1
out-solformat      =xyz
out-timesys        =gpst
out-timeform       =tow
"""


def test_single_point_within_10_m(run: tuple[SimResult, Path]) -> None:
    result, d = run
    (d / "spp.conf").write_text("pos1-posmode       =single\n" + CONF_COMMON)
    subprocess.run(["rnx2rtkp", "-k", "spp.conf", "-o", "spp.pos", "rover.obs", "rover.nav"],
                   cwd=d, check=True, capture_output=True, timeout=60)
    sol = _pos(d / "spp.pos")
    assert len(sol) == 1501
    err = _errors(result, sol)
    assert err.max() < 10.0, err.max()


def test_ppk_fixed_and_within_5_cm(run: tuple[SimResult, Path]) -> None:
    result, d = run
    base = result.truth["base"]["ecef_m"]
    (d / "ppk.conf").write_text(
        "pos1-posmode       =kinematic\npos1-soltype       =forward\n"
        "pos1-dynamics      =off\npos2-armode        =fix-and-hold\n"
        "pos2-arthres       =3\npos2-arelmask      =15\nant2-postype       =xyz\n"
        f"ant2-pos1          ={base[0]:.4f}\nant2-pos2          ={base[1]:.4f}\n"
        f"ant2-pos3          ={base[2]:.4f}\n" + CONF_COMMON
    )
    subprocess.run(
        ["rnx2rtkp", "-k", "ppk.conf", "-o", "ppk.pos", "rover.obs", "base.obs", "rover.nav"],
        cwd=d, check=True, capture_output=True, timeout=60,
    )
    sol = _pos(d / "ppk.pos")
    fixed = sol[:, 5] == 1
    assert fixed.mean() > 0.9, fixed.mean()
    err = _errors(result, sol[fixed])
    assert np.median(err) < 0.02 and np.percentile(err, 95) < 0.05, (
        np.median(err), np.percentile(err, 95))
