"""How late the demo's live positions come: from the rover epoch's reception by the daemon to
the ``rtk`` message's arrival at a subscriber on the same machine.

Run: python benchmarks/bench_live_latency.py [--flight S] [--speed N] [--no-dashboard]

``groundstation demo`` (default profile) runs as a process on its own Zenoh endpoint, with the
dashboard (a process connected to it, and headless Chromium showing its page when installed)
unless ``--no-dashboard``. A subscriber counts every ``groundstation/demo/rtk`` message: its
latency is the arrival time minus the message's ``rx_host_ns`` (one host clock). Printed:
messages against the rover epochs, the latency's min, median, p95, p99 and max, and the fixed
share of the last 60 s of flight.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from groundstation.bus import Bus, decode, key
from groundstation.config import ZenohSettings

REPO = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flight", type=float, default=300.0)
    ap.add_argument("--speed", default="2")
    ap.add_argument("--no-dashboard", action="store_true")
    a = ap.parse_args()
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    env = {**os.environ, "PYTHONPATH": str(REPO), "GROUNDSTATION_ZENOH_LISTEN": endpoint}
    got: list[tuple[int, dict[str, object]]] = []
    lock = threading.Lock()

    def on(_k: str, payload: bytes) -> None:
        now = time.time_ns()
        with lock:
            got.append((now, decode(payload)))

    bus = Bus(ZenohSettings(mode="peer", listen=(), connect=(endpoint,)))
    bus.subscribe(key("demo", "rtk"), on)
    extra: list[subprocess.Popen[bytes]] = []
    with tempfile.TemporaryDirectory() as tmp:
        demo = subprocess.Popen(
            [sys.executable, "-m", "groundstation.cli", "-q", "demo", "--flight", str(a.flight),
             "--speed", a.speed, "--no-view", "--out-dir", f"{tmp}/flights"],
            cwd=tmp, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        if not a.no_dashboard:
            port = _free_port()
            extra.append(subprocess.Popen(
                [sys.executable, "-m", "groundstation.cli", "-q", "dashboard", "--station", "demo",
                 "--port", str(port), "--connect", endpoint], cwd=tmp, env=env,
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            chromium = shutil.which("chromium") or shutil.which("chromium-browser")
            if chromium:
                time.sleep(3)
                extra.append(subprocess.Popen(
                    [chromium, "--headless", "--no-sandbox", "--disable-gpu",
                     f"--user-data-dir={tmp}/chr", "--remote-debugging-port=0",
                     f"http://127.0.0.1:{port}/"], stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL))
        out, _ = demo.communicate(timeout=a.flight * 3 + 120)
        for p in extra:
            p.terminate()
            p.wait(timeout=20)
    bus.close()
    summary = out.decode(errors="replace")
    epochs = next((ln for ln in summary.splitlines() if "link:" in ln), "").strip()
    with lock:
        items = list(got)
    lat = np.array([(t - int(m["rx_host_ns"])) / 1e6 for t, m in items  # type: ignore[call-overload]
                    if isinstance(m.get("rx_host_ns"), int)])
    last = [m["quality"] for _, m in items][-300:]
    shown = "off" if a.no_dashboard else "on" + (" + headless Chromium" if len(extra) > 1 else "")
    print(f"demo {a.flight:g} s at x{a.speed}, dashboard {shown}")
    print(f"rtk messages {len(items)}; {epochs}")
    if lat.size:
        p95, p99 = np.percentile(lat, 95), np.percentile(lat, 99)
        print(f"epoch reception -> rtk message received, ms: min {lat.min():.1f} median "
              f"{np.median(lat):.1f} p95 {p95:.1f} p99 {p99:.1f} max {lat.max():.1f}")
    if last:
        print(f"fixed in the last 60 s: {sum(q == 'fix' for q in last) / len(last):.1%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
