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
- ``payload``: a decoded message type with a random payload of random length, or with the
  right layout and random field values (:func:`random_frame`, also the frames
  ``fuzz_valid_frames.py`` sends through the daemon and the offline tools).

Checked on every case: nothing raises (the decoder returns a record or an ``UndecodedFrame``,
never an exception, in its daemon mode), the framer accounts for every byte (frames + garbage +
NMEA + RTCM3 = bytes in, nothing pending after flush), every frame it returns has a valid
checksum, and the case-specific invariants above. Exits 1 and prints the first failing case
(seed and index, so it replays) if any check fails.
"""

from __future__ import annotations

import argparse
import logging
import math
import random
import struct
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from groundstation.gpstime import NS_PER_WEEK
from groundstation.records import Frame, UndecodedFrame
from groundstation.sim.stream import SimConfig, simulate
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer, ubx_checksum

DECODED_TYPES = sorted(L.MESSAGES)
"""Every message type the decoder maps to a record (the layouts' table)."""
NMEA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
RTCM3 = bytes.fromhex("d300133ed7d30202980edeef34b4bd62ac0941986f33360b98")


class CaseFailed(Exception):
    """An invariant did not hold."""


# -- frames with the right layout and random field values ---------------------------------------

_MAX = {"U1": 0xFF, "X1": 0xFF, "U2": 0xFFFF, "X2": 0xFFFF, "U4": 0xFFFFFFFF, "X4": 0xFFFFFFFF}
_MIN = {"I1": -(1 << 7), "I2": -(1 << 15), "I4": -(1 << 31)}
TIME_FIELDS = frozenset({"iTOW", "towMsR", "towMsF", "rcvTow"})
WEEK_FIELDS = frozenset({"week", "wnR", "wnF"})
SHIFTS_S = (0.2, 1.0, 5.5, 59.0, 61.0, 600.0, 3600.0, 86_400.0, 604_800.0)
"""Time shifts a mutated time field gets: within the session's allowance, at its edge, far."""


@dataclass(frozen=True, slots=True)
class Context:
    """Where in the session a frame is made: the stream's current GPS week and time of week."""

    week: int
    itow_ms: int


def _interesting(ftype: str, rng: random.Random) -> int | float:
    """A value of a u-blox type that breaks decoders: extremes, NaN, infinities, random bits."""
    if ftype in ("R4", "R8"):
        big = 3.0e38 if ftype == "R4" else 1.0e308
        choice = rng.choice(("nan", "inf", "-inf", "big", "-big", "zero", "bits"))
        if choice == "bits":
            size = 4 if ftype == "R4" else 8
            raw = rng.randbytes(size)
            return float(struct.unpack("<f" if size == 4 else "<d", raw)[0])
        return {"nan": math.nan, "inf": math.inf, "-inf": -math.inf, "big": big, "-big": -big,
                "zero": -0.0}[choice]
    lo, hi = _MIN.get(ftype, 0), _MAX.get(ftype, (1 << (8 * int(ftype[1]) - 1)) - 1)
    return rng.choice((lo, hi, 0, 1, hi // 2, hi - 1, rng.randint(lo, hi)))


def _shifted(ftype: str, value: int | float, name: str, rng: random.Random) -> int | float:
    """A time or week field moved by a plausible-looking amount (kept within its type)."""
    sign = rng.choice((-1, 1))
    if name in WEEK_FIELDS:
        out: int | float = int(value) + sign * rng.choice((1, 2, 52, 1024))
    elif name == "rcvTow":
        out = float(value) + sign * rng.choice(SHIFTS_S)
    else:
        out = int(value) + sign * int(rng.choice(SHIFTS_S) * 1000)
    if isinstance(out, int):
        lo, hi = _MIN.get(ftype, 0), _MAX.get(ftype, (1 << (8 * int(ftype[1]) - 1)) - 1)
        out = min(max(out, lo), hi)
    return out


def _plausible(msg: L.Message, rng: random.Random, ctx: Context) -> tuple[dict[str, Any],
                                                                        list[dict[str, Any]]]:
    """Fields a receiver at ``ctx`` could send for ``msg`` (the base that gets mutated)."""
    tow, week = ctx.itow_ms, ctx.week
    n = rng.randint(0, 12)
    name = msg.name
    if name == "RXM-RAW":
        rows = [{"cpMes": rng.uniform(1e8, 1.3e8), "prMes": rng.uniform(2e7, 2.6e7),
                 "doMes": rng.uniform(-4e3, 4e3), "sv": rng.randint(1, 32),
                 "mesQI": rng.randint(4, 7), "cno": rng.randint(25, 50), "lli": rng.randint(0, 3)}
                for _ in range(n)]
        return {"iTOW": tow, "week": week}, rows
    if name == "RXM-RAWX":
        rows = [{"prMes": rng.uniform(2e7, 2.6e7), "cpMes": rng.uniform(1e8, 1.3e8),
                 "doMes": rng.uniform(-4e3, 4e3), "svId": rng.randint(1, 32),
                 "locktime": rng.randint(0, 64500), "cno": rng.randint(25, 50),
                 "cpStdev": rng.randint(0, 15), "trkStat": rng.randint(0, 15)}
                for _ in range(n)]
        return {"rcvTow": tow / 1000, "week": week, "leapS": 18, "recStat": 1,
                "version": 1}, rows
    if name == "TIM-TM2":
        flags = L.TIM_TM2_FLAGS.compose(mode=1, run=1, timeBase=1, time=1, utc=1,
                                        newFallingEdge=rng.randint(0, 1),
                                        newRisingEdge=rng.randint(0, 1))
        fall = max(tow - rng.randint(0, 200), 0)
        return {"ch": 0, "flags": flags, "count": rng.randint(0, 65535), "wnR": week,
                "wnF": week, "towMsF": fall, "towSubMsF": rng.randint(0, 999_999),
                "towMsR": fall + 14, "towSubMsR": rng.randint(0, 999_999), "accEst": 20}, []
    if name == "NAV-SOL":
        return {"iTOW": tow, "fTOW": rng.randint(-500_000, 500_000), "week": week, "gpsFix": 3,
                "flags": 0x0D, "ecefX": 377469655, "ecefY": -59664791, "ecefZ": 508948565,
                "pAcc": 250, "numSV": 8}, []
    if name in ("NAV-PVT", "NAV-POSLLH"):
        extra = {"fixType": 3, "flags": 1} if name == "NAV-PVT" else {}
        return {"iTOW": tow, "lat": 533400000, "lon": -89900000, "height": 50_000,
                "hAcc": 200, "vAcc": 300, **extra}, []
    if name in ("NAV-SVINFO", "NAV-SAT"):
        rows = [{f.name: rng.randint(0, 60) for f in msg.group if not f.is_padding}
                for _ in range(n)]
        return {"iTOW": tow}, rows
    # RXM-SFRB, RXM-SFRBX, AID-EPH: navigation words, random (parity fails, or passes by chance)
    head = {f.name: rng.randint(0, 32) for f in msg.fields if not f.is_padding}
    if name == "RXM-SFRBX":
        head.update(gnssId=0, sigId=0, numWords=10)
    reps = 10 if name != "AID-EPH" else rng.randint(0, 1)
    rows = [{f.name: rng.getrandbits(32) for f in msg.group if not f.is_padding}
            for _ in range(reps)]
    return head, rows


def random_payload(msg: L.Message, rng: random.Random) -> bytes:
    """A payload of ``msg``'s layout whose every field holds random bits (the count field
    matches the repeats, so it passes the length checks and reaches the field checks)."""
    head = bytearray(rng.randbytes(msg.head.size))
    if msg.name == "NAV-PVT" and msg.min_length is not None and rng.random() < 0.2:
        head = head[: msg.min_length]
    reps = 0
    if msg.group:
        if isinstance(msg.count, str):
            reps = rng.randint(0, 16)
            at = msg.offsets[msg.count]
            size = next(f.size for f in msg.fields if f.name == msg.count)
            head[at : at + size] = reps.to_bytes(size, "little")
        elif msg.count == L.BY_SIZE:
            reps = rng.randint(0, 1)
        else:
            reps = int(msg.count or 0)
    return bytes(head) + rng.randbytes(msg.block.size * reps)


def random_frame(key: tuple[int, int], rng: random.Random, ctx: Context) -> bytes:
    """A valid-checksum frame of a decoded type with random field values: every field random
    (a third), or what a receiver at ``ctx`` would send with one to three fields replaced by an
    extreme, NaN, infinite, random or shifted value (a time moved by 0.2 s .. a week)."""
    msg = L.MESSAGES[key]
    if rng.random() < 1 / 3:
        return build_frame(msg.cls, msg.id, random_payload(msg, rng))
    head, rows = _plausible(msg, rng, ctx)
    types = {f.name: f.type for f in (*msg.fields, *msg.group) if not f.is_padding}
    for _ in range(rng.randint(1, 3)):
        in_rows = bool(rows) and rng.random() < 0.4
        target = rng.choice(rows) if in_rows else head
        names = [n for n in (msg.block_names if in_rows else msg.head_names) if n != msg.count]
        if not names:
            continue
        name = rng.choice(names)
        ftype = types[name]
        if (name in TIME_FIELDS or name in WEEK_FIELDS) and rng.random() < 0.6:
            target[name] = _shifted(ftype, target.get(name, 0), name, rng)
        else:
            target[name] = _interesting(ftype, rng)
    return msg.frame(rows, **head)


def stream_context(raw: bytes, ctx: Context) -> Context:
    """The context after a real frame (an RXM-RAW's week and time of week)."""
    if raw[2:4] == b"\x02\x10" and len(raw) >= 14:
        itow, week = struct.unpack_from("<ih", raw, 6)
        if week > 0 and 0 <= itow < 604_800_000:
            return Context(week, itow)
    return ctx


assert NS_PER_WEEK == 604_800 * 10**9  # the context's units (ms of a week)


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
        self.context = Context(0, 0)
        for raw in self.seeds:
            self.context = stream_context(raw, self.context)
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
        if self.rng.random() < 0.5:  # the right layout, random fields (random_frame)
            frame = random_frame((cls, mid), self.rng, self.context)
        else:
            n = self.rng.choice((0, 1, 7, 8, 16, 24, 28, 36, 40, 52, 92,
                                 self.rng.randint(0, 600)))
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
