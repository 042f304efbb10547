"""Whole-process wall time of ``groundstation rinex`` against RTKLIB ``convbin`` on the same input.

Both run as fresh processes on the same decompressed ``.ubx`` (convbin cannot read gzip), as a user
would run them; the best of N runs counts (the machine is shared, the minimum is the least noisy
estimate). convbin gets the options the reference RINEX was made with (``-od -os``: Doppler and
SNR); its progress output goes to /dev/null as ours does.

    .venv/bin/python benchmarks/bench_rinex.py [INPUT] [--runs 7]
"""

from __future__ import annotations

import argparse
import gzip
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_INPUT = (
    REPO.parent / "shared/data/real/jdesbonnet__GNSS_RTK_data/20181104/rover-20181104-1634.ubx.gz"
)


def wall_s(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("input", nargs="?", type=Path, default=DEFAULT_INPUT)
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    if not args.input.exists():
        print(f"input not found: {args.input}", file=sys.stderr)
        return 2
    convbin = shutil.which("convbin")
    if convbin is None:
        print("convbin not installed (apt-get install rtklib)", file=sys.stderr)
        return 2
    gs = shutil.which("groundstation") or ""
    ours_cmd = [gs] if gs else [sys.executable, "-m", "groundstation.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        ubx = t / "input.ubx"
        opener = gzip.open if args.input.suffix == ".gz" else open
        with opener(args.input, "rb") as src, ubx.open("wb") as dst:
            shutil.copyfileobj(src, dst)
        cb = [convbin, "-r", "ubx", "-od", "-os", "-o", str(t / "cb.obs"), "-n", str(t / "cb.nav"),
              str(ubx)]
        ours = [*ours_cmd, "rinex", str(ubx), "-o", str(t / "gs"), "--progress", "never"]
        times: dict[str, list[float]] = {"convbin": [], "groundstation": []}
        for _ in range(args.runs):  # interleaved, so load changes hit both alike
            times["convbin"].append(wall_s(cb))
            times["groundstation"].append(wall_s(ours))
        size_mb = ubx.stat().st_size / 1e6
    best = {k: min(v) for k, v in times.items()}
    med = {k: sorted(v)[len(v) // 2] for k, v in times.items()}
    print(f"input: {args.input.name} ({size_mb:.2f} MB decompressed), {args.runs} runs each")
    print(f"convbin:        best {best['convbin']:.3f} s  median {med['convbin']:.3f} s")
    gs_best, gs_med = best["groundstation"], med["groundstation"]
    print(f"groundstation:  best {gs_best:.3f} s  median {gs_med:.3f} s")
    print(f"ratio groundstation / convbin: best {best['groundstation'] / best['convbin']:.2f}  "
          f"median {med['groundstation'] / med['convbin']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
