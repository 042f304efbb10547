"""fastraw: the vectorised frame index and RXM-RAW/RXM-RAWX/TIM-TM2 arrays against the framer and
pyubx2, field by field, on synthetic damage and on the real recordings."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
from pyubx2 import UBXReader

from groundstation.storage.reading import iter_chunks
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame
from groundstation.ubx.fastraw import (
    decode_raw,
    decode_rawx,
    decode_timtm2,
    index_frames,
)
from groundstation.ubx.framer import UbxFramer

RAWX_FIELDS = {
    "prMes": "prMes", "cpMes": "cpMes", "doMes": "doMes", "gnssId": "gnssId", "svId": "svId",
    "sigId": "sigId", "freqId": "freqId", "locktime": "locktime", "cno": "cno",
}  # fmt: skip
RAW_FIELDS = ("cpMes", "prMes", "doMes", "sv", "mesQI", "cno", "lli")

RAWX_FILES = (
    "real/gpsd__gpsd-mirror/test/daemon/ublox-neo-m8t.log",
    "real/gpsd__gpsd-mirror/test/daemon/ublox-zed-f9p_hpg1.11.log",
    "real/rtklibexplorer__GNSS_IMU/data/walk_0827/gnss_1730.ubx",
    "real/jdesbonnet__GNSS_RTK_data/20181004/base-20181004-1236.ubx.gz",
)
RAW_FILES = (
    "real/tomojitakasu__RTKLIB/test/data/rcvraw/ubx_20080526.ubx",
    "real/tridge__pyUblox/data/6P-raw-PPP.ubx",
    "real/gpsd__gpsd-mirror/test/daemon/ublox-aek-4t.log",
)


def _read(path: Path) -> bytes:
    return b"".join(c for c, _ in iter_chunks(path))


def _framer_offsets(data: bytes) -> list[int]:
    f = UbxFramer()
    frames = f.feed(data, 0) + f.flush(0)
    return [fr.offset for fr in frames]


def _rawx_payload(n: int, rng: random.Random) -> bytes:
    rows = [
        {"prMes": 2e7 + rng.random(), "cpMes": 1e8 + rng.random(), "doMes": rng.random(),
         "svId": rng.randint(1, 32), "locktime": rng.randint(0, 64500), "cno": 40, "prStdev": 3,
         "cpStdev": 2, "doStdev": 1, "trkStat": 15}
        for _ in range(n)
    ]
    return L.RXM_RAWX.payload(rows, rcvTow=1000.5, week=2026, leapS=18, recStat=1, version=1)


def test_index_matches_framer_on_synthetic_damage() -> None:
    rng = random.Random(7)
    parts: list[bytes] = []
    for k in range(300):
        frame = build_frame(0x02, 0x15, _rawx_payload(rng.randint(0, 5), rng))
        roll = rng.random()
        if roll < 0.1:  # cut short: the next frame must survive
            frame = frame[: rng.randint(2, len(frame) - 1)]
        elif roll < 0.2:  # flipped byte: bad checksum
            b = bytearray(frame)
            b[rng.randint(6, len(b) - 3)] ^= 0x55
            frame = bytes(b)
        elif roll < 0.25:  # garbage, some of it looking like a sync word
            frame = bytes(rng.randint(0, 255) for _ in range(rng.randint(1, 40))) + b"\xb5\x62"
        parts.append(frame)
        if k % 50 == 0:
            parts.append(build_frame(0x0D, 0x03, bytes(28)))
    data = b"".join(parts)
    index = index_frames(data)
    assert index.start.tolist() == _framer_offsets(data)
    assert len(index) > 200


def test_valid_frame_inside_a_frame_wins_in_bulk_and_streaming() -> None:
    # The rule of framer.scan_ubx: a valid frame that ends inside another frame's claimed span
    # proves that span false, whether or not the outer checksum happens to pass; so the inner
    # frame comes out as soon as it is complete, in any chunking, and the outer is damage.
    inner = build_frame(0x01, 0x02, b"abcd")
    outer = build_frame(0x0A, 0x04, b"xx" + inner + b"yy")
    data = outer + build_frame(0x01, 0x06, bytes(52))
    index = index_frames(data)
    assert index.start.tolist() == [8, len(outer)] == _framer_offsets(data)
    assert index.damaged == 1
    f = UbxFramer()
    got = [fr.offset for k in range(len(data)) for fr in f.feed(data[k : k + 1], k)]
    assert got + [fr.offset for fr in f.flush()] == [8, len(outer)]
    assert f.stats.bad_checksum == 1


def test_index_of_empty_and_tiny_inputs() -> None:
    assert len(index_frames(b"")) == 0
    assert len(index_frames(b"\xb5")) == 0
    assert index_frames(b"\xb5\x62\x02").damaged == 1


def test_rawx_rejects_message_shorter_than_its_count() -> None:
    good = _rawx_payload(2, random.Random(1))
    bad = good[:-10]
    data = build_frame(0x02, 0x15, good) + build_frame(0x02, 0x15, bad)
    block = decode_rawx(data, index_frames(data))
    assert block.frame.tolist() == [0]
    assert block.rejected.tolist() == [1]
    assert block.meas.size == 2
    assert block.epoch.tolist() == [0, 0]


@pytest.mark.shared_data
@pytest.mark.parametrize("rel", RAWX_FILES + RAW_FILES)
def test_index_matches_framer_on_real_files(shared_data: Path, rel: str) -> None:
    data = _read(shared_data / rel)
    assert index_frames(data).start.tolist() == _framer_offsets(data)


@pytest.mark.shared_data
@pytest.mark.parametrize("rel", RAWX_FILES)
def test_rawx_field_by_field_against_pyubx2(shared_data: Path, rel: str) -> None:
    data = _read(shared_data / rel)
    index = index_frames(data)
    block = decode_rawx(data, index)
    assert block.frame.size == index.select((0x02, 0x15)).size > 0
    row = 0
    for e, fi in enumerate(block.frame.tolist()):
        msg = UBXReader.parse(index.raw(data, fi))
        h = block.header[e]
        assert h["rcvTow"] == msg.rcvTow
        assert h["week"] == msg.week
        assert h["leapS"] == msg.leapS
        assert h["numMeas"] == msg.numMeas
        for i in range(1, msg.numMeas + 1):
            m = block.meas[row]
            assert block.epoch[row] == e
            for ours, theirs in RAWX_FIELDS.items():
                assert m[ours] == getattr(msg, f"{theirs}_{i:02d}"), (fi, i, ours)
            assert m["prStdev"] & 15 == getattr(msg, f"prStd_{i:02d}")
            assert m["cpStdev"] & 15 == getattr(msg, f"cpStd_{i:02d}")
            assert m["doStdev"] & 15 == getattr(msg, f"doStd_{i:02d}")
            trk = (
                getattr(msg, f"prValid_{i:02d}")
                | getattr(msg, f"cpValid_{i:02d}") << 1
                | getattr(msg, f"halfCyc_{i:02d}") << 2
                | getattr(msg, f"subHalfCyc_{i:02d}") << 3
            )
            assert m["trkStat"] & 15 == trk
            row += 1
    assert row == block.meas.size


@pytest.mark.shared_data
@pytest.mark.parametrize("rel", RAW_FILES)
def test_raw_field_by_field_against_pyubx2(shared_data: Path, rel: str) -> None:
    data = _read(shared_data / rel)
    index = index_frames(data)
    block = decode_raw(data, index)
    assert block.frame.size > 0
    row = 0
    for e, fi in enumerate(block.frame.tolist()):
        msg = UBXReader.parse(index.raw(data, fi))
        assert block.header[e]["iTOW"] == msg.iTOW
        assert block.header[e]["week"] == msg.week
        for i in range(1, msg.numSV + 1):
            for name in RAW_FIELDS:
                assert block.meas[row][name] == getattr(msg, f"{name}_{i:02d}"), (fi, i, name)
            row += 1
    assert row == block.meas.size
    assert np.array_equal(block.tow_ns, block.header["iTOW"].astype(np.int64) * 1_000_000)


@pytest.mark.shared_data
def test_timtm2_field_by_field_against_pyubx2(shared_data: Path) -> None:
    rel = "real/jdesbonnet__GNSS_RTK_data/20181104/rover-20181104-1634.ubx.gz"
    data = _read(shared_data / rel)
    index = index_frames(data)
    sel, rows = decode_timtm2(data, index)
    assert sel.size == 1196
    for fi, r in zip(sel.tolist()[::7], rows[::7], strict=True):
        msg = UBXReader.parse(index.raw(data, fi))
        for name in ("ch", "count", "wnR", "wnF", "towMsR", "towSubMsR", "towMsF", "towSubMsF",
                     "accEst"):
            assert r[name] == getattr(msg, name), name
        assert r["flags"] == index.payload(data, fi)[1]
