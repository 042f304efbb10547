"""Generates the damaged UBX fixtures of tests/data/ and their manifest (run once; README.md).

Each fixture is the simulator's clean rover stream (a few seconds of a LEA-6T: RXM-RAW,
RXM-SFRB, NAV-SOL, NAV-SVINFO) with one kind of damage, named after it. The manifest
(``manifest.json``) states what a correct reader must report for each file, computed here from
what the generator did (which frames it kept intact, which bytes it damaged or inserted), never
by running the project's framer: ``tests/unit/test_fixtures.py`` compares the two.

Run from the repository root::

    PYTHONPATH=. python tests/data/make_fixtures.py
"""

from __future__ import annotations

import gzip
import hashlib
import json
import random
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from groundstation.sim.profiles import sim_config
from groundstation.sim.stream import simulate
from groundstation.storage.mcapio import McapFileWriter
from groundstation.storage.topics import RAW_CHANNEL

HERE = Path(__file__).resolve().parent
N_FRAMES = 60  # ~12 kB: every message type of the stream, small enough to check in
SYNC = b"\xb5\x62"
RXM_RAW = (0x02, 0x10)


def fletcher(body: bytes) -> bytes:
    """UBX checksum over class, id, length and payload (u-blox protocol spec), written out
    here so the fixtures do not depend on the framer's own implementation."""
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


def crc24q(data: bytes) -> int:
    """RTCM 3 CRC-24Q, bit by bit (RTCM 10403.x)."""
    crc = 0
    for x in data:
        crc ^= x << 16
        for _ in range(8):
            crc <<= 1
            if crc & 0x1000000:
                crc ^= 0x1864CFB
    return crc & 0xFFFFFF


def frame(cls: int, mid: int, payload: bytes) -> bytes:
    body = bytes((cls, mid)) + len(payload).to_bytes(2, "little") + payload
    return SYNC + body + fletcher(body)


def nmea(body: str) -> bytes:
    ck = 0
    for ch in body.encode():
        ck ^= ch
    return f"${body}*{ck:02X}\r\n".encode()


def rtcm3(payload: bytes) -> bytes:
    head = bytes((0xD3, len(payload) >> 8, len(payload) & 0xFF)) + payload
    return head + crc24q(head).to_bytes(3, "big")


@dataclass
class Stream:
    """A fixture being built: its bytes and what a correct reader must find in them."""

    data: bytearray = field(default_factory=bytearray)
    intact: list[tuple[str, bytes]] = field(default_factory=list)
    garbage: int = 0
    bad_checksum: int = 0
    too_long: int = 0
    truncated: int = 0
    nmea: int = 0
    rtcm3: int = 0
    undecodable: Counter[str] = field(default_factory=Counter)

    def ok(self, name: str, raw: bytes) -> None:
        self.data += raw
        self.intact.append((name, raw))

    def junk(self, raw: bytes, syncs: int = 0) -> None:
        """Bytes that are no message; ``syncs``: the sync words among them (each a damaged
        frame, counted by the caller)."""
        assert raw.count(SYNC) == syncs, "stray sync word in damaged bytes"
        self.data += raw
        self.garbage += len(raw)

    def manifest(self, damage: str, reader: str = "bytes") -> dict[str, Any]:
        frames = Counter(name for name, _ in self.intact)
        decoded = frames - self.undecodable
        return {
            "damage": damage,
            "reader": reader,
            "stream_bytes": len(self.data),
            "frames": dict(sorted(frames.items())),
            "intact_sha256": hashlib.sha256(b"".join(r for _, r in self.intact)).hexdigest(),
            "bad_checksum": self.bad_checksum,
            "too_long": self.too_long,
            "truncated": self.truncated,
            "damaged_frames": self.bad_checksum + self.too_long + self.truncated,
            "garbage_bytes": self.garbage,
            "nmea_sentences": self.nmea,
            "rtcm3_frames": self.rtcm3,
            "decoded": dict(sorted(decoded.items())),
            "undecodable": dict(sorted(self.undecodable.items())),
        }


def source() -> list[tuple[str, bytes]]:
    sim = simulate(sim_config("default", duration_s=6.0, seed=7, with_base=False))
    msgs = [(m.name, m.raw) for m in sim.rover_messages[:N_FRAMES]]
    for _, raw in msgs:  # the damage below relies on it: no sync word inside a frame
        assert raw.count(SYNC) == 1
    return msgs


def flip(raw: bytes, at: int) -> bytes:
    b = bytearray(raw)
    b[at] ^= 0x5A if b[at] ^ 0x5A not in (0xB5, 0x62) else 0x3C
    return bytes(b)


def build(msgs: list[tuple[str, bytes]]) -> dict[str, tuple[Stream, str]]:
    rng = random.Random(12)
    out: dict[str, tuple[Stream, str]] = {}

    s = Stream()
    for name, raw in msgs:
        s.ok(name, raw)
    out["lea6t-clean.ubx"] = (s, "none")

    s = Stream()
    for i, (name, raw) in enumerate(msgs):
        if i in (5, 17, 33):
            s.junk(flip(raw, 6 + (len(raw) - 8) // 2), syncs=1)
            s.bad_checksum += 1
        else:
            s.ok(name, raw)
    out["lea6t-bad-checksum.ubx"] = (s, "one payload byte changed in 3 frames")

    s = Stream()
    for i, (name, raw) in enumerate(msgs):
        if i == 12:
            cut = raw[: len(raw) // 2]
            # the claimed span runs into the next frames and must fail its checksum
            nxt = b"".join(r for _, r in msgs[i + 1 :])
            span = (cut + nxt)[: len(raw)]
            assert fletcher(span[2:-2]) != span[-2:]
            s.junk(cut, syncs=1)
            s.bad_checksum += 1
        else:
            s.ok(name, raw)
    out["lea6t-truncated-frame.ubx"] = (s, "second half of frame 12 lost mid-stream")

    s = Stream()
    for i, (name, raw) in enumerate(msgs):
        if i == 8:  # claims 40 bytes more: a valid frame ends inside its claimed span
            n = int.from_bytes(raw[4:6], "little") + 40
            s.junk(raw[:4] + n.to_bytes(2, "little") + raw[6:], syncs=1)
            s.bad_checksum += 1
        elif i == 30:  # claims more than any UBX payload the reader accepts
            s.junk(raw[:4] + b"\xff\xff" + raw[6:], syncs=1)
            s.too_long += 1
        else:
            s.ok(name, raw)
    out["lea6t-false-length.ubx"] = (s, "length field of frame 8 +40, of frame 30 0xFFFF")

    s = Stream()
    for i, (name, raw) in enumerate(msgs):
        if i in (3, 20, 40):
            # no 0x62 so no sync word, no '$' or 0xD3 so no NMEA/RTCM3 candidate;
            # a lone 0xB5 first, as a half sync word
            junk = b"\xb5" + bytes(rng.choice([x for x in range(256)
                                               if x not in (0x62, 0x24, 0xD3)])
                                   for _ in range(37 * i % 97 + 11))
            s.junk(junk)
        s.ok(name, raw)
    out["lea6t-garbage-between-frames.ubx"] = (s, "random bytes before frames 3, 20, 40")

    s = Stream()
    for name, raw in msgs[:-1]:
        s.ok(name, raw)
    last = msgs[-1][1]
    s.junk(last[: len(last) - 7], syncs=1)
    s.truncated += 1
    out["lea6t-cut-at-end.ubx"] = (s, "stream ends 7 bytes before the end of its last frame")

    s = Stream()
    for i, (name, raw) in enumerate(msgs):
        s.ok(name, raw)
        if i % 10 == 4:
            s.data += nmea(f"GPGGA,0800{i:02d}.00,4717.11399,N,00833.91590,E,1,08,1.01,"
                           "499.6,M,48.0,M,,")
            s.nmea += 1
    out["lea6t-nmea-interleaved.ubx"] = (s, "a valid NMEA GGA sentence after every 10th frame")

    s = Stream()
    for i, (name, raw) in enumerate(msgs):
        s.ok(name, raw)
        if i % 10 == 7:
            # message 1005 (station position); the rest of the body avoids 0x62 (no sync word)
            body = bytes((0x3E, 0xD0)) + bytes(rng.choice(range(0x63, 0x100)) for _ in range(17))
            msg = rtcm3(body)
            assert SYNC not in msg
            s.data += msg
            s.rtcm3 += 1
    out["lea6t-rtcm3-interleaved.ubx"] = (s, "a valid RTCM3 1005 frame after every 10th frame")

    s = Stream()
    raws = [i for i, (n, _) in enumerate(msgs) if n == "RXM-RAW"]
    short_fixed, short_repeats = raws[4], raws[11]
    for i, (name, raw) in enumerate(msgs):
        if i == short_fixed:  # 5 bytes: shorter than RXM-RAW's 8-byte fixed part
            s.ok(name, frame(*RXM_RAW, raw[6:11]))
            s.undecodable[name] += 1
        elif i == short_repeats:  # numSV one more than the 24-byte blocks present
            p = bytearray(raw[6:-2])
            p[6] += 1
            s.ok(name, frame(*RXM_RAW, bytes(p)))
            s.undecodable[name] += 1
        else:
            s.ok(name, raw)
    out["lea6t-short-payload.ubx"] = (
        s, "two RXM-RAW with valid checksums whose payload is shorter than the layout")
    return out


def write_mcap_torn(msgs: list[tuple[str, bytes]], path: Path) -> dict[str, Any]:
    """An unfinished MCAP cut in the middle of a chunk: the reader gets the complete chunks."""
    data = b"".join(r for _, r in msgs)
    offsets, pos = [], 0
    for _, raw in msgs:
        offsets.append(pos)
        pos += len(raw)
    piece, per_chunk = 700, 4  # serial reads of 700 bytes, 4 per MCAP chunk
    pieces = [data[i : i + piece] for i in range(0, len(data), piece)]
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp) / "x.mcap"
        w = McapFileWriter(tmp_path, chunk_size_bytes=1 << 20, compression="zstd")
        chunk_ends: list[tuple[int, int]] = []  # (file size, stream bytes) after each chunk
        done = 0
        for k, p in enumerate(pieces):
            t = 1_750_000_000_000_000_000 + k * 100_000_000
            w.add(RAW_CHANNEL, p, t, t)
            done += len(p)
            if k % per_chunk == per_chunk - 1:
                w.flush()
                chunk_ends.append((w.size_bytes, done))
        full = tmp_path.read_bytes()  # the writer is abandoned unfinished, as by a kill
    keep_chunks = len(chunk_ends) // 2
    file_end, prefix = chunk_ends[keep_chunks - 1]
    next_end = chunk_ends[keep_chunks][0]
    path.write_bytes(full[: (file_end + next_end) // 2])
    return prefix_manifest(msgs, offsets, prefix,
                           f"unfinished MCAP cut mid-chunk: {keep_chunks} complete chunks "
                           f"({prefix} stream bytes) of {len(chunk_ends)}")


def write_gz_cut(msgs: list[tuple[str, bytes]], path: Path) -> dict[str, Any]:
    """A .ubx.gz whose compressed data stops at 60 %: the reader gets what decompresses."""
    import zlib

    data = b"".join(r for _, r in msgs)
    offsets, pos = [], 0
    for _, raw in msgs:
        offsets.append(pos)
        pos += len(raw)
    packed = gzip.compress(data, compresslevel=9, mtime=0)
    cut = packed[: len(packed) * 6 // 10]
    path.write_bytes(cut)
    prefix = len(zlib.decompressobj(wbits=31).decompress(cut))
    return prefix_manifest(msgs, offsets, prefix,
                           f"gzip cut at 60 % of its compressed size ({prefix} of {len(data)} "
                           "bytes decompress)")


def prefix_manifest(msgs: list[tuple[str, bytes]], offsets: list[int], prefix: int,
                    damage: str) -> dict[str, Any]:
    s = Stream()
    for (name, raw), off in zip(msgs, offsets, strict=True):
        if off + len(raw) <= prefix:
            s.ok(name, raw)
        elif off < prefix:  # the frame the cut went through
            cut = prefix - off >= 2  # a whole sync word: a frame cut short, else a stray byte
            s.junk(raw[: prefix - off], syncs=int(cut))
            s.truncated += int(cut)
    assert len(s.data) == prefix
    return s.manifest(damage, reader="recording")


def main() -> None:
    msgs = source()
    manifest: dict[str, Any] = {}
    for name, (stream, damage) in build(msgs).items():
        (HERE / name).write_bytes(stream.data)
        manifest[name] = stream.manifest(damage)
    manifest["lea6t-torn.mcap"] = write_mcap_torn(msgs, HERE / "lea6t-torn.mcap")
    manifest["lea6t-cut.ubx.gz"] = write_gz_cut(msgs, HERE / "lea6t-cut.ubx.gz")
    for name in manifest:
        size = (HERE / name).stat().st_size
        assert size < 50_000, f"{name}: {size} bytes"
    (HERE / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(f"wrote {len(manifest)} fixtures and manifest.json to {HERE}")


if __name__ == "__main__":
    main()
