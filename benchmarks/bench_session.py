"""A 10-hour simulated session through the whole live pipeline at maximum speed: memory growth.

Run: python benchmarks/bench_session.py [--hours 10] [--dropout-every-s 120] [--out DIR]

One hour of a simulated LEA-6T flight (``groundstation.sim``: RXM-RAW 5 Hz, RXM-SFRB, NAV-SOL,
NAV-SVINFO, TIM-TM2 time marks) is generated once and repeated with every GPS time (and mark
count) shifted by the hours already played, so the monitor sees one continuous session. Link
dropouts (0.4-3 s without bytes, one every ``--dropout-every-s`` on average, seeded) are cut out
of the stream as the radio would. The bytes flow through :class:`Pipeline` with everything a
field session runs: framer, decoder, the recorder (MCAP + sidecar, flushed every 0.5 s),
the monitor (1 Hz status, alerts) and the Zenoh publisher (a real session on loopback).

Time is the data's time: the source stamps each chunk with its simulated host receive time and
the pipeline's clock follows it, so flushes, status snapshots, alert timers and rate windows
happen as often as in a real 10-hour session, only faster. Resident memory (``VmRSS`` from
``/proc/self/status``) is sampled after a warm-up (the first simulated ``--warmup-min``
minutes: imports, caches, the Zenoh session, the first MCAP chunks) and then every simulated
10 minutes. Exit status 1 if the growth from the warm-up to the end exceeds ``--limit-mb``.
"""

from __future__ import annotations

import argparse
import asyncio
import random
import shutil
import struct
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path

from groundstation import gpstime
from groundstation.config import load_settings
from groundstation.live.daemon import Pipeline
from groundstation.sim.stream import SimConfig, simulate
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # peers
from peers import free_port  # noqa: E402

MS_PER_WEEK = 604_800_000
LATENCY_NS = 40_000_000  # UART + radio, as the simulator's output latency
READ_NS = 100_000_000  # one serial read per 100 ms of bytes


def rss_kb() -> int:
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS in /proc/self/status")


def _shift_tow(payload: bytearray, tow_off: int, week_off: int | None, shift_ms: int) -> None:
    tow = struct.unpack_from("<I", payload, tow_off)[0]
    week = struct.unpack_from("<H", payload, week_off)[0] if week_off is not None else 0
    week2, tow2 = divmod(week * MS_PER_WEEK + tow + shift_ms, MS_PER_WEEK)
    struct.pack_into("<I", payload, tow_off, tow2)
    if week_off is not None:
        struct.pack_into("<H", payload, week_off, week2)


def shifted(raw: bytes, shift_ms: int, count_shift: int) -> bytes:
    """A frame with its GPS times moved by ``shift_ms`` (and a mark's count by
    ``count_shift``), checksum recomputed. Subframes (RXM-SFRB) are left as they are."""
    cls, mid = raw[2], raw[3]
    p = bytearray(raw[6:-2])
    raw_o, sol_o, tm2_o = L.RXM_RAW.offsets, L.NAV_SOL.offsets, L.TIM_TM2.offsets
    if (cls, mid) == L.RXM_RAW.key:
        _shift_tow(p, raw_o["iTOW"], raw_o["week"], shift_ms)
    elif (cls, mid) == L.NAV_SOL.key:
        _shift_tow(p, sol_o["iTOW"], sol_o["week"], shift_ms)
    elif (cls, mid) == L.NAV_SVINFO.key:
        tow = struct.unpack_from("<I", p, L.NAV_SVINFO.offsets["iTOW"])[0]
        struct.pack_into("<I", p, L.NAV_SVINFO.offsets["iTOW"], (tow + shift_ms) % MS_PER_WEEK)
    elif (cls, mid) == L.TIM_TM2.key:
        count = struct.unpack_from("<H", p, tm2_o["count"])[0]
        struct.pack_into("<H", p, tm2_o["count"], (count + count_shift) & 0xFFFF)
        if struct.unpack_from("<H", p, tm2_o["wnR"])[0]:
            _shift_tow(p, tm2_o["towMsR"], tm2_o["wnR"], shift_ms)
        _shift_tow(p, tm2_o["towMsF"], tm2_o["wnF"], shift_ms)
    else:
        return raw
    return build_frame(cls, mid, bytes(p))


class SessionSource:
    """The repeated hour as a radio would deliver it: chunks every 100 ms, holes cut out."""

    name = "sim:10h"
    can_wait = True  # as fast as the sinks take it (the recorder never drops)

    def __init__(self, frames: list[tuple[int, bytes]], hours: int, dropout_every_s: float,
                 seed: int, marks_per_hour: int) -> None:
        self.frames = frames
        self.hours = hours
        self.rng = random.Random(seed)
        self.dropout_every_s = dropout_every_s
        self.marks_per_hour = marks_per_hour
        self.now_ns = gpstime.gps_to_unix_ns(frames[0][0])
        self.bytes = 0
        self.chunks_out = 0
        self.dropouts = 0
        self.hour_done = -1

    def clock(self) -> int:
        return self.now_ns

    async def chunks(self) -> AsyncIterator[tuple[bytes, int]]:
        span_ns = 3600 * gpstime.NS_PER_S
        hole_until = 0
        next_hole = self._next_hole(self.frames[0][0])
        for h in range(self.hours):
            buf = bytearray()
            buf_due = 0
            for t_gps, raw in self.frames:
                t = t_gps + h * span_ns
                if t >= next_hole:
                    hole_until = t + self.rng.randint(400, 3000) * 1_000_000
                    next_hole = self._next_hole(hole_until)
                    self.dropouts += 1
                if t < hole_until:
                    continue
                frame = shifted(raw, h * 3_600_000, h * self.marks_per_hour) if h else raw
                host = gpstime.gps_to_unix_ns(t) + LATENCY_NS
                if buf and host >= buf_due:
                    yield await self._out(bytes(buf), buf_due)
                    buf.clear()
                if not buf:
                    buf_due = host + READ_NS
                buf += frame
            if buf:
                yield await self._out(bytes(buf), buf_due)
            self.hour_done = h

    def _next_hole(self, after_ns: int) -> int:
        return after_ns + int(self.rng.expovariate(1 / self.dropout_every_s) * 1e9)

    async def _out(self, chunk: bytes, host_ns: int) -> tuple[bytes, int]:
        self.now_ns = host_ns
        self.bytes += len(chunk)
        self.chunks_out += 1
        await asyncio.sleep(0)
        return chunk, host_ns


async def run(args: argparse.Namespace, out_dir: Path) -> int:
    t0 = time.perf_counter()
    sim = simulate(SimConfig(duration_s=3600, seed=args.seed, with_base=False))
    frames = [(m.t_gps_ns, m.raw) for m in sim.rover_messages]
    marks = sum(1 for m in sim.rover_messages if m.name == "TIM-TM2")
    del sim
    print(f"simulated hour: {len(frames)} frames, {marks} TIM-TM2, "
          f"{sum(len(r) for _, r in frames) / 1e6:.2f} MB ({time.perf_counter() - t0:.1f} s)")
    source = SessionSource(frames, args.hours, args.dropout_every_s, args.seed, marks)
    settings = load_settings(environ={}, overrides={
        "source": {"path": "unused.ubx"},
        "station": "bench",
        "recorder": {"out_dir": str(out_dir), "flush_interval_s": 0.5},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
    })
    pipeline = Pipeline(settings, source=source, clock=source.clock, monitor_data_clock=True)
    samples: list[tuple[float, int]] = []  # (simulated hours, RSS kB)
    start_kb = 0
    warm_ns = int(args.warmup_min * 60e9)
    t_start = source.now_ns

    async def sampler() -> None:
        nonlocal start_kb
        next_ns = t_start + warm_ns
        while True:
            await asyncio.sleep(0.05)
            if source.now_ns >= next_ns:
                kb = rss_kb()
                hours = (source.now_ns - t_start) / 3600e9
                if not samples:
                    start_kb = kb
                samples.append((hours, kb))
                if len(samples) % 6 == 1:
                    print(f"  {hours:5.2f} h simulated: RSS {kb / 1024:.1f} MiB "
                          f"({time.perf_counter() - t_run:.0f} s)", flush=True)
                next_ns += 600 * gpstime.NS_PER_S

    t_run = time.perf_counter()
    task = asyncio.create_task(sampler())
    summary = await pipeline.run()
    task.cancel()
    wall = time.perf_counter() - t_run
    end_kb = rss_kb()
    samples.append(((source.now_ns - t_start) / 3600e9, end_kb))
    peak_kb = max(kb for _, kb in samples)
    growth_mb = (end_kb - start_kb) / 1024
    mcap_mb = sum(p.stat().st_size for p in summary.files) / 1e6
    mon = pipeline.monitor.monitor if pipeline.monitor else None
    pub = pipeline.publisher
    print(f"session: {args.hours} h simulated in {wall:.0f} s ({args.hours * 3600 / wall:.0f}x "
          f"real time); {source.bytes / 1e6:.1f} MB in {source.chunks_out} chunks, "
          f"{summary.frames} frames, {summary.records} records, {summary.events} events, "
          f"{source.dropouts} dropouts cut")
    print(f"recording: {len(summary.files)} file(s), {mcap_mb:.1f} MB MCAP; sinks: "
          + ", ".join(f"{q.name} delivered {q.delivered} dropped {q.dropped}"
                      for q in summary.queues))
    if mon is not None:
        print(f"monitor: {mon.epochs} epochs, {mon.link.dropout_count} dropouts measured, "
              f"{mon.marks} marks, {mon.missed} missed, alerts now {sorted(mon.alerts.active)}")
    if pub is not None:
        print(f"publisher: {pub.published} puts, {pub.failed} failed, {len(pub.marks)} marks "
              "held for q/timemarks")
    print(f"RSS after {args.warmup_min:g} min warm-up {start_kb / 1024:.1f} MiB, peak "
          f"{peak_kb / 1024:.1f} MiB, end {end_kb / 1024:.1f} MiB: growth {growth_mb:+.1f} MiB "
          f"(limit {args.limit_mb:g})")
    print("RSS by simulated hour: " + ", ".join(
        f"{h:.1f} h {kb / 1024:.1f}" for h, kb in samples[::6] + samples[-1:]))
    return 0 if growth_mb < args.limit_mb else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=int, default=10)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--dropout-every-s", type=float, default=120.0)
    ap.add_argument("--warmup-min", type=float, default=20.0)
    ap.add_argument("--limit-mb", type=float, default=10.0)
    ap.add_argument("--out", type=Path, help="keep the recording here (default: a temp dir)")
    args = ap.parse_args(argv)
    import logging

    logging.basicConfig(level=logging.WARNING)
    logging.getLogger("groundstation.monitor").setLevel(logging.ERROR)  # dropout alerts
    if args.out is not None:
        return asyncio.run(run(args, args.out))
    tmp = Path(tempfile.mkdtemp(prefix="bench_session_"))
    try:
        return asyncio.run(run(args, tmp))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
