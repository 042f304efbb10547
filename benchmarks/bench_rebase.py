"""``solve --rebase`` against a full solve with the same new base, back to back (issue 24).

For each flight: one full solve with the surveyed base (the result to re-base), then N pairs
run in turn, A B A B: A = ``solve --rebase RESULT --base-xyz NEW``, B = the full solve with
``--base-xyz NEW``. Both are fresh processes with the same report options (``--no-pdf`` unless
``--pdf``). Printed per flight: wall and CPU seconds of each, min / median / max, and the
ratio A/B pair by pair; then how far the re-based cameras lie from the full solve's (fixed
ones: the bar is 1 mm; the engine's float filter moves within its sigma when the base moves).

Flights: the real 2018-10-09 flight of ``../shared/data`` (skipped with a line when absent)
and a simulated one-hour LEA-6T flight (``--hour``), its base moved 1 m.

    .venv/bin/python benchmarks/bench_rebase.py [--runs 5] [--pdf] [--hour]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from groundstation.geodesy import ecef_to_llh, enu_rotation, llh_to_ecef

REPO = Path(__file__).resolve().parents[1]
JD = REPO.parent / "shared/data/real/jdesbonnet__GNSS_RTK_data/20181009"
JD_BASE = (3774696.5547, -596647.9083, 5089485.6511)
MOVE_ENU_M = (0.35, -0.2, 0.9)
"""How far the base moves: about a metre, mostly in height (a height typed wrong)."""


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "groundstation.cli", "solve", "--no-progress", *args]


def _run(cmd: list[str]) -> tuple[float, float]:
    """(wall s, CPU s) of one fresh process; exits on a failure."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{err}")
    return wall, usage.ru_utime + usage.ru_stime


def _cameras(out: Path) -> list[dict[str, str]]:
    with (out / "cameras.csv").open() as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def _differences(a: Path, b: Path) -> tuple[list[float], list[float]]:
    """Distances (m) between the cameras of two results: (fixed, others)."""
    fixed: list[float] = []
    other: list[float] = []
    for r, s in zip(_cameras(a), _cameras(b), strict=True):
        if not r["lat_deg"] or not s["lat_deg"]:
            continue
        p, q = (np.array(llh_to_ecef(float(x["lat_deg"]), float(x["lon_deg"]),
                                     float(x["ellipsoidal_h_m"]))) for x in (r, s))
        (fixed if r["grade"] == "fixed" else other).append(float(np.linalg.norm(p - q)))
    return fixed, other


def _stats(values: list[float], fmt: str = "{:.3f}") -> str:
    return " / ".join(fmt.format(v) for v in (min(values), statistics.median(values),
                                              max(values)))


def bench(name: str, solve_args: list[str], base: tuple[float, float, float], runs: int,
          pdf: bool, work: Path) -> None:
    lat, lon, _ = ecef_to_llh(*base)
    new = np.array(base) + np.array(enu_rotation(lat, lon)).T @ np.array(MOVE_ENU_M)
    xyz = ",".join(f"{v:.4f}" for v in new.tolist())
    report = [] if pdf else ["--no-pdf"]
    done = work / f"{name}-done"
    _run(_cli(*solve_args, "--base-xyz", ",".join(f"{v:.4f}" for v in base),
              "--out-dir", str(done), *report))
    rebase = _cli("--rebase", str(done), "--base-xyz", xyz, "--out-dir", str(work / f"{name}-A"),
                  *report)
    full = _cli(*solve_args, "--base-xyz", xyz, "--out-dir", str(work / f"{name}-B"), *report)
    _run(rebase)  # warm-up (bytecode, page cache)
    a, b = [], []
    for _ in range(runs):
        a.append(_run(rebase))
        b.append(_run(full))
    print(f"## {name} ({'with' if pdf else 'without'} the PDF, {runs} pairs)")
    print(f"re-base wall s  {_stats([w for w, _ in a])}   CPU s {_stats([c for _, c in a])}")
    print(f"full    wall s  {_stats([w for w, _ in b])}   CPU s {_stats([c for _, c in b])}")
    print(f"ratio   wall    {_stats([x[0] / y[0] for x, y in zip(a, b, strict=True)])}   "
          f"CPU {_stats([x[1] / y[1] for x, y in zip(a, b, strict=True)])}")
    fixed, other = _differences(work / f"{name}-A", work / f"{name}-B")
    print(f"cameras, re-based vs solved again (mm): fixed {len(fixed)}: "
          f"{_stats([d * 1000 for d in fixed], '{:.2f}')}" + (
              f"; others {len(other)}: {_stats([d * 1000 for d in other], '{:.1f}')}"
              if other else ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--pdf", action="store_true", help="both print report.pdf (Chromium)")
    ap.add_argument("--hour", action="store_true", help="also a simulated one-hour flight")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_rebase.") as tmp:
        work = Path(tmp)
        if JD.is_dir():
            bench("real 2018-10-09", [str(JD / "rover-20181009-1221.ubx.gz"), "--base",
                                      str(JD / "base-20181009-1220.ubx.gz")],
                  JD_BASE, args.runs, args.pdf, work)
        else:
            print(f"skipped the real flight: {JD} not found", file=sys.stderr)
        if args.hour:
            sim = [sys.executable, "-m", "groundstation.cli", "simulate", "--out",
                   str(work / "hour.ubx"), "--base-out", str(work / "hourbase.ubx"),
                   "--duration", "3600", "--truth", str(work / "hour.json")]
            _run(sim)
            truth = json.loads((work / "hour.json").read_text())
            x, y, z = truth["base"]["ecef_m"]
            bench("simulated hour", [str(work / "hour.ubx"), "--base",
                                     str(work / "hourbase.ubx")],
                  (round(x, 4), round(y, 4), round(z, 4)), args.runs, args.pdf, work)


if __name__ == "__main__":
    main()
