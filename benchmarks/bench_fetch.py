"""Fetching a recording over Zenoh: throughput by window size, against reading it locally.

Run: python benchmarks/bench_fetch.py [--mb 32] [--router]

A file of ``--mb`` MB of random bytes (the transfer does not look inside it) is served by
:class:`groundstation.live.serve.RecordingServer` on one Zenoh session and fetched by
:class:`groundstation.solve.fetch.Fetcher` on another, over loopback TCP: directly (the
solver a client of the daemon's peer) or, with ``--router``, both as clients of a
``groundstation router`` process. Each window size fetches the whole file (256 KiB chunks,
CRC per chunk, SHA-256 of the whole file at the end). The reference is reading the file and
hashing it in this process (what a solver on the daemon's machine does); the figures are
ratios to it, taken back to back.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # peers

from peers import free_port  # noqa: E402

from groundstation.bus import open_bus  # noqa: E402
from groundstation.config import ZenohSettings  # noqa: E402
from groundstation.live.serve import RecordingServer  # noqa: E402
from groundstation.solve.fetch import Fetcher, Remote  # noqa: E402
from groundstation.storage.transfer import sha256_file  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=32.0)
    ap.add_argument("--router", action="store_true", help="both ends through a router")
    ap.add_argument("--windows", default="1,4,8,16")
    args = ap.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = None
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        src = d / "rover_20260101T000000Z.mcap"
        src.write_bytes(os.urandom(int(args.mb * 1e6)))
        if args.router:
            env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
            router = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "router",
                                       "--listen", endpoint], env=env, cwd=d,
                                      stderr=subprocess.DEVNULL)
            time.sleep(2.0)
            station_settings = ZenohSettings(mode="client", listen=(), connect=(endpoint,))
        else:
            station_settings = ZenohSettings(listen=(endpoint,))
        station = open_bus(station_settings)
        solver = open_bus(ZenohSettings(mode="client", listen=(), connect=(endpoint,)))
        try:
            server = RecordingServer("rover")
            served = server.add(src, "rover_20260101T000000Z")
            assert served is not None
            server.bind(station)
            time.sleep(1.0)
            t0 = time.perf_counter()
            sha256_file(src)
            ref = time.perf_counter() - t0
            print(f"file {args.mb:g} MB; via {'router' if args.router else 'peer link'}; "
                  f"load {Path('/proc/loadavg').read_text().split()[0]}")
            print(f"reference: read + SHA-256 locally: {ref:.3f} s "
                  f"({args.mb / ref:.0f} MB/s)")
            print("| window | time | MB/s | x reference |")
            print("|---:|---:|---:|---:|")
            for w in (int(x) for x in args.windows.split(",")):
                out = d / f"out-{w}"
                remote = Remote("rover", "rover_20260101T000000Z", served.name, served.size,
                                served.sha256, served.chunk_bytes, out / "rover" / served.name)
                t0 = time.perf_counter()
                got = Fetcher(solver, window=w).fetch(remote)
                dt = time.perf_counter() - t0
                assert got.stat().st_size == served.size
                print(f"| {w} | {dt:.3f} s | {args.mb / dt:.0f} | {dt / ref:.1f} |")
                got.unlink()
        finally:
            solver.close()
            station.close()
            if router is not None:
                router.terminate()
                router.wait(timeout=10)


if __name__ == "__main__":
    main()
