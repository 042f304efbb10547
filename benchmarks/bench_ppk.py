"""PPK engines on the same RINEX files: wall time, epochs, fixed share (issue 13).

Run: python benchmarks/bench_ppk.py [--repeat 3] [--sim-s 400]
Engines: Debian's rnx2rtkp 2.4.3 b34 with its options; demo5 (pyrtklib5, worker process) with
the same b34 options; demo5 with our u-blox L1 5 Hz default. Datasets: the real 2018-10-09
jdesbonnet M8P flight (convbin's RINEX, when ../shared/data is present) and a simulated LEA-6T
flight (our RINEX writer), both combined forward + backward. Wall time is the best of
``--repeat`` runs of ``run_engine`` on RINEX input (no conversion), including the demo5 worker's
start (about 0.3 s); the ratio is against b34 on the same files and options, so it holds across
machines. The full engines x datasets table of issue 13 is still to come.
"""

from __future__ import annotations

import argparse
import gzip
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from groundstation.offline import rinex
from groundstation.sim.faults import FaultConfig
from groundstation.sim.stream import SimConfig, simulate
from groundstation.solve import engine
from groundstation.solve.engine import options as eo
from groundstation.solve.positions import read_pos

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
JD_BASE = (3774696.5547, -596647.9083, 5089485.6511)


def real_flight(work: Path) -> tuple[Path, Path, tuple[float, float, float]] | None:
    src = SHARED / "reference" / "convbin_rinex"
    if not src.is_dir():
        return None
    for stem in ("rover-20181009-1221", "base-20181009-1220"):
        for ext in ("obs", "nav"):
            (work / f"{stem}.{ext}").write_bytes(
                gzip.decompress((src / f"{stem}.{ext}.gz").read_bytes()))
    return work / "rover-20181009-1221.obs", work / "base-20181009-1220.obs", JD_BASE


def sim_flight(work: Path, duration_s: float) -> tuple[Path, Path, tuple[float, float, float]]:
    sim = simulate(SimConfig(duration_s=duration_s, seed=3, faults=FaultConfig.default()))
    obs = []
    for name, data in (("rover", sim.rover_bytes), ("base", sim.base_bytes)):
        ubx = work / f"{name}.ubx"
        ubx.write_bytes(data)
        res = rinex.convert(ubx, work / name, rinex.RinexOptions(version="3.04"))
        obs.append(res.obs_path)
    b = sim.truth["base"]["ecef_m"]
    return obs[0], obs[1], (float(b[0]), float(b[1]), float(b[2]))


def run(engine_name: str, overrides: dict[str, str], files: tuple[Path, Path, tuple[float, float,
        float]], work: Path, repeat: int) -> tuple[float, int, float]:
    best = float("inf")
    n, fixed = 0, 0.0
    for k in range(repeat):
        t = time.perf_counter()
        r = engine.run_engine(engine_name, files[0], files[1], files[2], work / f"{k}",
                              overrides=overrides)
        best = min(best, time.perf_counter() - t)
        traj = read_pos(r.pos_path)
        n, fixed = len(traj), float(np.mean(traj.quality == 1))
    return best, n, fixed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sim-s", type=float, default=400.0)
    args = ap.parse_args()
    # demo5 reads b34's options through its own table: drop the output keys both share anyway.
    b34_opts = {k: v for k, v in eo.B34_L1_KINEMATIC.items() if k not in eo.OUTPUT_OPTIONS}
    engines = [("rnx2rtkp", "b34 options", b34_opts), ("demo5", "b34 options", b34_opts),
               ("demo5", "our default", {})]
    if shutil.which("rnx2rtkp") is None:
        engines = engines[1:]
        print("rnx2rtkp not installed: demo5 rows only")
    with tempfile.TemporaryDirectory(prefix="bench-ppk-") as tmp:
        work = Path(tmp)
        (work / "real").mkdir()
        (work / "sim").mkdir()
        datasets = [("simulated LEA-6T", sim_flight(work / "sim", args.sim_s))]
        real = real_flight(work / "real")
        if real is not None:
            datasets.insert(0, ("real 2018-10-09 M8P", real))
        print("| dataset | engine | options | epochs | fixed | wall (best of "
              f"{args.repeat}) | vs b34 |")
        print("|---|---|---|---:|---:|---:|---:|")
        for ds, files in datasets:
            ref = None
            for i, (name, label, opts) in enumerate(engines):
                wall, n, fixed = run(name, dict(opts), files, work / f"{ds[:4]}{i}", args.repeat)
                if name == "rnx2rtkp":
                    ref = wall
                ratio = f"{wall / ref:.2f}x" if ref else "-"
                print(f"| {ds} | {name} | {label} | {n} | {fixed:.1%} | {wall:.2f} s | {ratio} |",
                      flush=True)


if __name__ == "__main__":
    main()
