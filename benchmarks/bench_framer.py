"""Framer and framer+decoder throughput on the largest real recording, against pyubx2.

Run: python benchmarks/bench_framer.py [PATH]
The reference is pyubx2's own UBXReader (framing + parsing every UBX message) on the same bytes in
the same process, so the ratio holds across machines. Times are CPU time of this process (the
machine is shared; wall time would count the other processes' turns), best of N.

Run: python benchmarks/bench_framer.py --ingest [MB]
The live path's share of ``bench_ingest.py --file-only``: the same input (the LEA-6T capture
repeated to MB megabytes, default 5) fed to :class:`UbxFramer` in the file source's 4096-byte
reads and in 64-byte serial reads, framer alone and framer + :class:`Decoder`, as the daemon's
``_decode`` does per chunk. Compare two trees by running it with each first on ``PYTHONPATH``,
back to back.
"""

from __future__ import annotations

import gzip
import io
import os
import sys
import time
from pathlib import Path

from pyubx2 import UBXReader

from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

DEFAULT = (
    Path(__file__).resolve().parents[2]
    / "shared/data/real/jdesbonnet__GNSS_RTK_data/20181104/rover-20181104-1634.ubx.gz"
)
CHUNK = 4096  # what a serial read returns at most, roughly
INGEST = DEFAULT.parents[2] / "tridge__pyUblox/data/6P-raw-PPP.ubx"


def load(path: Path) -> bytes:
    return gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()


def best_of(n: int, fn: object) -> float:
    times = []
    for _ in range(n):
        t0 = time.process_time()
        fn()  # type: ignore[operator]
        times.append(time.process_time() - t0)
    return min(times)


def ingest(megabytes: float) -> int:
    """CPU of the framer (+ decoder) per chunk on bench_ingest's input, 4096- and 64-byte reads."""
    if not INGEST.exists():
        print(f"input not found: {INGEST}", file=sys.stderr)
        return 2
    one = INGEST.read_bytes()
    data = one * max(1, int(megabytes * 1e6 / len(one)))
    mb = len(data) / 1e6

    def run(chunk: int, decode: bool) -> int:
        framer = UbxFramer()
        decoder = Decoder()
        n = 0
        for i in range(0, len(data), chunk):
            frames = framer.feed(data[i : i + chunk], i)
            n += len(frames)
            if decode:
                for f in frames:
                    decoder.decode(f)
        return n

    print(f"input: {INGEST.name} x{len(data) // len(one)}, {mb:.2f} MB, "
          f"{run(1 << 20, False)} UBX frames; CPU s per 5 MB, best of 5")
    for chunk in (4096, 64):
        t_frame = best_of(5, lambda chunk=chunk: run(chunk, False)) * 5 / mb
        t_both = best_of(5, lambda chunk=chunk: run(chunk, True)) * 5 / mb
        print(f"{chunk:5d}-byte reads: framer {t_frame:6.3f} s, framer + decoder {t_both:6.3f} s "
              f"(decoder {t_both - t_frame:6.3f} s)")
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--ingest":
        return ingest(float(sys.argv[2]) if len(sys.argv) > 2 else 5.0)
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT
    if not path.exists():
        print(f"input not found: {path} (pass a .ubx or .ubx.gz)", file=sys.stderr)
        return 2
    data = load(path)
    mb = len(data) / 1e6
    n_frames = 0

    def frame_only() -> None:
        nonlocal n_frames
        framer = UbxFramer()
        n = 0
        for i in range(0, len(data), CHUNK):
            n += len(framer.feed(data[i : i + CHUNK], i))
        n += len(framer.flush())
        n_frames = n

    def frame_and_decode() -> None:
        framer = UbxFramer()
        decoder = Decoder()
        for i in range(0, len(data), CHUNK):
            for f in framer.feed(data[i : i + CHUNK], i):
                decoder.decode(f)
        for f in framer.flush():
            decoder.decode(f)

    def bulk_index() -> None:
        from groundstation.ubx.fastraw import index_frames

        index_frames(data)

    def pyubx2_reader() -> None:
        for _ in UBXReader(io.BytesIO(data), protfilter=2, quitonerror=0):
            pass

    t_frame = best_of(5, frame_only)
    t_decode = best_of(3, frame_and_decode)
    t_index = best_of(5, bulk_index)
    t_ref = best_of(2, pyubx2_reader)
    print(f"input: {path.name}, {mb:.2f} MB, {n_frames} UBX frames")
    for label, t in (("framer only", t_frame), ("framer + decoder", t_decode),
                     ("bulk frame index", t_index), ("pyubx2 UBXReader", t_ref)):
        print(f"{label:<18} {t:7.3f} s  {n_frames / t:10.0f} frames/s  {mb / t:7.1f} MB/s")
    print(f"ratio framer+decoder / pyubx2 = {t_decode / t_ref:.2f} (lower is faster)")
    print(f"ratio framer only / pyubx2    = {t_frame / t_ref:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
