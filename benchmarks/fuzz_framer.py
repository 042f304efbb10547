"""Seeded fuzz run of the framer and the decoder: no exception may escape, invariants must hold.

Run: python benchmarks/fuzz_framer.py [--cases 100000] [--seed 1] [--sim-s 120]

Seeds are simulated LEA-6T frames (RXM-RAW, RXM-SFRB, TIM-TM2, NAV-SOL, NAV-SVINFO from
``groundstation.sim``), frames of every type the decoder maps built with random payloads of
random lengths (valid checksums, so they reach pyubx2 and the record mappers), NMEA and RTCM3.
Each case is one of:

- ``random``: random bytes, fed in random chunks;
- ``mutated``: seed frames with bit flips, byte changes, insertions and deletions, checksum left
  broken (the framer must reject and resynchronise) or recomputed (the decoder gets damage that
  passed the checksum);
- ``truncated``: a frame cut anywhere, then intact frames, which must all be recovered (unless
  the cut frame's claimed span happens to pass its 8-bit checksum, about 1 in 65 536 random
  spans: then every frame starting after that span must be; such coincidences are counted);
- ``chunking``: an intact stream with damage fed in random chunkings, which must give exactly
  the frames of feeding it in one piece;
- ``payload``: a decoded message type with a random payload of random length.

Checked on every case: nothing raises (the decoder returns a record or an ``UndecodedFrame``,
never an exception, in its daemon mode), the framer accounts for every byte (frames + garbage +
NMEA + RTCM3 = bytes in, nothing pending after flush), every frame it returns has a valid
checksum, and the case-specific invariants above. Exits 1 and prints the first failing case
(seed and index, so it replays) if any check fails.
"""

from __future__ import annotations

import argparse
import logging
import random
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from groundstation.records import Frame, UndecodedFrame
from groundstation.sim.stream import SimConfig, simulate
from groundstation.ubx.build import build_frame
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer, ubx_checksum

DECODED_TYPES = [
    (0x02, 0x10), (0x02, 0x11), (0x02, 0x13), (0x02, 0x15), (0x0D, 0x03), (0x0B, 0x31),
    (0x01, 0x02), (0x01, 0x06), (0x01, 0x07), (0x01, 0x30), (0x01, 0x35),
]
NMEA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
RTCM3 = bytes.fromhex("d300133ed7d30202980edeef34b4bd62ac0941986f33360b98")


class CaseFailed(Exception):
    """An invariant did not hold."""


@dataclass(frozen=True, slots=True)
class Outcome:
    frames: int
    records: int
    undecodable: int
    garbage_bytes: int


def chunked(data: bytes, rng: random.Random) -> list[bytes]:
    """``data`` cut at random places (from single bytes to the whole)."""
    out = []
    i = 0
    while i < len(data):
        n = rng.choice((1, 2, 7, rng.randint(1, 64), rng.randint(1, 4096)))
        out.append(data[i : i + n])
        i += n
    return out


def run_stream(pieces: list[bytes], decoder: Decoder) -> tuple[list[Frame], Outcome]:
    """Frame and decode ``pieces``; check the framer's accounting and every frame's checksum."""
    framer = UbxFramer()
    frames: list[Frame] = []
    for k, piece in enumerate(pieces):
        frames += framer.feed(piece, k)
    frames += framer.flush(len(pieces))
    s = framer.stats
    total = sum(map(len, pieces))
    if s.bytes_in != total or s.pending_bytes != 0:
        raise CaseFailed(f"bytes_in {s.bytes_in} != {total} or {s.pending_bytes} pending")
    accounted = s.frame_bytes + s.garbage_bytes + s.nmea_bytes + s.rtcm3_bytes
    if accounted != total:
        raise CaseFailed(f"{accounted} bytes accounted for, {total} fed")
    records = undecodable = 0
    for f in frames:
        if f.raw[:2] != b"\xb5\x62" or ubx_checksum(f.raw[2:-2]) != (f.raw[-2], f.raw[-1]):
            raise CaseFailed(f"frame with a bad checksum returned: {f.raw[:16].hex()}")
        rec = decoder.decode(f)
        if isinstance(rec, UndecodedFrame):
            undecodable += 1
        elif not isinstance(rec, Frame):
            records += 1
    return frames, Outcome(len(frames), records, undecodable, s.garbage_bytes)


def mutate(frame: bytes, rng: random.Random) -> bytes:
    b = bytearray(frame)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(4)
        if op == 0 and b:
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1 and b:
            b[rng.randrange(len(b))] = rng.randrange(256)
        elif op == 2:
            b[rng.randint(0, len(b)) : rng.randint(0, len(b))] = rng.randbytes(rng.randint(1, 8))
        elif b:
            i = rng.randrange(len(b))
            del b[i : i + rng.randint(1, 8)]
    return bytes(b)


def refresh_checksum(frame: bytes) -> bytes:
    """Make a damaged frame valid again (length field from the payload actually there)."""
    if len(frame) < 8:
        return frame
    return build_frame(frame[2], frame[3], frame[6:-2])


class Fuzzer:
    def __init__(self, seed: int, sim_s: float) -> None:
        self.rng = random.Random(seed)
        sim = simulate(SimConfig(duration_s=sim_s, seed=seed, with_base=False))
        self.seeds = [m.raw for m in sim.rover_messages]
        self.seed_types = Counter((f[2], f[3]) for f in self.seeds)
        self.decoder = Decoder()
        self.counts: Counter[str] = Counter()
        self.frames = self.records = self.undecodable = 0
        self.coincidences = 0

    def intact(self, n: int) -> list[bytes]:
        k = self.rng.randrange(len(self.seeds) - n)
        return self.seeds[k : k + n]

    def case_random(self) -> None:
        data = self.rng.randbytes(self.rng.randint(0, 2000))
        self._tally(run_stream(chunked(data, self.rng), self.decoder)[1])

    def case_mutated(self) -> None:
        frames = [mutate(f, self.rng) for f in self.intact(self.rng.randint(1, 5))]
        if self.rng.random() < 0.5:
            frames = [refresh_checksum(f) for f in frames]
        self._tally(run_stream(chunked(b"".join(frames), self.rng), self.decoder)[1])

    def case_truncated(self) -> None:
        cut, *after = self.intact(self.rng.randint(2, 6))
        head = cut[: self.rng.randrange(len(cut))]
        got, out = run_stream(chunked(head + b"".join(after), self.rng), self.decoder)
        expected = after
        if got and head and got[0].offset == 0:
            # The cut frame's header was intact and the bytes that followed happened to give
            # its claimed length a valid checksum: an 8-bit Fletcher checksum passes about one
            # random span in 65 536. Such a frame is valid by the protocol; the frames that
            # start after it must still all be recovered.
            if not got[0].raw.startswith(head):
                raise CaseFailed("a frame at the cut frame's offset that is not its start")
            self.coincidences += 1
            end = len(got[0].raw) - len(head)
            starts = [sum(map(len, after[:k])) for k in range(len(after))]
            expected = [f for f, s in zip(after, starts, strict=True) if s >= end]
        tail = [f.raw for f in got[len(got) - len(expected) :]] if expected else []
        if tail != expected:
            raise CaseFailed(
                f"frames after a cut lost: {len(expected)} expected, {out.frames} framed; cut "
                f"{cut[2]:02X}-{cut[3]:02X} at {len(head)} of {len(cut)}: {head.hex()} | "
                + " ".join(f.hex() for f in after) + " -> " + " ".join(f.raw.hex() for f in got)
            )
        self._tally(out)

    def case_chunking(self) -> None:
        parts = []
        for f in self.intact(self.rng.randint(3, 12)):
            r = self.rng.random()
            parts.append(mutate(f, self.rng) if r < 0.2 else f[: len(f) // 2] if r < 0.3 else f)
            if self.rng.random() < 0.1:
                parts.append(self.rng.choice((NMEA, RTCM3, self.rng.randbytes(9))))
        data = b"".join(parts)
        whole, _ = run_stream([data], Decoder())
        got, out = run_stream(chunked(data, self.rng), self.decoder)
        if [f.raw for f in got] != [f.raw for f in whole]:
            raise CaseFailed("a chunking changed the frames")
        self._tally(out)

    def case_payload(self) -> None:
        cls, mid = self.rng.choice(DECODED_TYPES)
        n = self.rng.choice((0, 1, 7, 8, 16, 24, 28, 36, 40, 52, 92, self.rng.randint(0, 600)))
        frame = build_frame(cls, mid, self.rng.randbytes(n))
        self._tally(run_stream(chunked(frame, self.rng), self.decoder)[1])

    def _tally(self, out: Outcome) -> None:
        self.frames += out.frames
        self.records += out.records
        self.undecodable += out.undecodable

    def run(self, cases: int, seed: int) -> int:
        kinds: list[tuple[str, Callable[[], None], float]] = [
            ("random", self.case_random, 0.2),
            ("mutated", self.case_mutated, 0.3),
            ("truncated", self.case_truncated, 0.15),
            ("chunking", self.case_chunking, 0.15),
            ("payload", self.case_payload, 0.2),
        ]
        names = [k[0] for k in kinds]
        weights = [k[2] for k in kinds]
        fns = {k[0]: k[1] for k in kinds}
        for i in range(cases):
            kind = self.rng.choices(names, weights)[0]
            try:
                fns[kind]()
            except Exception:  # anything escaping is the finding
                print(f"case {i} ({kind}, seed {seed}) failed:", file=sys.stderr)
                traceback.print_exc()
                return 1
            self.counts[kind] += 1
        return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--sim-s", type=float, default=120.0, help="simulated seconds of seeds")
    args = ap.parse_args(argv)
    # Damage makes the decoder log a warning per undecodable frame: count them, do not print.
    logging.getLogger("groundstation").setLevel(logging.ERROR)
    fuzz = Fuzzer(args.seed, args.sim_s)
    t0 = time.perf_counter()
    rc = fuzz.run(args.cases, args.seed)
    dt = time.perf_counter() - t0
    done = sum(fuzz.counts.values())
    types = ", ".join(f"{c:02X}-{i:02X} x{n}" for (c, i), n in sorted(fuzz.seed_types.items()))
    print(f"seed frames: {len(fuzz.seeds)} ({types})")
    print(f"cases: {done} in {dt:.1f} s = {done / dt:.0f} cases/s; "
          + ", ".join(f"{k} {n}" for k, n in sorted(fuzz.counts.items())))
    ds = fuzz.decoder.stats
    print(f"frames out of the framer: {fuzz.frames}; records: {fuzz.records}; undecodable "
          f"(returned as UndecodedFrame, not raised): {fuzz.undecodable}; passed through: "
          f"{ds.passed_through}")
    print(f"truncated cases where the cut frame's claimed span passed its checksum by chance: "
          f"{fuzz.coincidences}")
    print("undecodable by type: " + ", ".join(
        f"{k} {n}" for k, n in sorted(ds.undecodable_by_type.items())))
    print("exceptions escaped: 0" if rc == 0 else "FAILED")
    return rc


if __name__ == "__main__":
    sys.exit(main())
