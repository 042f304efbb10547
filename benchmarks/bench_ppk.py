"""PPK engines x datasets: fixed share, wrong fixes, camera centres, agreement, wall time.

Run: python benchmarks/bench_ppk.py [--seed-s 1200] [--seeds 1,2,3] [--severities 0.5,1,2]
         [--only KEY] [--ours-opt KEY=VALUE ...]
     python benchmarks/bench_ppk.py --hour [--repeat 2]
     python benchmarks/bench_ppk.py --sweep [--sweep-seeds 501-530] [--sweep-severities
         0.5,1,1.5,2] [--sweep-faults SPEC] [--real-seeds 1-5] [--interp METHOD]
         [--out FILE.jsonl]
     python benchmarks/bench_ppk.py --why-real
     python benchmarks/bench_ppk.py --why-gaps [--real-seeds 1-5]

``--sweep`` (issue 22): the whole ``solve`` (engine, integrity stage, marks) on many flights,
judged at the camera positions: the seed profile's default 50-min flight at each severity for
every seed of ``--sweep-seeds``, against the simulator's truth; and the real 2018-10-09 and
2018-10-04 run-2 flights rewritten as a LEA-6T (``groundstation.sim.rewrite``), without faults
and through the seed link with each of ``--real-seeds``, against the solve of the untouched
recording (its fixed camera positions). Per run: camera positions fixed (share), wrong fixes
(fixed and more than 10 cm off), positions off by more than 5 cm and more than 3 sigma on an
axis, the worst error of a fixed one, wall time; then minimum, median and maximum per group.
``--sweep-faults`` gives the simulated flights another link than the seed profile's (a fault
file, e.g. ``benchmarks/faults/long-outages.toml``): fault patterns the rules were not made on.

Engines (rows per dataset):
- ``b34``: Debian's rnx2rtkp 2.4.3 b34 with the project's former options (GPS L1, combined,
  fix-and-hold; ``options.B34_L1_KINEMATIC``), positions at marks by straight line;
- ``demo5``: demo5 (pyrtklib5, worker process) with our u-blox L1 5 Hz default, no phase
  conditioning, straight line at marks;
- ``ours``: phase conditioning + demo5 (same options) + the smoother at marks.

Datasets: the simulator's default (demo) flight; the seed profile (the field report's failed
flight) at each severity and seed; the three jdesbonnet M8P kinematic runs (convbin's RINEX)
against rnx2rtkp EX 2.5.1's solutions; MatRTKLIB's static Septentrio pair processed as
kinematic, L1 only, against its true position.

Columns: epochs; fixed share (seed: of the in-flight epochs); wrong fixes (fixed epochs more than
10 cm from the truth, where there is truth); camera centres (the antenna at each exposure, no
lever arm: the lever arm is exact in the simulation) RMS horizontal / vertical against the
truth's; agreement with the demo5 reference where both are fixed (p95 3D); wall time of the
whole ``run_engine`` call (RINEX conversion, conditioning, engine).

``--why-real`` (issue 22, item 5): where the real flights' fixes go as a LEA-6T (camera
positions per grade, untouched with and without GLONASS and rewritten), and what the
one-direction fixes the grading holds back would have given (:func:`why_real`).

``--why-gaps`` (issue 22): what the real flights' radio gaps cost, per fault seed: the
conditioning's bridges across them judged by the same flight without faults, and the whole-arc
solution on the flight without faults, on it at the link's epochs only, and through the link
(:func:`why_gaps`).

``--hour``: a 1-hour seed flight (severity 1): our conditioning + the dynamics pass + demo5
combined (forward and backward) from the UBX recordings against b34's combined mode on the RINEX
files our writer made of the same recordings, and ours without the dynamics pass (the constant
default noise); best of ``--repeat``.
"""

from __future__ import annotations

import argparse
import gzip
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

# The tree this script is in, not whichever groundstation the venv has installed: run from a
# second checkout (a worktree of another commit) it measured the installed one (session 12's
# first sweeps compared main with itself).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from groundstation.geodesy import ecef_to_llh, enu_rotation, llh_to_ecef
from groundstation.offline import rinex
from groundstation.rules.marks import build_marks
from groundstation.sim.profiles import sim_config
from groundstation.sim.stream import simulate
from groundstation.solve import engine
from groundstation.solve import interpolate as mi
from groundstation.solve.engine import options as eo
from groundstation.solve.engine.dynamics import nearest_index
from groundstation.solve.flight import read_flight
from groundstation.solve.integrity.grade import GRADE_NAMES
from groundstation.solve.posfile import read_pos
from groundstation.solve.trajectory import Q_FIX, Trajectory

FloatArray = npt.NDArray[np.float64]
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
WRONG_M = 0.10
JD_BASE_1009 = (3774696.5547, -596647.9083, 5089485.6511)
JD_BASE_1004 = llh_to_ecef(53.280449957, -9.057836328, 66.8)
JD_RUNS = {
    "jd 2018-10-04 run 1": ("rover-20181004-1237", "base-20181004-1236", JD_BASE_1004,
                            "jd_20181004_run1_kin_vs_M8Pbase"),
    "jd 2018-10-04 run 2": ("rover-20181004-1532", "base-20181004-1452", JD_BASE_1004,
                            "jd_20181004_run2_kin_vs_M8Pbase"),
    "jd 2018-10-09": ("rover-20181009-1221", "base-20181009-1220", JD_BASE_1009,
                      "jd_20181009_kin_vs_M8Pbase_svin"),
}
ENGINES = (  # label, engine, conditioning, interpolation at marks
    ("b34", "rnx2rtkp", False, "linear"),
    ("demo5", "demo5", False, "linear"),
    ("ours", "demo5", True, "smoother"),
)


@dataclass
class Dataset:
    """Inputs of one row group and what to compare with."""

    name: str
    rover: Path
    base: Path
    base_ecef_m: tuple[float, float, float]
    truth_t_ns: npt.NDArray[np.int64] | None = None  # truth trajectory
    truth_xyz: FloatArray | None = None
    static_truth: tuple[float, float, float] | None = None
    flight: tuple[int, int] | None = None  # in-flight span (GPS ns)
    exposures: list[dict[str, Any]] | None = None
    reference: Path | None = None
    truth: dict[str, Any] | None = None


def sim_dataset(work: Path, profile: str, duration_s: float, seed: int,
                severity: float) -> Dataset:
    cfg = sim_config(profile, duration_s=duration_s, seed=seed,
                     severity=severity if profile == "seed" else 1.0)
    sim = simulate(cfg)
    work.mkdir(parents=True, exist_ok=True)
    (work / "rover.ubx").write_bytes(sim.rover_bytes)
    (work / "base.ubx").write_bytes(sim.base_bytes)
    tr = sim.truth["trajectory"]
    ph = sim.truth.get("phases") or {}
    name = (f"seed sev {severity:g} #{seed}" if profile == "seed" else "demo default")
    return Dataset(
        name, work / "rover.ubx", work / "base.ubx",
        tuple(float(v) for v in sim.truth["base"]["ecef_m"]),  # type: ignore[arg-type]
        truth_t_ns=np.asarray(tr["t_gps_ns"], dtype=np.int64),
        truth_xyz=np.stack([np.asarray(tr[c], dtype=np.float64) for c in ("x_m", "y_m", "z_m")],
                           axis=1),
        flight=((int(ph["takeoff_gps_ns"]), int(ph["landing_gps_ns"]))
                if "takeoff_gps_ns" in ph else None),
        exposures=[e for e in sim.truth["exposures"] if not e.get("missed")],
        truth=sim.truth,
    )


def _unzip(src: Path, dst: Path) -> Path:
    out = dst / src.name.removesuffix(".gz")
    out.write_bytes(gzip.decompress(src.read_bytes()))
    return out


def jd_dataset(work: Path, name: str) -> Dataset | None:
    rover, base, base_xyz, ref = JD_RUNS[name]
    src = SHARED / "reference" / "convbin_rinex"
    if not src.is_dir():
        return None
    work.mkdir(parents=True, exist_ok=True)
    files = [_unzip(src / f"{f}.{e}.gz", work) for f in (rover, base) for e in ("obs", "nav")]
    return Dataset(name, files[0], files[2], base_xyz,
                   reference=SHARED / "reference" / "rnx2rtkp_pos" / f"{ref}.pos.gz")


def matrtklib_dataset(work: Path) -> Dataset | None:
    src = SHARED / "real" / "taroz__MatRTKLIB" / "examples" / "data" / "static"
    if not src.is_dir():
        return None
    work.mkdir(parents=True, exist_ok=True)
    for f in ("rover.obs", "base.obs", "base.nav"):
        shutil.copy(src / f, work / f)
    # The rover's nav is the base's (same site, same time): the engines look for STEM*.nav.
    shutil.copy(src / "base.nav", work / "rover.nav")

    def llh(p: Path) -> tuple[float, float, float]:
        lat, lon, h = (float(v) for v in p.read_text().split()[:3])
        return llh_to_ecef(lat, lon, h)

    return Dataset("MatRTKLIB static as kinematic", work / "rover.obs", work / "base.obs",
                   llh(src / "base_position.txt"), static_truth=llh(src / "rover_position.txt"))


def _enu(d: FloatArray, at: FloatArray) -> FloatArray:
    lat, lon, _ = ecef_to_llh(*(float(v) for v in at))
    out: FloatArray = d @ np.asarray(enu_rotation(lat, lon)).T
    return out


def _truth_at(ds: Dataset, t_ns: npt.NDArray[np.int64]) -> FloatArray | None:
    if ds.static_truth is not None:
        return np.tile(np.asarray(ds.static_truth), (t_ns.size, 1))
    if ds.truth_t_ns is None or ds.truth_xyz is None:
        return None
    t0 = ds.truth_t_ns[0]
    q = (t_ns - t0) / 1e9
    tt = (ds.truth_t_ns - t0) / 1e9
    return np.stack([np.interp(q, tt, ds.truth_xyz[:, k]) for k in range(3)], axis=1)


def _epochs_ms(t: Trajectory) -> npt.NDArray[np.int64]:
    return np.asarray(np.round(t.t_gps_ns / 1e6), dtype=np.int64)


def evaluate(ds: Dataset, label: str, engine_name: str, cond: bool, interp: str,
             work: Path, overrides: dict[str, str]) -> dict[str, str]:
    t = time.perf_counter()
    run = engine.run_engine(engine_name, ds.rover, ds.base, ds.base_ecef_m, work,
                            overrides=overrides, condition=cond)
    wall = time.perf_counter() - t
    traj = read_pos(run.pos_path)
    fix = traj.quality == Q_FIX
    row = {"dataset": ds.name, "engine": label, "epochs": str(len(traj)),
           "wall": f"{wall:.1f} s", "fixed": "-", "wrong": "-", "camera": "-", "agree": "-"}
    span = np.ones(len(traj), dtype=bool)
    if ds.flight is not None:
        span = (traj.t_gps_ns >= ds.flight[0]) & (traj.t_gps_ns < ds.flight[1])
    row["fixed"] = f"{np.mean(fix[span]):.1%}" if span.any() else "-"
    truth = _truth_at(ds, traj.t_gps_ns)
    if truth is not None:
        err = np.linalg.norm(traj.ecef_m - truth, axis=1)
        wrong = fix & (err > WRONG_M)
        row["wrong"] = str(int(np.sum(wrong)))
    if ds.exposures:
        marks = build_marks(read_flight(ds.rover).timemarks)
        times = [mi.mark_time_ns(m.falling_t_gps_ns, m.rising_t_gps_ns, "falling") for m in marks]
        mp = mi.interpolate(traj, times, interp)
        fall = np.array([e["falling_t_gps_ns"] for e in ds.exposures], dtype=np.int64)
        truth_xyz = np.array([e["ecef_m"] for e in ds.exposures], dtype=np.float64)
        d_list = []
        for k, tm in enumerate(times):
            if tm is None or not np.isfinite(mp.ecef_m[k, 0]):
                continue
            j = int(np.argmin(np.abs(fall - tm)))
            if abs(int(fall[j]) - tm) < 1_000:
                d_list.append(mp.ecef_m[k] - truth_xyz[j])
        if d_list:
            d = _enu(np.array(d_list), truth_xyz[0])
            h = float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)))
            v = float(np.sqrt(np.mean(d[:, 2] ** 2)))
            row["camera"] = f"{h * 100:.1f} / {v * 100:.1f} cm ({len(d_list)})"
    if ds.reference is not None and ds.reference.exists():
        ref = read_pos(ds.reference)
        _, ii, jj = np.intersect1d(_epochs_ms(traj), _epochs_ms(ref), return_indices=True)
        both = (traj.quality[ii] == Q_FIX) & (ref.quality[jj] == Q_FIX)
        if both.any():
            dd = np.linalg.norm(traj.ecef_m[ii][both] - ref.ecef_m[jj][both], axis=1)
            row["agree"] = f"{np.percentile(dd, 95) * 100:.1f} cm ({int(both.sum())})"
        row["fixed"] += f" (ref {np.mean(ref.quality == Q_FIX):.1%})"
    if run.conditioning and run.conditioning.get("applied"):
        tot = run.conditioning["totals"]
        assert isinstance(tot, dict)
        row["engine"] += (f" [hidden {tot['hidden_found']}, repaired {tot['repaired']}, "
                          f"flagged {tot['flagged']}]")
    used = run.dynamics.get("used") if run.dynamics else None
    if run.dynamics and isinstance(used, dict):
        meas = run.dynamics.get("measured")
        row["engine"] += (" {q " + " / ".join(str(v) for v in used.values())
                          + (f" from A {meas['accel_h_m_s2']:.2f} / {meas['accel_v_m_s2']:.3f}"
                             if isinstance(meas, dict) else "") + "}")
    return row


def _overrides(label: str, ds: Dataset, ours: dict[str, str]) -> dict[str, str]:
    if label == "b34":
        return {}
    out = dict(ours) if label == "ours" else {}
    if ds.name.startswith("MatRTKLIB"):
        out["pos1-navsys"] = "1"  # GPS, as b34 (the file's Galileo has no nav here)
    return out


def table(args: argparse.Namespace) -> None:
    engines = [e for e in ENGINES if e[1] != "rnx2rtkp" or shutil.which("rnx2rtkp")]
    ours_opts = eo.parse_assignments(args.ours_opt, "--ours-opt")
    with tempfile.TemporaryDirectory(prefix="bench-ppk-") as tmp:
        work = Path(tmp)
        makers: list[tuple[str, Any]] = [
            ("demo", lambda w: sim_dataset(w, "default", 300.0, 1, 1.0))]
        for sev in [float(s) for s in args.severities.split(",")]:
            for seed in [int(s) for s in args.seeds.split(",")]:
                makers.append((f"seed{sev}_{seed}", lambda w, sev=sev, seed=seed: sim_dataset(
                    w, "seed", args.seed_s, seed, sev)))
        for name in JD_RUNS:
            makers.append((name.replace(" ", "_"), lambda w, name=name: jd_dataset(w, name)))
        makers.append(("matrtklib", matrtklib_dataset))
        print("| dataset | engine | epochs | fixed | wrong fixes | camera RMS h / v (n) "
              "| agreement p95 (n) | wall |")
        print("|---|---|---:|---:|---:|---:|---:|---:|", flush=True)
        for key, make in makers:
            if args.only and args.only not in key:
                continue
            ds = make(work / key)
            if ds is None:
                print(f"| {key} | (data absent) | | | | | | |")
                continue
            for label, name, cond, interp in engines:
                try:
                    r = evaluate(ds, label, name, cond, interp, work / key / label,
                                 _overrides(label, ds, ours_opts))
                except Exception as err:  # one failing engine must not end the table
                    print(f"| {ds.name} | {label} | failed: {err} | | | | | |", flush=True)
                    continue
                print(f"| {r['dataset']} | {r['engine']} | {r['epochs']} | {r['fixed']} | "
                      f"{r['wrong']} | {r['camera']} | {r['agree']} | {r['wall']} |", flush=True)
            shutil.rmtree(work / key, ignore_errors=True)


def hour(args: argparse.Namespace) -> None:
    with tempfile.TemporaryDirectory(prefix="bench-ppk-hour-") as tmp:
        work = Path(tmp)
        ds = sim_dataset(work / "sim", "seed", 3600.0, 1, 1.0)
        obs = []
        for p in (ds.rover, ds.base):
            res = rinex.convert(p, work / "rinex" / p.stem, rinex.RinexOptions(version="3.04"))
            obs.append(res.obs_path)
        b34_opts = {k: v for k, v in eo.B34_L1_KINEMATIC.items() if k not in eo.OUTPUT_OPTIONS}
        best_b34 = best_ours = best_const = float("inf")
        for k in range(args.repeat):
            t = time.perf_counter()
            engine.run_engine("rnx2rtkp", obs[0], obs[1], ds.base_ecef_m, work / f"b{k}",
                              overrides=b34_opts, condition=False)
            best_b34 = min(best_b34, time.perf_counter() - t)
            t = time.perf_counter()
            run = engine.run_engine("demo5", ds.rover, ds.base, ds.base_ecef_m, work / f"o{k}",
                                    condition=True)
            best_ours = min(best_ours, time.perf_counter() - t)
            t = time.perf_counter()
            engine.run_engine("demo5", ds.rover, ds.base, ds.base_ecef_m, work / f"c{k}",
                              condition=True, dynamics=False)
            best_const = min(best_const, time.perf_counter() - t)
            print(f"run {k}: b34 {best_b34:.1f} s, ours {best_ours:.1f} s, ours without the "
                  f"dynamics pass {best_const:.1f} s", flush=True)
        traj = read_pos(run.pos_path)
        print(f"epochs {len(traj)}; b34 combined (RINEX in) {best_b34:.1f} s; ours (UBX in: "
              f"RINEX + conditioning + dynamics pass + demo5 combined) {best_ours:.1f} s; ratio "
              f"{best_ours / best_b34:.2f}; without the dynamics pass {best_const:.1f} s "
              f"({best_const / best_b34:.2f}); dynamics {run.dynamics}")


# -- the sweep (issue 22) ----------------------------------------------------------------------

JD_SWEEP = {
    "2018-10-09": ("20181009", "rover-20181009-1221", "base-20181009-1220", JD_BASE_1009),
    "2018-10-04 run 2": ("20181004", "rover-20181004-1532", "base-20181004-1452",
                         JD_BASE_1004),
}


def _span(text: str) -> list[int]:
    """``501-530`` or ``1,2,7`` -> the integers."""
    if "-" in text and "," not in text:
        a, b = (int(v) for v in text.split("-"))
        return list(range(a, b + 1))
    return [int(v) for v in text.split(",") if v]


def _judge(res: Any, ref_xyz: FloatArray, ref_fixed: npt.NDArray[np.bool_],
           t0: float) -> dict[str, Any]:
    """Camera positions of a ``SolveResult`` against reference positions per mark."""
    mp = res.mark_positions
    pos = np.isfinite(mp.ecef_m[:, 0]) & np.all(np.isfinite(ref_xyz), axis=1) & ref_fixed
    lat, lon, _ = ecef_to_llh(*(float(v) for v in ref_xyz[pos][0])) if pos.any() else (0, 0, 0)
    d = _enu(mp.ecef_m - ref_xyz, ref_xyz[pos][0]) if pos.any() else np.zeros((0, 3))
    del lat, lon
    err = np.linalg.norm(d, axis=1)
    fixed = mp.quality == Q_FIX
    beyond = np.any(np.abs(d) > 3 * mp.sd_enu_m, axis=1) & (err > 0.05)
    n = int(pos.sum())
    from groundstation.solve.positions import engine_info

    integ = (engine_info(res.trajectory) or {}).get("integrity") or {}
    fac = integ.get("float_sigma_factor") or {}
    arcs = integ.get("arcs") or {}
    return {
        "float_factor": [fac.get("horizontal"), fac.get("vertical"), fac.get("from")],
        "phase_factor": arcs.get("phase_variance_factor"),
        "grades": {g: int(np.sum(mp.grade[pos] == c)) for c, g in GRADE_NAMES.items()
                   if np.any(mp.grade[pos] == c)},
        "marks": n,
        "fixed": int((fixed & pos).sum()),
        "fixed_share": round(float((fixed & pos).sum()) / max(n, 1), 4),
        "wrong": int((fixed & pos & (err > WRONG_M)).sum()),
        "worst_fixed_m": round(float(np.max(np.where(fixed & pos, err, 0.0), initial=0.0)), 3),
        "beyond": int((beyond & pos).sum()),
        "beyond_share": round(float((beyond & pos).sum()) / max(n, 1), 4),
        "wall_s": round(time.perf_counter() - t0, 1),
    }


INTERP: list[str] = []
"""``--interp``: the interpolation the sweep's solves use (default: ``solve``'s)."""


def _solve(rover: Path, base: Path, base_xyz: tuple[float, float, float], out: Path,
           rtk_options: tuple[tuple[str, str], ...] = ()) -> Any:
    from groundstation.solve.pipeline import solve
    from groundstation.solve.settings import SolveSettings

    more = {"interp": INTERP[0]} if INTERP else {}
    return solve(SolveSettings(flight=rover, out_dir=out, base=base, base_ecef_m=base_xyz,
                               rtk_options=rtk_options, **more))  # type: ignore[arg-type]


def sweep_sim(work: Path, seed: int, severity: float, faults: str = "") -> dict[str, Any]:
    """One seed-profile flight (the profile's default span), solved and judged at the marks
    against the truth's exposures. ``faults``: the link's fault pattern (``FaultConfig.load``'s
    spec; empty: the profile's own)."""
    from groundstation.sim.faults import FaultConfig

    link = FaultConfig.load(faults) if faults else None
    cfg = sim_config("seed", seed=seed, severity=severity, faults=link)
    sim = simulate(cfg)
    work.mkdir(parents=True, exist_ok=True)
    (work / "rover.ubx").write_bytes(sim.rover_bytes)
    (work / "base.ubx").write_bytes(sim.base_bytes)
    base = tuple(float(v) for v in sim.truth["base"]["ecef_m"])
    t0 = time.perf_counter()
    label = f" link {Path(faults).stem}" if faults else ""
    row: dict[str, Any] = {"flight": f"sim severity {severity:g}{label}", "seed": seed}
    try:
        res = _solve(work / "rover.ubx", work / "base.ubx", base, work / "out")  # type: ignore[arg-type]
    except Exception as err:  # recorded: the sweep must say every failure
        row["error"] = f"{type(err).__name__}: {err}"
        return row
    ex = [e for e in sim.truth["exposures"] if not e.get("missed")]
    fall = np.array([e["falling_t_gps_ns"] for e in ex], dtype=np.int64)
    txyz = np.array([e["ecef_m"] for e in ex], dtype=np.float64)
    t = res.mark_positions.t_gps_ns
    j = np.clip(np.searchsorted(fall, t), 0, fall.size - 1)
    j0 = np.maximum(j - 1, 0)
    j = np.where(np.abs(fall[j0] - t) < np.abs(fall[j] - t), j0, j)
    hit = np.abs(fall[j] - t) < 1_000
    ref = np.where(hit[:, None], txyz[j], np.nan)
    row.update(_judge(res, ref, hit, t0))
    return row


def _reference(work: Path, day: str, rover: str, base: str,
               base_xyz: tuple[float, float, float], gps_only: bool = False,
               ) -> tuple[dict[int, Any], Path, Path]:
    """The untouched recording's fixed solution (the engine's own combined one, as the issue
    counts it: 496 fixed camera positions on 2018-10-09): the antenna per mark number, at the
    marks where its two bracketing epochs are fixed. ``gps_only``: the same recording solved
    with GPS alone (``pos1-navsys=1``), what a LEA-6T sees of the same sky (the u-blox 8
    recordings track GLONASS too): the share a GPS L1 receiver could reach at best."""
    src = SHARED / "real" / "jdesbonnet__GNSS_RTK_data" / day
    out = work / ("reference-gps" if gps_only else "reference")
    res = _solve(src / f"{rover}.ubx.gz", src / f"{base}.ubx.gz", base_xyz, out,
                 (("pos1-navsys", "1"),) if gps_only else ())
    engine_traj = read_pos(out / "rtklib" / "rover.pos")
    times = [mi.mark_time_ns(m.falling_t_gps_ns, m.rising_t_gps_ns, "falling")
             for m in res.marks]
    mp = mi.interpolate(engine_traj, times, "linear")
    ref = {}
    for m, x, q in zip(res.marks, mp.ecef_m, mp.quality, strict=True):
        if q == Q_FIX:
            ref[m.number] = x
    return ref, src / f"{rover}.ubx.gz", src / f"{base}.ubx.gz"


def sweep_real(work: Path, name: str, fault_seeds: list[int]) -> list[dict[str, Any]]:
    """A real flight as a LEA-6T: without faults and with the seed link per seed, judged at
    the marks against the untouched recording's fixed positions."""
    from groundstation.sim.faults import FaultConfig
    from groundstation.sim.rewrite import RewriteConfig, rewrite

    day, rover, base, base_xyz = JD_SWEEP[name]
    if not (SHARED / "real").is_dir():
        return [{"flight": name, "error": "../shared/data absent"}]
    work.mkdir(parents=True, exist_ok=True)
    ref, rover_src, base_src = _reference(work, day, rover, base, base_xyz)
    ref_gps, _, _ = _reference(work, day, rover, base, base_xyz, gps_only=True)
    base_lea = work / "base.ubx"
    base_lea.write_bytes(rewrite(base_src, RewriteConfig()).data)
    rows = []
    for seed in [0, *fault_seeds]:
        faults = FaultConfig.none() if seed == 0 else FaultConfig.seed()
        rv = work / f"rover-{seed}.ubx"
        rv.write_bytes(rewrite(rover_src, RewriteConfig(faults=faults, seed=max(seed, 1))).data)
        t0 = time.perf_counter()
        row: dict[str, Any] = {"flight": f"{name} as LEA-6T", "seed": seed,
                               "faults": "seed link" if seed else "none",
                               "reference_fixed": len(ref),
                               "reference_gps_fixed": len(ref_gps)}
        try:
            res = _solve(rv, base_lea, base_xyz, work / f"out-{seed}")
        except Exception as err:
            row["error"] = f"{type(err).__name__}: {err}"
            rows.append(row)
            continue
        refx = np.array([ref.get(m.number, np.full(3, np.nan)) for m in res.marks])
        has = np.all(np.isfinite(refx), axis=1)
        row.update(_judge(res, refx, has, t0))
        row["fixed_of_reference"] = round(row["fixed"] / max(len(ref), 1), 4)
        row["fixed_of_gps_reference"] = round(row["fixed"] / max(len(ref_gps), 1), 4)
        rows.append(row)
    return rows


def _graded(res: Any) -> dict[str, int]:
    """Camera positions per grade of a ``SolveResult``."""
    g = res.mark_positions.grade
    return {name: int(np.sum(g == code)) for code, name in GRADE_NAMES.items()
            if np.any(g == code)}


def why_real(work: Path, name: str) -> None:
    """Where a real flight's fixes go as a LEA-6T (issue 22, item 5): the camera positions
    graded fixed on the untouched recording (GPS + GLONASS, and GPS alone) and on its LEA-6T
    rewrite without faults; then the rewrite's epochs left at ``demoted:one-direction``: the
    one direction's fix against the untouched recording's checked fixes (GPS + GLONASS,
    graded ``fixed``), i.e. what promoting them would have given."""
    from groundstation.sim.rewrite import RewriteConfig, rewrite
    from groundstation.solve.integrity.grade import CHECK_NAMES, FIXED

    day, rover, base, base_xyz = JD_SWEEP[name]
    src = SHARED / "real" / "jdesbonnet__GNSS_RTK_data" / day
    work.mkdir(parents=True, exist_ok=True)
    full = _solve(src / f"{rover}.ubx.gz", src / f"{base}.ubx.gz", base_xyz, work / "full")
    gps = _solve(src / f"{rover}.ubx.gz", src / f"{base}.ubx.gz", base_xyz, work / "gps",
                 (("pos1-navsys", "1"),))
    (work / "rover.ubx").write_bytes(rewrite(src / f"{rover}.ubx.gz", RewriteConfig()).data)
    (work / "base.ubx").write_bytes(rewrite(src / f"{base}.ubx.gz", RewriteConfig()).data)
    lea = _solve(work / "rover.ubx", work / "base.ubx", base_xyz, work / "lea")
    print(f"{name}: camera positions per grade")
    for label, res in (("untouched, GPS + GLONASS", full), ("untouched, GPS alone", gps),
                       ("LEA-6T rewrite, no faults", lea)):
        print(f"  {label}: {_graded(res)}")
    tr = lea.trajectory
    one = np.flatnonzero(tr.check == CHECK_NAMES.index("demoted:one-direction")) \
        if tr.check is not None else np.zeros(0, dtype=np.int64)
    print(f"  rewrite epochs demoted:one-direction: {one.size}; their one direction's fix "
          "against the untouched recording (GPS + GLONASS):")
    graded = full.trajectory
    engine_own = read_pos(work / "full" / "rtklib" / "rover.pos")
    for label, ref, checked in (
            ("its checked fixes", graded, graded.grade == FIXED),
            ("the engine's own fixes (the sweep's reference)", engine_own,
             engine_own.quality == Q_FIX)):
        print(f"   {label}:")
        _one_direction_errors(work / "lea", tr.t_gps_ns[one], ref, checked)


MATCH_NS = 50_000_000
"""Epochs of two solutions within this are the same epoch."""


def _one_direction_errors(out: Path, t: npt.NDArray[np.int64], ref: Trajectory,
                          checked: npt.NDArray[np.bool_]) -> None:
    """Each direction's fixes at epochs ``t`` against ``ref`` where ``checked``."""
    for direction in ("forward", "backward"):
        run = read_pos(out / "rtklib" / direction / "rover.pos")
        k, j = nearest_index(run.t_gps_ns, t), nearest_index(ref.t_gps_ns, t)
        near = ((np.abs(run.t_gps_ns[k] - t) < MATCH_NS)  # .pos times: rounded to 1 us
                & (np.abs(ref.t_gps_ns[j] - t) < MATCH_NS))
        use = near & (run.quality[k] == Q_FIX) & checked[j]
        err = np.linalg.norm(run.ecef_m[k[use]] - ref.ecef_m[j[use]], axis=1)
        if err.size == 0:
            print(f"    {direction}: none to compare")
            continue
        print(f"    {direction}: {err.size} epochs, error min / median / max "
              f"{err.min():.3f} / {np.median(err):.3f} / {err.max():.3f} m, > 5 cm "
              f"{int((err > 0.05).sum())}, > 10 cm {int((err > WRONG_M).sum())}")


def _summary(rows: list[dict[str, Any]]) -> None:
    """Minimum, median and maximum per group, as a markdown table."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        key = r["flight"] + (f" ({r['faults']})" if "faults" in r else "")
        groups.setdefault(key, []).append(r)
    print("\n| flights | runs | failed | fixed (min / median / max) | wrong fixes (total, "
          "worst run) | worst fixed error | beyond 3 sigma and 5 cm (min / median / max) "
          "| wall s (min / median / max) |")
    print("|---|---:|---:|---|---|---:|---|---|")
    for key, rs in groups.items():
        ok = [r for r in rs if "error" not in r]
        if not ok:
            print(f"| {key} | {len(rs)} | {len(rs)} | | | | | |")
            continue
        share = "fixed_of_reference" if "fixed_of_reference" in ok[0] else "fixed_share"

        wrong = [r["wrong"] for r in ok]
        fixed = _mmm(ok, share)
        if "fixed_of_gps_reference" in ok[0]:
            fixed += (f" (of the {ok[0]['reference_gps_fixed']} of GPS alone: "
                      f"{_mmm(ok, 'fixed_of_gps_reference')})")
        print(f"| {key} | {len(rs)} | {len(rs) - len(ok)} | {fixed} | {sum(wrong)}, "
              f"{max(wrong)} | {max(r['worst_fixed_m'] for r in ok):.3f} m | "
              f"{_mmm(ok, 'beyond_share')} | {_mmm(ok, 'wall_s', False)} |")


def _mmm(rows: list[dict[str, Any]], key: str, share: bool = True) -> str:
    """``min / median / max`` of ``key`` over ``rows`` (as percentages for shares)."""
    v = np.array([r[key] for r in rows], dtype=float)

    def fmt(x: float) -> str:
        return f"{x:.1%}" if share else f"{x:.1f}"

    return f"{fmt(float(v.min()))} / {fmt(float(np.median(v)))} / {fmt(float(v.max()))}"


def sweep(args: argparse.Namespace) -> None:
    import json

    rows: list[dict[str, Any]] = []
    out = open(args.out, "w", encoding="utf-8") if args.out else None  # noqa: SIM115
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
        work = Path(tmp)

        def keep(r: dict[str, Any]) -> None:
            rows.append(r)
            print(json.dumps(r), flush=True)
            if out is not None:
                out.write(json.dumps(r) + "\n")
                out.flush()

        for name in JD_SWEEP if args.real_seeds != "none" else ():
            for r in sweep_real(work / name.replace(" ", "_"), name, _span(args.real_seeds)):
                keep(r)
        for sev in [float(v) for v in args.sweep_severities.split(",") if v]:
            for seed in _span(args.sweep_seeds):
                keep(sweep_sim(work / f"s{sev:g}_{seed}", seed, sev, args.sweep_faults))
                shutil.rmtree(work / f"s{sev:g}_{seed}", ignore_errors=True)
    if out is not None:
        out.close()
    _summary(rows)


def _observations(path: Path, work: Path) -> tuple[Any, list[Any]]:
    """(observations, ephemerides) of a recording, as the engine's RINEX conversion sees them."""
    got: list[tuple[Any, list[Any]]] = []

    def hook(obs: Any, ephs: Any, approx: Any) -> Any:
        got.append((obs, list(ephs)))
        return obs

    rinex.convert(path, work, rinex.RinexOptions(version="3.04"), None, hook)
    return got[0]


def _keep_epochs(obs: Any, keep_t: set[int]) -> Any:
    """``obs`` (conditioned) at the epochs of ``keep_t`` only; a start of an ambiguity (LLI
    bit 0) at a dropped epoch moves to the satellite's next kept epoch."""
    from dataclasses import replace

    kept = np.array([t in keep_t for t in obs.t_gps_ns.tolist()])
    new_index = np.cumsum(kept) - 1
    lli = obs.lli.copy()
    order = np.lexsort((obs.t_gps_ns[obs.epoch], obs.prn, obs.sys))
    carry: dict[tuple[str, int], bool] = {}
    for i in order.tolist():
        key = (str(obs.sys[i]), int(obs.prn[i]))
        if not kept[obs.epoch[i]]:
            carry[key] = carry.get(key, False) or bool(lli[i] & 1)
        elif carry.pop(key, False):
            lli[i] |= 1
    rows = kept[obs.epoch]
    return replace(obs, t_gps_ns=obs.t_gps_ns[kept], leap_s=obs.leap_s[kept],
                   epoch=new_index[obs.epoch[rows]], sys=obs.sys[rows], prn=obs.prn[rows],
                   code=obs.code[rows], pr_m=obs.pr_m[rows], cp_cyc=obs.cp_cyc[rows],
                   do_hz=obs.do_hz[rows], cno_dbhz=obs.cno_dbhz[rows], lli=lli[rows])


def _moved_on(decisions: list[tuple[int, str, int]], obs: Any) -> list[tuple[int, str, int]]:
    """The conditioning's decisions on observations thinned to fewer epochs: one at a dropped
    epoch moves to the satellite's next phase kept (its step shows there), as a restart does
    in :func:`_keep_epochs`; a put-back keeps the first phase it moved."""
    g = (obs.sys == "G") & (obs.cp_cyc != 0.0)
    times: dict[str, npt.NDArray[np.int64]] = {}
    for sv in sorted(set(obs.prn[g].tolist())):
        times[f"G{sv:02d}"] = np.sort(obs.t_gps_ns[obs.epoch[g & (obs.prn == sv)]])
    out = []
    for t, name, first in decisions:
        ts = times.get(name)
        k = int(np.searchsorted(ts, t)) if ts is not None else 0
        if ts is not None and k < ts.size:
            out.append((int(ts[k]), name, first if first < t else int(ts[k])))
    return out


def _bridges(clean: Any, faulty: Any) -> dict[str, int]:
    """The conditioning's bridges across the faulty stream's radio gaps, judged by the clean
    stream (the same receiver's phase, every epoch there): per satellite and pair of
    consecutive faulty epochs more than 1.5 intervals apart where neither stream started the
    ambiguity again, whether the two conditioned phases still differ by the same amount."""
    def table(o: Any) -> dict[tuple[int, int], int]:
        g = np.flatnonzero((o.sys == "G") & (o.cp_cyc != 0.0))
        t = o.t_gps_ns[o.epoch[g]]
        return {(int(a), int(b)): int(i) for a, b, i in zip(t, o.prn[g], g, strict=True)}

    mc, mf = table(clean), table(faulty)
    nominal = float(np.median(np.diff(np.unique(faulty.t_gps_ns))))
    starts: dict[int, npt.NDArray[np.int64]] = {}
    for (t, p), i in mc.items():
        if clean.lli[i] & 1:
            starts.setdefault(p, np.zeros(0, dtype=np.int64))
            starts[p] = np.append(starts[p], t)
    out = {"bridges": 0, "right": 0, "half_cycle_off": 0, "cycles_off": 0}
    by_sv: dict[int, list[int]] = {}
    for t, p in mf:
        if (t, p) in mc:
            by_sv.setdefault(p, []).append(t)
    for p, ts in by_sv.items():
        ts.sort()
        for t_prev, t in zip(ts, ts[1:], strict=False):
            if t - t_prev <= 1.5 * nominal or faulty.lli[mf[(t, p)]] & 1:
                continue
            st = starts.get(p, np.zeros(0, dtype=np.int64))
            if np.any((st > t_prev) & (st <= t)):
                continue
            d = ((faulty.cp_cyc[mf[(t, p)]] - clean.cp_cyc[mc[(t, p)]])
                 - (faulty.cp_cyc[mf[(t_prev, p)]] - clean.cp_cyc[mc[(t_prev, p)]]))
            out["bridges"] += 1
            if abs(d) < 0.1:
                out["right"] += 1
            elif abs(abs(d) - 0.5) < 0.1:
                out["half_cycle_off"] += 1
            else:
                out["cycles_off"] += 1
    return out


def why_gaps(work: Path, name: str, fault_seeds: list[int]) -> list[dict[str, Any]]:
    """What a real flight's radio gaps cost the whole-arc solution (issue 22), per fault seed
    of the seed link: the conditioning's bridges across the gaps judged by the same flight
    without faults (:func:`_bridges`), and the whole-arc solution (gaps judged, fixed epochs)
    on three streams: without faults; without faults but only at the epochs the link let
    through (the phase every satellite kept, the gaps alone); through the link."""
    from groundstation.sim.faults import FaultConfig
    from groundstation.sim.rewrite import RewriteConfig, rewrite
    from groundstation.solve import conditioning
    from groundstation.solve.integrity.assess import arcs_stage

    day, rover, base, base_xyz = JD_SWEEP[name]
    src = SHARED / "real" / "jdesbonnet__GNSS_RTK_data" / day
    work.mkdir(parents=True, exist_ok=True)
    (work / "base.ubx").write_bytes(rewrite(src / f"{base}.ubx.gz", RewriteConfig()).data)
    base_obs, base_ephs = _observations(work / "base.ubx", work / "base")

    def stream(seed: int) -> tuple[Any, list[Any], list[tuple[int, str, int]]]:
        faults = FaultConfig.none() if seed == 0 else FaultConfig.seed()
        rv = work / f"rover-{seed}.ubx"
        rv.write_bytes(rewrite(src / f"{rover}.ubx.gz",
                               RewriteConfig(faults=faults, seed=max(seed, 1))).data)
        obs, ephs = _observations(rv, work / f"rover-{seed}")
        approx = (float(base_xyz[0]), float(base_xyz[1]), float(base_xyz[2]))
        out, rep = conditioning.condition(obs, ephs, approx)
        return out, ephs, rep.decisions

    def solved(obs: Any, ephs: list[Any], decisions: list[tuple[int, str, int]],
               ) -> dict[str, Any]:
        have = set(ephs)
        arcs = arcs_stage(obs, base_obs, ephs + [e for e in base_ephs if e not in have],
                          base_xyz, decisions)
        if arcs is None:
            return {"epochs": 0}
        doubts = arcs.resolution.gap_doubts
        return {"epochs": int(arcs.t_ns.size), "fixed_epochs": int(arcs.fixed.sum()),
                "arcs": int(arcs.resolution.tab.n_arcs),
                "gaps_contradicted": sum(d.contradicted for d in doubts),
                "gaps_could_hide": sum(not d.contradicted for d in doubts)}

    clean, clean_ephs, clean_dec = stream(0)
    rows = [{"flight": name, "seed": 0, "stream": "no faults",
             **solved(clean, clean_ephs, clean_dec)}]
    for seed in fault_seeds:
        faulty, ephs, dec = stream(seed)
        kept = set(faulty.t_gps_ns.tolist())
        thinned = _keep_epochs(clean, kept)
        rows.append({"flight": name, "seed": seed, "stream": "no faults, link's epochs only",
                     **solved(thinned, clean_ephs, _moved_on(clean_dec, thinned))})
        rows.append({"flight": name, "seed": seed, "stream": "seed link",
                     **solved(faulty, ephs, dec), **_bridges(clean, faulty)})
    for r in rows:
        print(r, flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--seed-s", type=float, default=1200.0)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--severities", default="0.5,1,2")
    ap.add_argument("--only", default="", help="only datasets whose key contains this")
    ap.add_argument("--ours-opt", action="append", default=[], metavar="KEY=VALUE",
                    help="an engine option for the 'ours' rows only (repeatable)")
    ap.add_argument("--hour", action="store_true")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--sweep", action="store_true", help="issue 22's sweep (see the doc)")
    ap.add_argument("--sweep-seeds", default="501-530")
    ap.add_argument("--sweep-severities", default="0.5,1,1.5,2")
    ap.add_argument("--sweep-faults", default="", metavar="SPEC",
                    help="the simulated flights' link: none, default, seed or a fault file "
                         "(benchmarks/faults/); default: the seed profile's own")
    ap.add_argument("--real-seeds", default="1-5", help="fault seeds of the real flights, or "
                    "none")
    ap.add_argument("--out", default="", help="write every run as a JSON line here")
    ap.add_argument("--interp", default="", help="the sweep's interpolation at the marks "
                    "(default: solve's)")
    ap.add_argument("--why-real", action="store_true", help="where the real flights' fixes "
                    "go as a LEA-6T (see why_real)")
    ap.add_argument("--why-gaps", action="store_true", help="what the real flights' radio "
                    "gaps cost the whole-arc solution, for each of --real-seeds (see why_gaps)")
    args = ap.parse_args()
    if args.interp:
        INTERP.append(args.interp)
    if args.why_real:
        with tempfile.TemporaryDirectory(prefix="bench-why-") as tmp:
            for name in JD_SWEEP:
                why_real(Path(tmp) / name.replace(" ", "_"), name)
    elif args.why_gaps:
        with tempfile.TemporaryDirectory(prefix="bench-gaps-") as tmp:
            for name in JD_SWEEP:
                why_gaps(Path(tmp) / name.replace(" ", "_"), name, _span(args.real_seeds))
    elif args.hour:
        hour(args)
    elif args.sweep:
        sweep(args)
    else:
        table(args)


if __name__ == "__main__":
    main()
