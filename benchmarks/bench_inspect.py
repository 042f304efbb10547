"""Whole-process time of ``groundstation inspect`` against RTKLIB ``convbin`` on the same recording.

As issue 12 states the target: ``groundstation inspect X.ubx.gz`` against
``convbin -r ubx -od -os -o X.obs -n X.nav X.ubx`` (convbin cannot read gzip, so it gets the
file decompressed beforehand). Both run as fresh processes, interleaved; the best of N runs
counts, and the CPU time (user + system, from ``wait4``) is shown beside the wall time because
the machine is shared: on a busy machine wall time overstates both, CPU time much less. Our
process gets its bytecode cache in a temporary directory (``PYTHONPYCACHEPREFIX``, one warm-up
run first), as an installed package has it, even where ``PYTHONDONTWRITEBYTECODE`` is set.

    .venv/bin/python benchmarks/bench_inspect.py [INPUT.ubx.gz] [--runs 7]
"""

from __future__ import annotations

import argparse
import gzip
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_INPUT = (
    REPO.parent / "shared/data/real/jdesbonnet__GNSS_RTK_data/20181104/rover-20181104-1634.ubx.gz"
)


def run(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall s, CPU s) of one fresh process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO, env=env
    )
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{cmd[0]} failed with {proc.returncode}")
    return wall, usage.ru_utime + usage.ru_stime


def setup(description: str) -> tuple[argparse.Namespace, str, list[str]] | None:
    """The benchmarks' shared command line (input, ``--runs``), convbin's path and our command;
    None (after one line on stderr) when the input or convbin is missing."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("input", nargs="?", type=Path, default=DEFAULT_INPUT)
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    if not args.input.exists():
        print(f"input not found: {args.input}", file=sys.stderr)
        return None
    convbin = shutil.which("convbin")
    if convbin is None:
        print("convbin not installed (apt-get install rtklib)", file=sys.stderr)
        return None
    gs = shutil.which("groundstation") or ""
    return args, convbin, [gs] if gs else [sys.executable, "-m", "groundstation.cli"]


def plain_copy(src_path: Path, dir_: Path) -> Path:
    """``src_path`` decompressed (if gzipped) into ``dir_/input.ubx``: what convbin reads."""
    ubx = dir_ / "input.ubx"
    opener = gzip.open if src_path.suffix == ".gz" else open
    with opener(src_path, "rb") as src, ubx.open("wb") as dst:
        shutil.copyfileobj(src, dst)
    return ubx


OursArgs = Callable[[Path, Path, Path], list[str]]
"""Our command's arguments from (the given input, its decompressed copy, a scratch folder)."""


def against_convbin(description: str, what: str, ours_args: OursArgs) -> int:
    """Interleaved runs of convbin and of ``groundstation <what>`` on one input (the shared
    command line of :func:`setup`); prints best and median wall and CPU times and the ratios."""
    got = setup(description)
    if got is None:
        return 2
    args, convbin, ours_cmd = got
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        ubx = plain_copy(args.input, t)
        cb = [convbin, "-r", "ubx", "-od", "-os", "-o", str(t / "cb.obs"), "-n", str(t / "cb.nav"),
              str(ubx)]
        ours = [*ours_cmd, *ours_args(args.input, ubx, t)]
        # the bytecode cache an installed package has
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPYCACHEPREFIX"] = str(t / "pycache")
        run(cb)
        run(ours, env)  # warm-up: page cache, bytecode cache
        times: dict[str, list[tuple[float, float]]] = {"convbin": [], "groundstation": []}
        for _ in range(args.runs):  # interleaved, so load changes hit both alike
            times["convbin"].append(run(cb))
            times["groundstation"].append(run(ours, env))
        size_mb = ubx.stat().st_size / 1e6
    print(f"input: {args.input.name} ({size_mb:.2f} MB decompressed), {args.runs} runs each")
    best: dict[str, tuple[float, float]] = {}
    med: dict[str, tuple[float, float]] = {}
    for name, v in times.items():
        walls = sorted(w for w, _ in v)
        cpus = sorted(c for _, c in v)
        best[name] = (walls[0], cpus[0])
        med[name] = (walls[len(v) // 2], cpus[len(v) // 2])
        print(f"{name:<14} wall best {walls[0]:.3f} s  median {med[name][0]:.3f} s   "
              f"CPU best {cpus[0]:.3f} s  median {med[name][1]:.3f} s")
    ours_best, cb_best = best["groundstation"], best["convbin"]
    med_ratio = med["groundstation"][0] / med["convbin"][0]
    print(f"ratio {what} / convbin: wall best {ours_best[0] / cb_best[0]:.2f}  median "
          f"{med_ratio:.2f}   CPU best {ours_best[1] / cb_best[1]:.2f}")
    return 0


def main() -> int:
    return against_convbin(__doc__.splitlines()[0], "inspect",
                           lambda src, _ubx, _tmp: ["inspect", str(src)])


if __name__ == "__main__":
    sys.exit(main())
