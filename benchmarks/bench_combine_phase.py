"""Do the forward and backward fixes of the real 2018-10-09 flight fit the carrier phase?

Run: python benchmarks/bench_combine_phase.py   (needs ../shared/data)

Solves the jdesbonnet 2018-10-09 M8P recordings as ``groundstation solve`` does (our RINEX, the
dynamics pass, forward and backward runs merged by ``engine/combine.py``), then checks each epoch
that both runs fixed with a test independent of RTKLIB: for a candidate rover position, the RMS
of the fractional part of the GPS L1 double-differenced phase residuals (0 for the true position
but for noise and multipath; a few centimetres of error show as tenths of a cycle). Broadcast
orbits and clocks, Saastamoinen at both ends, the base epoch nearest in time (as demo5 picks it),
elevation >= 15 deg, half-cycle-flagged phases left out, the highest satellite as reference.

Prints three tables: by forward-backward difference (forward, backward, reference positions),
by the chi-square of that difference (the merge's test), and by the distance to the base epoch.
"""

from __future__ import annotations

import gzip
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from groundstation.geodesy import ecef_to_llh
from groundstation.gnss.atmosphere import saastamoinen_delay_m
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.orbit import C_M_S, L1_WAVELENGTH_M, rotate_earth, sat_state, toe_gps_ns
from groundstation.offline import rinex
from groundstation.offline.rinex.observations import ObsSet
from groundstation.solve import engine
from groundstation.solve.engine import combine as cb
from groundstation.solve.posfile import read_pos

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
UBX = SHARED / "real" / "jdesbonnet__GNSS_RTK_data" / "20181009"
REF = SHARED / "reference" / "rnx2rtkp_pos" / "jd_20181009_kin_vs_M8Pbase_svin.pos.gz"
BASE = np.array((3774696.5547, -596647.9083, 5089485.6511))
ELMASK_DEG = 15.0
Obs = dict[int, dict[int, tuple[float, float]]]  # epoch ns -> sv -> (pseudorange, phase)


def _recording(name: str, work: Path) -> tuple[Obs, list[BroadcastEphemeris]]:
    src = work / f"{name}.ubx"
    src.write_bytes(gzip.decompress((UBX / f"{name}.ubx.gz").read_bytes()))
    got: dict[str, object] = {}

    def hook(obs: ObsSet, ephs: Sequence[BroadcastEphemeris],
             approx: tuple[float, float, float]) -> ObsSet:
        got["obs"], got["ephs"] = obs, list(ephs)
        return obs

    rinex.convert(src, work / name, rinex.RinexOptions(version="3.04"), None, hook)
    o = got["obs"]
    assert isinstance(o, ObsSet)
    m = (o.sys == "G") & (o.code == "1C") & (o.cp_cyc != 0) & (o.pr_m != 0) & ((o.lli & 2) == 0)
    out: Obs = {}
    for e, sv, pr, cp in zip(o.epoch[m].tolist(), o.prn[m].tolist(), o.pr_m[m].tolist(),
                             o.cp_cyc[m].tolist(), strict=True):
        out.setdefault(int(o.t_gps_ns[e]), {})[int(sv)] = (pr, cp)
    ephs = got["ephs"]
    assert isinstance(ephs, list)
    return out, ephs


class PhaseFit:
    """Fractional double-difference residuals of candidate rover positions."""

    def __init__(self, rover: Obs, base: Obs, ephs: Sequence[BroadcastEphemeris]) -> None:
        self.rover, self.base = rover, base
        self.rover_t = np.array(sorted(rover), dtype=np.int64)
        self.base_t = np.array(sorted(base), dtype=np.int64)
        self.ephs: dict[int, list[BroadcastEphemeris]] = {}
        for e in ephs:
            self.ephs.setdefault(e.sv, []).append(e)
        lat, _, h = ecef_to_llh(*(float(v) for v in BASE))
        self.lat, self.h = lat, h

    def _sat(self, sv: int, t_rx: int, pr: float) -> tuple[npt.NDArray[np.float64], float]:
        t_tx = t_rx - int(pr / C_M_S * 1e9)
        eph = min(self.ephs[sv], key=lambda x: abs(toe_gps_ns(x) - t_tx))
        st = sat_state(eph, (t_tx - toe_gps_ns(eph)) / 1e9)
        return np.asarray(st.pos_m), C_M_S * float(st.clock_s)

    def _one_way(self, sat: npt.NDArray[np.float64], clk: float, x: npt.NDArray[np.float64],
                 up: npt.NDArray[np.float64]) -> tuple[float, float]:
        """(range - satellite clock + troposphere in metres, sine of the elevation)."""
        d = rotate_earth(sat, np.linalg.norm(sat - x) / C_M_S) - x
        rho = float(np.linalg.norm(d))
        sin_el = float(d @ up) / rho
        el = np.degrees(np.arcsin(max(sin_el, 0.02)))
        return rho - clk + float(saastamoinen_delay_m(self.lat, self.h, el)), sin_el

    def nearest_epoch(self, t_ns: int) -> int | None:
        k = int(np.argmin(np.abs(self.rover_t - t_ns)))
        return int(self.rover_t[k]) if abs(int(self.rover_t[k]) - t_ns) < 20_000_000 else None

    def base_age_s(self, t_ns: int) -> float:
        return float(np.min(np.abs(self.base_t - t_ns))) / 1e9

    def rms(self, t_ns: int, x: npt.NDArray[np.float64]) -> float:
        """RMS fractional DD residual (cycles) of rover position ``x`` at rover epoch ``t_ns``."""
        ro = self.rover[t_ns]
        tb = int(self.base_t[np.argmin(np.abs(self.base_t - t_ns))])
        bo = self.base[tb]
        up = x / np.linalg.norm(x)
        sd, sin_el = [], []
        for sv in sorted(set(ro) & set(bo) & set(self.ephs)):
            rng_r, s_el = self._one_way(*self._sat(sv, t_ns, ro[sv][0]), x, up)
            if s_el < np.sin(np.radians(ELMASK_DEG)):
                continue
            rng_b, _ = self._one_way(*self._sat(sv, tb, bo[sv][0]), BASE, up)
            sd.append((ro[sv][1] - rng_r / L1_WAVELENGTH_M) - (bo[sv][1] - rng_b / L1_WAVELENGTH_M))
            sin_el.append(s_el)
        if len(sd) < 5:
            return float("nan")
        a = np.asarray(sd)
        k = int(np.argmax(sin_el))
        dd = np.delete(a - a[k], k)
        return float(np.sqrt(np.mean((dd - np.round(dd)) ** 2)))


def main() -> None:
    if not UBX.is_dir():
        print(f"{UBX} is absent: nothing to measure")
        return
    with tempfile.TemporaryDirectory(prefix="bench-combine-") as tmp:
        work = Path(tmp)
        rover, ephs = _recording("rover-20181009-1221", work)
        base, base_ephs = _recording("base-20181009-1220", work)
        fit = PhaseFit(rover, base, ephs + base_ephs)
        run = engine.run_engine("demo5", UBX / "rover-20181009-1221.ubx.gz",
                                UBX / "base-20181009-1220.ubx.gz", tuple(BASE.tolist()),
                                work / "solve")
        _, fwd = cb.parse_solutions((work / "solve" / "forward" / "rover.pos").read_text())
        _, bwd = cb.parse_solutions((work / "solve" / "backward" / "rover.pos").read_text())
        ref = read_pos(REF)
    ref_at = {int(round(t / 1e6)): k for k, t in enumerate(ref.t_gps_ns.tolist())}
    rows = []
    for i, t_s in enumerate(fwd.t_s.tolist()):
        j = int(np.argmin(np.abs(bwd.t_s - t_s)))
        if fwd.q[i] != 1 or bwd.q[j] != 1 or abs(bwd.t_s[j] - t_s) > cb.DTTOL_S:
            continue
        t_ns = int(round(t_s * 1e9))
        e = fit.nearest_epoch(t_ns)
        if e is None:
            continue
        d = fwd.xyz[i] - bwd.xyz[j]
        cov = fwd.cov[i] + bwd.cov[j]
        chi2 = float(d @ np.linalg.solve(cov, d))
        k = ref_at.get(int(round(t_ns / 1e6)))
        r = fit.rms(e, ref.ecef_m[k]) if k is not None and ref.quality[k] == 1 else np.nan
        rows.append((float(np.linalg.norm(d)), chi2, fit.rms(e, fwd.xyz[i]), fit.rms(e, bwd.xyz[j]),
                     r, fit.base_age_s(e)))
    a = np.asarray(rows)
    a = a[np.isfinite(a[:, 2]) & np.isfinite(a[:, 3])]
    print(f"{run.combination}\n")
    print("| forward-backward difference | epochs | forward | backward | reference | forward "
          "fits better |\n|---|---:|---:|---:|---:|---:|")
    for lo, hi in ((0, 0.01), (0.01, 0.02), (0.02, 0.03), (0.03, 0.05), (0.05, 0.1), (0.1, 1e9)):
        m = (a[:, 0] >= lo) & (a[:, 0] < hi)
        if m.any():
            label = f"> {lo * 100:g}" if hi > 1e6 else f"{lo * 100:g}-{hi * 100:g}"
            print(f"| {label} cm | {int(m.sum())} | {np.median(a[m, 2]):.3f} | "
                  f"{np.median(a[m, 3]):.3f} | {np.nanmedian(a[m, 4]):.3f} | "
                  f"{int(np.sum(a[m, 2] < a[m, 3]))} |")
    print("\n| chi-square | epochs | forward | backward |\n|---|---:|---:|---:|")
    for lo, hi in ((0, 4), (4, cb.CHI2_3DOF_1PCT), (cb.CHI2_3DOF_1PCT, 19.7), (19.7, 1e12)):
        m = (a[:, 1] >= lo) & (a[:, 1] < hi)
        if m.any():
            label = f"> {lo:g}" if hi > 1e6 else f"{lo:g}-{hi:g}"
            print(f"| {label} | {int(m.sum())} | {np.median(a[m, 2]):.3f} | "
                  f"{np.median(a[m, 3]):.3f} |")
    print("\n| distance to the base epoch | epochs | forward |\n|---|---:|---:|")
    for lo, hi in ((0, 0.5), (0.5, 2), (2, 4), (4, 8), (8, 1e9)):
        m = (a[:, 5] >= lo) & (a[:, 5] < hi)
        if m.any():
            label = f"> {lo:g}" if hi > 1e6 else f"{lo:g}-{hi:g}"
            print(f"| {label} s | {int(m.sum())} | {np.median(a[m, 2]):.3f} |")


if __name__ == "__main__":
    main()
