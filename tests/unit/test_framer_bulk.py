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
from groundstation.ubx import fastraw, framer
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


@pytest.mark.parametrize("window", [64, 1000, 1 << 18])
def test_vector_checksums_equal_the_checksum_of_each_frame(
    window: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``_checksums_ok`` (all candidates at once, in windows) says what ``ubx_checksum`` says of
    each one: right and wrong checksums, overlapping spans, long frames, several windows."""
    monkeypatch.setattr(framer, "_CHECKSUM_WINDOW", window)
    rng = random.Random(window)
    data = bytearray(_damaged_stream(rng, 300))
    for size in (0, 1, 300, 5000):  # long payloads: a window shorter than one frame
        data += build_frame(0x02, 0x10, rng.randbytes(size))
    arr = np.frombuffer(bytes(data), dtype=np.uint8)
    start = np.array(sorted(rng.sample(range(len(data) - 8), 400)), dtype=np.int64)
    end = np.minimum(start + 8 + np.array([rng.randrange(0, 6000) for _ in start]), len(data))
    true_starts = [i for i in range(len(data) - 1) if data[i : i + 2] == b"\xb5\x62"]
    start = np.concatenate((start, np.array(true_starts, dtype=np.int64)))
    length = np.array([data[s + 4] | data[s + 5] << 8 if s + 6 <= len(data) else 0
                       for s in start.tolist()], dtype=np.int64)
    end = np.concatenate((end, start[len(end):] + 8 + length[len(end):]))
    order = np.argsort(start, kind="stable")
    start, end = start[order], end[order]
    keep = end <= len(data)
    start, end = start[keep], end[keep]
    got = framer._checksums_ok(arr, start, end).tolist()
    want = [framer.ubx_checksum(data[s + 2 : e - 2]) == (data[e - 2], data[e - 1])
            for s, e in zip(start.tolist(), end.tolist(), strict=True)]
    assert got == want
    assert 50 < sum(want) < len(want)  # both verdicts are tested


def test_both_candidate_paths_of_the_loop_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    """``scan_ubx`` finds its candidates with numpy from ``_VECTOR_BYTES`` on and with
    ``bytes.find`` below: forced to each path, the same decisions on damaged streams cut
    anywhere and on the overlapping case."""
    rng = random.Random(4096)
    cases = [(_overlapping(), 0, n) for n in range(len(_overlapping()) + 1)]
    for _ in range(400):
        data = _damaged_stream(rng, rng.randrange(1, 60))
        lo = rng.randrange(0, 3)
        cases.append((data, lo, rng.randrange(lo, len(data) + 1)))
    for data, lo, n in cases:
        for max_payload in (8192, 30):
            for final in (True, False):
                monkeypatch.setattr(framer, "_VECTOR_BYTES", 0)
                vector = scan_ubx(data, lo, n, max_payload, final=final)
                monkeypatch.setattr(framer, "_VECTOR_BYTES", 1 << 30)
                assert scan_ubx(data, lo, n, max_payload, final=final) == vector
