"""Ingest benchmarks: daemon CPU at a sustained 115200-baud pty stream, and max file ingest rate.

Usage::

    .venv/bin/python benchmarks/bench_ingest.py [--seconds 20] [--file-mb 20] [--file-only]

Run it with the tree under test first on the path (``PYTHONPATH=$PWD``): the in-process part
imports ``groundstation`` from there.

1. ``groundstation run`` as a real process on a pty, fed at 11520 B/s (115200 baud, 8N1) with
   a real LEA-6T capture (or a generated stream when ../shared/data is absent); CPU use =
   process CPU time (user + system, from /proc) / wall time over the feeding window.
2. The whole pipeline (``run_daemon``: file source -> framer -> decoder -> fanout -> recorder
   with MCAP + sidecar, monitor, Zenoh publisher) in process, from a file as fast as possible:
   MB/s and frames/s, process CPU and the event-loop thread's CPU.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path

from groundstation.config import FileSourceSettings, RecorderSettings, Settings
from groundstation.live.daemon import run_daemon
from groundstation.ubx.build import build_frame

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real" / "tridge__pyUblox" / "data" / "6P-raw-PPP.ubx"


def stream_bytes() -> tuple[bytes, str]:
    if REAL.exists():
        return REAL.read_bytes(), f"real capture {REAL.name}"
    out = bytearray()
    for i in range(2000):
        out += build_frame(0x02, 0x10, bytes(8 + 24 * (i % 10)))
    return bytes(out), "generated RXM-RAW frames"


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    utime, stime = int(fields[11]), int(fields[12])
    return (utime + stime) / os.sysconf("SC_CLK_TCK")


def wakeups(pid: int, tid: int | None = None) -> int:
    """Voluntary context switches of one thread (default: the process's main thread, the
    event loop): how often it went to sleep and was woken (each costs far more CPU on a busy
    machine than the work it wakes for)."""
    for line in Path(f"/proc/{pid}/task/{tid or pid}/status").read_text().splitlines():
        if line.startswith("voluntary_ctxt_switches"):
            return int(line.split()[1])
    return 0


def thread_cpu(pid: int) -> dict[int, float]:
    """CPU seconds of each thread of ``pid`` (the serial reader thread is one of them)."""
    out: dict[int, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # a thread that just ended
        out[int(task.name)] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return out


def bench_serial(seconds: float, data: bytes) -> dict[str, float]:
    rate = 11520.0
    with tempfile.TemporaryDirectory() as tmp:
        master, slave = os.openpty()
        tty.setraw(slave)
        proc = subprocess.Popen(
            [sys.executable, "-m", "groundstation.cli", "-q", "run", "--port",
             os.ttyname(slave), "--out-dir", tmp, "--station", "bench"],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        time.sleep(2.0)  # imports and port open
        cpu0, t0, w0 = cpu_seconds(proc.pid), time.monotonic(), wakeups(proc.pid)
        threads0 = thread_cpu(proc.pid)
        sent = 0
        piece = 64
        while (now := time.monotonic()) - t0 < seconds:
            due = int((now - t0) * rate)
            while sent < due:
                chunk = data[sent % len(data) : sent % len(data) + min(piece, due - sent)]
                sent += os.write(master, chunk)
            time.sleep(0.005)
        cpu1, t1, w1 = cpu_seconds(proc.pid), time.monotonic(), wakeups(proc.pid)
        threads1 = thread_cpu(proc.pid)
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=30)
        os.close(master)
        os.close(slave)
        ubx = next(Path(tmp).glob("*.ubx")).stat().st_size
    return {"wall_s": t1 - t0, "cpu_s": cpu1 - cpu0, "cpu_pct": 100 * (cpu1 - cpu0) / (t1 - t0),
            "bytes_sent": sent, "bytes_recorded": ubx, "exit": rc,
            "wakeups_per_s": (w1 - w0) / (t1 - t0),
            "main_thread_pct": 100 * (threads1.get(proc.pid, 0.0) - threads0.get(proc.pid, 0.0))
            / (t1 - t0),
            "busiest_other_thread_pct": 100 * max(
                (c - threads0.get(tid, 0.0) for tid, c in threads1.items() if tid != proc.pid),
                default=0.0) / (t1 - t0)}


def bench_file(megabytes: float, data: bytes) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "in.ubx"
        reps = max(1, int(megabytes * 1e6 / len(data)))
        src.write_bytes(data * reps)
        settings = Settings(
            source=FileSourceSettings(path=src, read_size_bytes=4096), station="bench",
            recorder=RecorderSettings(out_dir=Path(tmp) / "out"),
        )
        cpu0, t0, main0 = time.process_time(), time.perf_counter(), time.thread_time()
        summary = asyncio.run(run_daemon(settings))
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        main = time.thread_time() - main0
    return {"bytes": summary.bytes_in, "frames": summary.frames, "records": summary.records,
            "wall_s": wall, "cpu_s": cpu, "main_thread_cpu_s": main,
            "mb_per_s": summary.bytes_in / 1e6 / wall, "frames_per_s": summary.frames / wall}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="serial feeding time")
    parser.add_argument("--file-mb", type=float, default=20.0, help="size of the file test")
    parser.add_argument("--file-only", action="store_true", help="skip the serial part")
    args = parser.parse_args()
    data, what = stream_bytes()
    print(f"# host: {platform.machine()} {platform.python_implementation()} "
          f"{platform.python_version()}, {os.cpu_count()} CPUs; stream: {what}")
    if not args.file_only:
        serial_part(args.seconds, data)
    f = bench_file(args.file_mb, data)
    print(f"file max rate: {f['mb_per_s']:.2f} MB/s, {f['frames_per_s']:.0f} frames/s "
          f"({int(f['bytes'])} bytes, {int(f['frames'])} frames, {int(f['records'])} records "
          f"in {f['wall_s']:.1f} s, {f['cpu_s']:.2f} s CPU, of it {f['main_thread_cpu_s']:.2f} s "
          f"on the event-loop thread); load average {os.getloadavg()[0]:.2f}")
    return 0


def serial_part(seconds: float, data: bytes) -> None:
    s = bench_serial(seconds, data)
    print(f"serial 115200 baud: {s['cpu_pct']:.1f} % CPU ({s['cpu_s']:.2f} s CPU over "
          f"{s['wall_s']:.1f} s wall, {s['wakeups_per_s']:.0f} wake-ups/s of the event loop; "
          f"event loop thread {s['main_thread_pct']:.1f} %, busiest other thread (the serial "
          f"reader) {s['busiest_other_thread_pct']:.1f} %), "
          f"{int(s['bytes_sent'])} bytes sent, "
          f"{int(s['bytes_recorded'])} recorded, exit {int(s['exit'])}")


if __name__ == "__main__":
    sys.exit(main())
