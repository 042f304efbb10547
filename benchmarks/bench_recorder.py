"""The recorder's synchronous path alone: the MCAP writer, and the session recorder, on the records
of a real capture (what the whole-pipeline file ingest of ``bench_ingest.py`` spends there).

Usage::

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_recorder.py [--mb 5] [--runs 5]

The capture (the LEA-6T ``6P-raw-PPP.ubx`` repeated to ``--mb``) is framed and decoded once, in
4 KiB chunks; then, best of ``--runs`` (CPU time of this thread):

1. ``McapFileWriter`` (zstd, 64 KiB chunks): the raw chunks and the records' JSON as messages.
2. ``SessionRecorder``: ``write_raw`` / ``write_record`` for every item (JSON encoding, publish
   time, LocationFix, sidecar, MCAP), then ``close``; and the same through ``write_items`` in
   bursts of 200 items, as the recorder sink hands them over.

Put the tree under test first on the path: the script imports ``groundstation`` from there.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from groundstation import jsonio
from groundstation.records import Frame, RawChunk, UndecodedFrame
from groundstation.storage.mcapio import ChannelSpec, McapFileWriter
from groundstation.storage.session import SessionRecorder
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real" / "tridge__pyUblox" / "data" / "6P-raw-PPP.ubx"
LINK_NS_PER_BYTE = 86_806  # 115 200 baud, 8N1


def items_of(megabytes: float) -> list[Any]:
    """Raw chunks and decoded records, in pipeline order."""
    data = REAL.read_bytes()
    blob = data * max(1, int(megabytes * 1e6 / len(data)))
    framer, decoder = UbxFramer(), Decoder()
    items: list[Any] = []
    t = 1_700_000_000_000_000_000
    for i in range(0, len(blob), 4096):
        chunk = blob[i:i + 4096]
        t += len(chunk) * LINK_NS_PER_BYTE
        items.append(RawChunk(chunk, t))
        for frame in framer.feed(chunk, t):
            record = decoder.decode(frame)
            if not isinstance(record, (Frame, UndecodedFrame)):
                items.append(record)
    return items


def bench_writer(items: list[Any], runs: int) -> float:
    raw, js = ChannelSpec("/ubx/raw", "ubx"), ChannelSpec("/records", "json")
    msgs = [(raw, it.data) if type(it) is RawChunk else (js, jsonio.dumps(it)) for it in items]
    best = float("inf")
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as tmp:
            w = McapFileWriter(Path(tmp) / "a.mcap")
            t0 = time.thread_time()
            for i, (spec, data) in enumerate(msgs):
                w.add(spec, data, i, i)
            w.finish()
            best = min(best, time.thread_time() - t0)
    return best


def bench_session(items: list[Any], runs: int, burst: int = 0) -> float:
    """Best CPU time of a session over ``items``: item by item, or in bursts of ``burst``."""
    bursts = [items[i:i + burst] for i in range(0, len(items), burst)] if burst else []
    best = float("inf")
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as tmp:
            rec = SessionRecorder(Path(tmp), "bench")
            rec.open()
            t0 = time.thread_time()
            if burst:
                for part in bursts:
                    i = 0
                    while i < len(part):
                        i = rec.write_items(part, i, time.time_ns, rec.file_count)
            else:
                for it in items:
                    if type(it) is RawChunk:
                        rec.write_raw(it.data, it.t_host_ns)
                    else:
                        rec.write_record(it, getattr(it, "t_host_ns", 0) or 1)
            rec.close()
            best = min(best, time.thread_time() - t0)
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--mb", type=float, default=5.0, help="size of the stream")
    parser.add_argument("--runs", type=int, default=5, help="best of this many runs")
    args = parser.parse_args()
    if not REAL.exists():
        print(f"needs the real capture {REAL} (../shared/data)", file=sys.stderr)
        return 1
    items = items_of(args.mb)
    records = sum(1 for it in items if type(it) is not RawChunk)
    print(f"# {len(items) - records} raw chunks, {records} records; load average "
          f"{os.getloadavg()[0]:.2f}")
    print(f"MCAP writer: {bench_writer(items, args.runs):.3f} s CPU (best of {args.runs})")
    print(f"session recorder: {bench_session(items, args.runs):.3f} s CPU (best of {args.runs})")
    print(f"session recorder, bursts of 200: {bench_session(items, args.runs, 200):.3f} s CPU "
          f"(best of {args.runs})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
