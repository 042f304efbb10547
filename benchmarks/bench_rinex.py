"""Whole-process wall time of ``groundstation rinex`` against RTKLIB ``convbin`` on the same input.

Both run as fresh processes on the same decompressed ``.ubx`` (convbin cannot read gzip), as a user
would run them; the best of N runs counts (the machine is shared, the minimum is the least noisy
estimate). convbin gets the options the reference RINEX was made with (``-od -os``: Doppler and
SNR); its progress output goes to /dev/null as ours does. Wall time and CPU time (user + system of
the process, from ``wait4``) are both reported: on a shared machine the CPU time is the steadier.

    .venv/bin/python benchmarks/bench_rinex.py [INPUT] [--runs 7]

A 10-hour simulated flight: ``groundstation simulate --out /tmp/sim10h.ubx --duration 36000
--faults default --seed 8``, then ``bench_rinex.py /tmp/sim10h.ubx --runs 3``.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from bench_inspect import plain_copy, run, setup

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    got = setup(__doc__.splitlines()[0])
    if got is None:
        return 2
    args, convbin, ours_cmd = got
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        ubx = plain_copy(args.input, t)
        cb = [convbin, "-r", "ubx", "-od", "-os", "-o", str(t / "cb.obs"), "-n", str(t / "cb.nav"),
              str(ubx)]
        ours = [*ours_cmd, "rinex", str(ubx), "-o", str(t / "gs"), "--progress", "never"]
        # the bytecode cache an installed package has, as in bench_inspect
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
    print(f"ratio groundstation / convbin: wall best {ours_best[0] / cb_best[0]:.2f}  median "
          f"{med_ratio:.2f}   CPU best {ours_best[1] / cb_best[1]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
