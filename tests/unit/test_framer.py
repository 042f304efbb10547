"""The UBX framer: chunking invariance, resynchronisation after damage, statistics, and the
same frames as the bulk index (one rule)."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from real_files import REAL_UBX_FILES
from streams import flight_stream, garbage, rxm_raw, tim_tm2

from groundstation.records import Frame
from groundstation.storage.reading import iter_chunks
from groundstation.ubx.build import build_frame
from groundstation.ubx.fastraw import index_frames
from groundstation.ubx.framer import UbxFramer, crc24q, iter_frames, ubx_checksum


def feed_in_chunks(data: bytes, sizes: list[int]) -> tuple[list[bytes], UbxFramer]:
    framer = UbxFramer()
    out, pos, i = [], 0, 0
    while pos < len(data):
        n = sizes[i % len(sizes)] if sizes else len(data)
        out += [f.raw for f in framer.feed(data[pos : pos + n], i)]
        pos += n
        i += 1
    out += [f.raw for f in framer.flush()]
    return out, framer


def test_checksum_known_frame() -> None:
    # CFG-MSG poll for RXM-RAW, as pyubx2 serialises it.
    assert build_frame(0x06, 0x01, b"\x02\x10") == bytes.fromhex("b5620601020002101b45")
    assert ubx_checksum(bytes(range(200))) == ubx_checksum(bytearray(range(200)))


def test_byte_by_byte_equals_whole() -> None:
    data, frames = flight_stream(40)
    whole, _ = feed_in_chunks(data, [])
    single, _ = feed_in_chunks(data, [1])
    odd, _ = feed_in_chunks(data, [7, 1, 300, 2, 55])
    assert whole == single == odd == frames


def test_frame_time_is_time_of_completing_chunk() -> None:
    frame = rxm_raw(2000, 1000, [(5, 0)])
    framer = UbxFramer()
    assert framer.feed(frame[:10], 111) == []
    out = framer.feed(frame[10:], 222)
    assert [f.t_host_ns for f in out] == [222]
    assert out[0].offset == 0


def test_bad_checksum_does_not_swallow_next_frame() -> None:
    a = rxm_raw(2000, 1000, [(5, 0), (6, 0)])
    mark = tim_tm2(3, 2000, 1050, 0, None)
    damaged = bytearray(a)
    damaged[20] ^= 0xFF
    # A frame cut by a dropout: the first 30 bytes of an epoch, then the time mark.
    cut = a[:30]
    frames = iter_frames(bytes(damaged) + mark + cut + mark)
    assert [f.raw for f in frames] == [mark, mark]


def test_cut_frame_with_long_claimed_length_recovers_following_frames() -> None:
    big = rxm_raw(2000, 1000, [(p, 0) for p in range(1, 13)])
    following = [tim_tm2(k, 2000, 1100 + k, 0, None) for k in range(5)]
    stream = big[:40] + b"".join(following) + big
    framer = UbxFramer()
    out = []
    for i in range(0, len(stream), 16):
        out += framer.feed(stream[i : i + 16], i)
    out += framer.flush()
    assert [f.raw for f in out] == [*following, big]
    stats = framer.stats
    assert stats.bad_checksum == 1
    assert stats.garbage_bytes == 40


def test_length_above_maximum_is_damage() -> None:
    ok = tim_tm2(1, 2000, 1000, 0, None)
    bogus = b"\xb5\x62\x02\x10\xff\x7f"  # claims 32767 bytes
    framer = UbxFramer(max_payload=4096)
    frames = framer.feed(bogus + ok, 0) + framer.flush()
    assert [f.raw for f in frames] == [ok]
    assert framer.stats.too_long == 1
    assert framer.stats.damaged_frames == 1


def test_truncated_at_end_of_stream() -> None:
    ok = tim_tm2(1, 2000, 1000, 0, None)
    framer = UbxFramer()
    assert [f.raw for f in framer.feed(ok + ok[:12], 0)] == [ok]
    tail = framer.flush()
    assert tail == []
    stats = framer.stats
    assert stats.frames == 1
    assert stats.truncated == 1
    assert stats.garbage_bytes == 12
    assert stats.pending_bytes == 0


def test_nmea_and_rtcm3_are_recognised_not_garbage() -> None:
    nmea = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
    body = bytes([0xD3, 0x00, 0x13]) + bytes(range(19))
    rtcm = body + crc24q(body).to_bytes(3, "big")
    bad_nmea = b"$GPGGA,123519,4807.038,N*00\r\n"
    ok = tim_tm2(1, 2000, 1000, 0, None)
    data = nmea + ok + rtcm + ok + bad_nmea + ok
    for sizes in ([], [1], [5, 3]):
        frames, framer = feed_in_chunks(data, sizes)
        assert frames == [ok, ok, ok]
        s = framer.stats
        assert (s.nmea_sentences, s.rtcm3_frames) == (1, 1)
        assert s.garbage_bytes == len(bad_nmea)
        assert s.frames_by_type == {(0x0D, 0x03): 3}


def test_every_byte_accounted_for() -> None:
    rng = random.Random(1)
    data, frames = flight_stream(30)
    noisy = garbage(rng, 50) + data + garbage(rng, 7)
    out, framer = feed_in_chunks(noisy, [13])
    s = framer.stats
    assert out == frames
    assert s.bytes_in == s.frame_bytes + s.garbage_bytes + s.nmea_bytes + s.rtcm3_bytes
    assert s.garbage_bytes == 57


# -- property: damage never costs an intact frame ---------------------------------------------

_frame_st = st.builds(
    lambda kind, k: rxm_raw(2100, 1000 + 200 * k, [(p, k % 4) for p in range(1, 2 + k % 12)])
    if kind
    else tim_tm2(k, 2100, 1000 + k, k * 7, None if k % 2 else 999 + k),
    st.booleans(),
    st.integers(0, 2000),
)

_piece_st = st.one_of(
    st.tuples(st.just("frame"), _frame_st, st.just(0)),
    st.tuples(st.just("garbage"), st.binary(min_size=1, max_size=40), st.just(0)),
    st.tuples(st.just("truncated"), _frame_st, st.integers(1, 200)),
    st.tuples(st.just("bitflip"), _frame_st, st.integers(0, 10_000)),
)


@settings(max_examples=300, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(
    pieces=st.lists(_piece_st, min_size=1, max_size=25),
    sizes=st.lists(st.integers(1, 700), min_size=1, max_size=10),
)
def test_property_intact_frames_survive_any_damage(
    pieces: list[tuple[str, bytes, int]], sizes: list[int]
) -> None:
    stream = bytearray()
    intact: list[tuple[int, bytes]] = []
    for kind, blob, arg in pieces:
        if kind == "frame":
            intact.append((len(stream), blob))
            stream += blob
        elif kind == "garbage":
            stream += blob.replace(b"\xb5", b"\xb4")  # garbage that cannot start a frame
        elif kind == "truncated":
            stream += blob[: max(1, min(arg, len(blob) - 1))]
        else:
            bit = arg % (len(blob) * 8)
            flipped = bytearray(blob)
            flipped[bit // 8] ^= 1 << (bit % 8)
            stream += flipped
    framer = UbxFramer()
    out = []
    pos = i = 0
    while pos < len(stream):
        n = sizes[i % len(sizes)]
        out += framer.feed(bytes(stream[pos : pos + n]), i)
        pos += n
        i += 1
    out += framer.flush()
    got = {f.offset: f.raw for f in out}
    offsets = [f.offset for f in out]
    assert offsets == sorted(set(offsets))  # in order, each once
    for off, raw in intact:
        assert got.get(off) == raw, f"intact frame at {off} lost"
    assert framer.stats.pending_bytes == 0


def test_false_long_header_does_not_hold_back_later_frames() -> None:
    # A cut frame whose length field claims 8000 bytes, then ordinary traffic: each frame must
    # come out as soon as it is complete, not once 8000 bytes have arrived.
    bogus = b"\xb5\x62\x02\x10\x40\x1f" + bytes(10)
    marks = [tim_tm2(k, 2000, 1000 + k, 0, None) for k in range(5)]
    framer = UbxFramer()
    assert framer.feed(bogus, 1) == []
    out = []
    for t, m in enumerate(marks, start=2):
        got = framer.feed(m, t)
        assert [f.raw for f in got] == [m], f"mark {t - 2} held back"
        out += got
    assert framer.stats.bad_checksum == 1
    assert framer.stats.garbage_bytes == len(bogus)


# -- one rule: the streaming framer in any chunking equals the bulk index ----------------------



def stream_in_random_chunks(data: bytes, seed: int, largest: int) -> tuple[list[Frame], UbxFramer]:
    rng = random.Random(seed)
    framer = UbxFramer()
    out: list[Frame] = []
    pos = 0
    while pos < len(data):
        n = rng.choice((1, 2, 7, rng.randint(1, 64), rng.randint(1, largest)))
        out += framer.feed(data[pos : pos + n], pos)
        pos += n
    out += framer.flush(pos)
    return out, framer


def damage(data: bytes, seed: int, events: int) -> bytes:
    """A copy with the damage a serial link does: flipped bytes, lost runs, repeated runs,
    inserted noise, sync words with false (often long) lengths."""
    rng = random.Random(seed)
    out = bytearray(data)
    for _ in range(events):
        at = rng.randrange(max(len(out), 1))
        kind = rng.randrange(5)
        if kind == 0:
            out[at] ^= 1 << rng.randrange(8)
        elif kind == 1:
            del out[at : at + rng.randint(1, 300)]
        elif kind == 2:
            out[at:at] = out[max(0, at - 200) : at][: rng.randint(1, 200)]
        elif kind == 3:
            out[at:at] = rng.randbytes(rng.randint(1, 50))
        else:
            out[at:at] = b"\xb5\x62" + rng.randbytes(2) + rng.randint(0, 9000).to_bytes(2, "little")
    return bytes(out)


def assert_same_frames(data: bytes, seed: int) -> None:
    index = index_frames(data)
    frames, framer = stream_in_random_chunks(data, seed, largest=5000)
    assert [f.offset for f in frames] == index.start.tolist()
    assert [f.raw for f in frames] == [index.raw(data, i) for i in range(len(index))]
    s = framer.stats
    assert s.damaged_frames == index.damaged
    assert s.bytes_in == s.frame_bytes + s.garbage_bytes + s.nmea_bytes + s.rtcm3_bytes
    assert s.pending_bytes == 0
    whole = UbxFramer()
    whole.feed(data, 0)
    whole.flush(0)
    assert whole.stats == s  # counts do not depend on the chunking either


def test_streaming_equals_bulk_on_damaged_synthetic_streams() -> None:
    data, _ = flight_stream(200)
    for seed in range(6):
        assert_same_frames(damage(data, seed, events=60), seed)


@pytest.mark.shared_data
@pytest.mark.parametrize("rel", REAL_UBX_FILES)
def test_streaming_equals_bulk_on_real_files_and_damaged_copies(
    shared_data: Path, rel: str
) -> None:
    data = b"".join(c for c, _ in iter_chunks(shared_data / "real" / rel))
    assert_same_frames(data, 1)
    part = data[: 400_000]
    assert_same_frames(damage(part, 2, events=max(20, len(part) // 2000)), 3)


def test_ubx_framing_does_not_depend_on_rtcm3_or_nmea() -> None:
    # A valid UBX frame is a frame even inside what would otherwise be a valid RTCM3 frame: UBX
    # framing never waits for, nor is hidden by, the recognition of the bytes between frames
    # (that is what lets the bulk index ignore NMEA and RTCM3).
    ok = tim_tm2(1, 2000, 1000, 0, None)
    body = bytes([0xD3, 0x00, len(ok) + 4]) + b"ab" + ok + b"cd"
    rtcm = body + crc24q(body).to_bytes(3, "big")
    data = rtcm + ok
    for sizes in ([], [1], [9, 2]):
        frames, framer = feed_in_chunks(data, sizes)
        assert frames == [ok, ok]
        s = framer.stats
        assert s.rtcm3_frames == 0  # cut by a UBX frame, so not a whole RTCM3 frame
        assert s.garbage_bytes == len(rtcm) - len(ok)
    assert index_frames(data).start.tolist() == [5, len(rtcm)]
