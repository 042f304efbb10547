"""Ten simulated stations at 5 Hz through one router: marks lost, mark latency, CPU.

Run: python benchmarks/bench_stations.py [--stations 10] [--seconds 600]

Every station is two processes, each in its own working directory: ``groundstation simulate
--tcp`` (a receiver streaming in real time, 5 Hz epochs and time marks, no faults) and
``groundstation run --tcp`` (the daemon, recording and publishing). One ``groundstation router``
listens on a free loopback port; the daemons are all given that endpoint as their listen
endpoint, the default settings' shape, find it taken and join the router (``groundstation.bus``).
This process subscribes to every station's time marks through the router.

The simulated flights (``simulate --duration`` of ``--seconds`` + 300 s) stand on the ground for
the first quarter or more of their span, climb, fly four 100 m survey lines with an exposure
every 2 m (the marks, about five minutes of them), and land. The measurement starts when every
station's first mark has arrived and lasts ``--seconds``: with the default 600 s it holds every
flight's marks and, all along, every station's 5 Hz epochs, status and events.

- marks lost: at the end every daemon is asked for all its marks (``q/timemarks``); a mark it
  holds that this subscriber never received live is lost (0 expected).
- mark latency: receipt here minus the daemon's host time of the mark (``t_host_ns``, the moment
  the daemon read the bytes; one machine, one clock): the daemon's pipeline + Zenoh + router.
- CPU: user + system time of the router and of each daemon over the measured span (from
  ``/proc/<pid>/stat``), as a percentage of one core.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from groundstation.bus import decode, key, open_bus
from groundstation.config import ZenohSettings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # peers
from peers import cli_env, free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def start(cwd: Path, *argv: str) -> subprocess.Popen[bytes]:
    cwd.mkdir(parents=True, exist_ok=True)
    return subprocess.Popen([sys.executable, "-m", "groundstation.cli", "-q", *argv], cwd=cwd,
                            env=cli_env(), stdout=subprocess.DEVNULL,
                            stderr=(cwd / "stderr.txt").open("w"))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stations", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=600.0, help="measured span")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="gs-stations-"))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    names = [f"s{i:02d}" for i in range(args.stations)]
    procs: list[subprocess.Popen[bytes]] = []
    lock = threading.Lock()
    live: dict[str, set[int]] = {n: set() for n in names}
    latency_ms: list[float] = []
    alive: set[str] = set()

    def on_mark(k: str, payload: bytes) -> None:
        now = time.time_ns()
        doc = decode(payload)
        with lock:
            live[doc["station"]].add(doc["index"])
            latency_ms.append((now - doc["t_host_ns"]) / 1e6)

    def on_alive(k: str, up: bool) -> None:
        with lock:
            (alive.add if up else alive.discard)(k.split("/")[1])

    ok = False
    try:
        router = start(tmp / "router", "router", "--listen", endpoint)
        procs.append(router)
        bus = None
        for _ in range(100):
            try:
                bus = open_bus(ZenohSettings(mode="client", listen=(), connect=(endpoint,)))
                break
            except Exception:
                time.sleep(0.2)
        assert bus is not None, "the router did not come up"
        bus.subscribe(key("*", "timemark"), on_mark)
        bus.subscribe_liveliness(key("*", "alive"), on_alive)
        daemons: dict[str, subprocess.Popen[bytes]] = {}
        span = args.seconds + 300  # take-off first, landing after the measurement
        for name in names:
            port = free_port()
            procs.append(start(tmp / f"{name}-sim", "simulate", "--tcp", str(port), "--duration",
                               str(span), "--speed", "1", "--seed", str(names.index(name) + 1)))
            daemons[name] = start(tmp / name, "run", "--tcp", f"127.0.0.1:{port}", "--station",
                                  name, "--zenoh-listen", endpoint)
            procs.append(daemons[name])
        deadline = time.monotonic() + 120
        while len(alive) < len(names):
            if time.monotonic() > deadline:
                print(f"only {sorted(alive)} came up; see {tmp}", file=sys.stderr)
                return 1
            time.sleep(0.5)
        # the simulated flights take off after a minute on the ground: marks start then
        while True:
            with lock:
                if all(live.values()):
                    break
            if time.monotonic() > deadline + 300:
                print(f"no marks from some stations; see {tmp}", file=sys.stderr)
                return 1
            time.sleep(0.5)
        with lock:
            for s in live.values():
                s.clear()
            latency_ms.clear()
        cpu0 = {n: cpu_s(p.pid) for n, p in daemons.items()} | {"router": cpu_s(router.pid)}
        t0 = time.monotonic()
        time.sleep(args.seconds)
        elapsed = time.monotonic() - t0
        cpu1 = {n: cpu_s(p.pid) for n, p in daemons.items()} | {"router": cpu_s(router.pid)}
        time.sleep(1.0)  # the last marks in flight
        with lock:
            first = {n: min(s) if s else None for n, s in live.items()}
        lost = held = 0
        for name in names:
            indices = {decode(p)["index"] for _, p in bus.get(key(name, "q/timemarks"), 10.0)}
            start_index = first[name]
            if start_index is None:
                print(f"{name}: no mark received live", file=sys.stderr)
                continue
            last = max(live[name])
            window = {i for i in indices if start_index <= i <= last}
            held += len(window)
            lost += len(window - live[name])
        lat = sorted(latency_ms)
        pct = {n: 100 * (cpu1[n] - cpu0[n]) / elapsed for n in cpu0}
        d = [pct[n] for n in names]
        print(f"{len(names)} stations, {elapsed:.0f} s measured: marks {held} held by the "
              f"daemons, {lost} lost; latency p50 {statistics.median(lat):.2f} ms, "
              f"p99 {lat[int(0.99 * (len(lat) - 1))]:.2f} ms, max {lat[-1]:.2f} ms; "
              f"router CPU {pct['router']:.1f}%; daemon CPU mean {statistics.mean(d):.1f}% "
              f"(max {max(d):.1f}%) of one core")
        bus.close()
        ok = lost == 0
        return 0 if ok else 1
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
        if ok:
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            print(f"logs and recordings kept in {tmp}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
