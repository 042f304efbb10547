"""The framing rule on whole arrays (``framer.scan_ubx_arrays``, the offline bulk path) against
the rule's loop (``framer.scan_ubx``, the live path): the same frames, damage counts and
``hold`` on every fixture, every real file, random damaged streams cut anywhere, and the rare
overlapping case; and the streaming bulk index (``fastraw.index_chunks``) against the whole-file
index in any block size."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import numpy as np
import pytest
from real_files import REAL_UBX_FILES, real_bytes

from groundstation.storage.reading import iter_chunks
from groundstation.ubx import fastraw
from groundstation.ubx.build import build_frame
from groundstation.ubx.framer import scan_ubx, scan_ubx_arrays

FIXTURES = sorted((Path(__file__).parents[1] / "data").glob("lea6t-*"))


def _same(data: bytes, lo: int, n: int, max_payload: int = 8192, *, final: bool) -> None:
    loop = scan_ubx(data, lo, n, max_payload, final=final)
    arrays = scan_ubx_arrays(data, lo, n, max_payload, final=final)
    assert arrays.start.tolist() == loop.start
    assert arrays.length.tolist() == loop.length
    assert (arrays.bad_checksum, arrays.too_long, arrays.truncated, arrays.hold) == (
        loop.bad_checksum, loop.too_long, loop.truncated, loop.hold)


def _damaged_stream(rng: random.Random, items: int) -> bytes:
    out = bytearray()
    for _ in range(items):
        r = rng.random()
        payload = rng.randbytes(rng.randrange(0, 60))
        if r < 0.6:
            out += build_frame(rng.randrange(256), rng.randrange(256), payload)
        elif r < 0.7:
            out += rng.randbytes(rng.randrange(1, 20))
        elif r < 0.85:  # one bit flipped anywhere, the length field included
            f = bytearray(build_frame(0x02, 0x15, payload))
            f[rng.randrange(len(f))] ^= 1 << rng.randrange(8)
            out += f
        else:  # a sync word and a few random bytes: false or huge lengths
            out += b"\xb5\x62" + rng.randbytes(rng.randrange(0, 10))
    return bytes(out)


def _overlapping() -> bytes:
    """Frame A's payload ends in the header of a valid frame B that runs past A's end (B's
    payload starts with A's checksum): both complete, right and clean; the rule takes A and
    B's bytes after A are damage."""
    a = build_frame(0x01, 0x07, b"\x11" * 10 + b"\xb5\x62\x01\x02" + struct.pack("<H", 6))
    b_body = a[-8:-2] + a[-2:] + b"\x22" * 4  # B: class 01 id 02, 6-byte payload
    b = b_body + bytes(build_frame(0x01, 0x02, b_body[6:])[-2:])
    assert build_frame(0x01, 0x02, b_body[6:]) == b
    return a + b[8:] + build_frame(0x0D, 0x03, b"\x00" * 28)


@pytest.mark.parametrize("path", FIXTURES, ids=[p.name for p in FIXTURES])
def test_every_fixture(path: Path) -> None:
    data = b"".join(c for c, _ in iter_chunks(path, follow_parts=False))
    for final in (True, False):
        _same(data, 0, len(data), final=final)


@pytest.mark.shared_data
@pytest.mark.parametrize("name", REAL_UBX_FILES)
def test_every_real_file(shared_data: Path, name: str) -> None:
    data = real_bytes(shared_data, name)
    for final in (True, False):
        _same(data, 0, len(data), final=final)
    assert fastraw.index_frames(data).start.size > 0


def test_random_damage_cut_anywhere() -> None:
    rng = random.Random(20261122)
    for _ in range(1500):
        data = _damaged_stream(rng, rng.randrange(1, 40))
        lo = rng.randrange(0, 3)
        cut = rng.randrange(lo, len(data) + 1)
        for max_payload in (8192, 30):
            for final in (True, False):
                _same(data, lo, len(data), max_payload, final=final)
                _same(data, lo, cut, max_payload, final=final)


def test_overlapping_clean_frames() -> None:
    data = _overlapping()
    scan = scan_ubx_arrays(data, 0, len(data), 8192, final=True)
    assert scan.start.tolist() == [0, len(data) - 36]  # A, then the frame after B
    for n in range(len(data) + 1):
        for final in (True, False):
            _same(data, 0, n, final=final)


@pytest.mark.parametrize("block", [1, 7, 100, 4096])
def test_index_chunks_equals_the_whole_file_index(
    block: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = random.Random(block)
    data = _damaged_stream(rng, 400) + _overlapping() + b"\xb5\x62\x01"
    monkeypatch.setattr(fastraw, "BLOCK_BYTES", block)
    chunks = [data[i : i + 37] for i in range(0, len(data), 37)]
    frames, index = fastraw.index_chunks(chunks)
    whole = fastraw.index_frames(data)
    assert index.damaged == whole.damaged
    assert index.length.tolist() == whole.length.tolist()
    assert frames == b"".join(whole.raw(data, i) for i in range(len(whole)))
    assert index.start.tolist() == (np.cumsum(whole.length + 8) - (whole.length + 8)).tolist()
    assert fastraw.index_frames(frames).start.tolist() == index.start.tolist()
