"""Latency from the last byte of a TIM-TM2 written into the pty to its receipt by a Zenoh
subscriber in another process (this one), over the real daemon.

Run: python benchmarks/bench_zenoh_latency.py [--marks N] [--rate HZ]
Both timestamps come from this process's monotonic clock, so no clock sync is involved.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

from groundstation.bus import decode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.ubx import layouts as L

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # peers
from peers import free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
WEEK, TOW0_MS = 2300, 300_000_000


def tim_tm2(count: int, tow_ms: int) -> bytes:
    flags = L.TIM_TM2_FLAGS.compose(
        mode=1, run=1, newFallingEdge=1, newRisingEdge=1, timeBase=1, utc=1, time=1
    )
    return L.TIM_TM2.frame(flags=flags, count=count, wnR=WEEK, wnF=WEEK, towMsR=tow_ms + 14,
                           towMsF=tow_ms, accEst=20)


def rxm_raw(tow_ms: int) -> bytes:
    rows = [{"cpMes": 1e8 + prn, "prMes": 2e7 + prn, "doMes": 100.0, "sv": prn, "mesQI": 7,
             "cno": 45} for prn in range(1, 9)]
    return L.RXM_RAW.frame(rows, iTOW=tow_ms, week=WEEK)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--marks", type=int, default=600)
    ap.add_argument("--rate", type=float, default=10.0, help="marks per second")
    args = ap.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    master, slave = os.openpty()
    tty.setraw(slave)
    out = tempfile.mkdtemp(prefix="gs-latency-")
    daemon = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "-q", "run", "--port", os.ttyname(slave),
         "--station", "lat", "--out-dir", out, "--zenoh-listen", endpoint],
        cwd=REPO,
    )
    rx: dict[int, int] = {}
    sent: dict[int, int] = {}
    lock = threading.Lock()

    def on_mark(_k: str, payload: bytes) -> None:
        t = time.monotonic_ns()
        count = decode(payload)["count"]
        with lock:
            rx.setdefault(count, t)

    bus = open_bus(ZenohSettings(listen=(), connect=(endpoint,)))
    try:
        deadline = time.monotonic() + 15
        while not bus.get(key("lat", "q/status"), timeout_s=0.5):
            if time.monotonic() > deadline:
                print("daemon did not come up", file=sys.stderr)
                return 1
        bus.subscribe(key("lat", "timemark"), on_mark)
        time.sleep(0.5)
        period = 1.0 / args.rate
        for i in range(args.marks):
            tow = TOW0_MS + int(i * period * 1000)
            os.write(master, rxm_raw(tow))
            frame = tim_tm2(i, tow + 20)
            os.write(master, frame)
            sent[i] = time.monotonic_ns()
            time.sleep(period)
        time.sleep(1.0)
    finally:
        bus.close()
        daemon.send_signal(signal.SIGTERM)
        daemon.wait(timeout=20)
        os.close(master)
        os.close(slave)
    lat_ms = sorted((rx[i] - sent[i]) / 1e6 for i in sent if i in rx)
    lost = len(sent) - len(lat_ms)
    if not lat_ms:
        print("no marks received", file=sys.stderr)
        return 1
    p = statistics.quantiles(lat_ms, n=100)
    print(f"marks sent {len(sent)}, received {len(lat_ms)}, lost {lost}")
    print(f"latency ms: p50 {p[49]:.2f}  p90 {p[89]:.2f}  p99 {p[98]:.2f}  max {lat_ms[-1]:.2f}  "
          f"min {lat_ms[0]:.2f}")
    return 0 if lost == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
