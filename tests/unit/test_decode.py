"""Decoder: records equal pyubx2's own fields; unparseable frames are kept and counted."""

from __future__ import annotations

import struct

import pytest
from pyubx2 import UBXReader
from streams import WEEK, rxm_raw, t_gps_ns, tim_tm2

from groundstation.errors import DecodeError
from groundstation.records import Frame, RawEpoch, TimeMark, UndecodedFrame
from groundstation.ubx.build import build_frame
from groundstation.ubx.decode import Decoder, message_name
from groundstation.ubx.framer import iter_frames


def decode_one(raw: bytes, decoder: Decoder | None = None) -> object:
    (frame,) = iter_frames(raw, 42)
    return (decoder or Decoder()).decode(frame)


def test_rxm_raw_matches_pyubx2() -> None:
    raw = rxm_raw(WEEK, 123_456_200, [(5, 0), (12, 1), (29, 2), (135, 3)])
    epoch = decode_one(raw)
    assert isinstance(epoch, RawEpoch)
    ref = UBXReader.parse(raw)
    assert (epoch.gps_week, epoch.tow_ns, epoch.source) == (WEEK, 123_456_200_000_000, "RXM-RAW")
    assert epoch.t_host_ns == 42
    assert len(epoch.sats) == ref.numSV == 4
    for i, s in enumerate(epoch.sats, start=1):
        assert s.carrier_phase_cyc == getattr(ref, f"cpMes_{i:02d}")
        assert s.pseudorange_m == getattr(ref, f"prMes_{i:02d}")
        assert s.doppler_hz == getattr(ref, f"doMes_{i:02d}")
        assert s.cno_dbhz == getattr(ref, f"cno_{i:02d}")
        assert s.mes_qi == getattr(ref, f"mesQI_{i:02d}")
        assert s.lli == getattr(ref, f"lli_{i:02d}")
        assert s.slip == bool(s.lli & 1)
        assert s.half_cycle_unresolved == bool(s.lli & 2)
    assert [s.label for s in epoch.sats] == ["G05", "G12", "G29", "S35"]


def test_tim_tm2_gps_time_base() -> None:
    raw = tim_tm2(7, WEEK, 100_000, 123_456, 100_014, 654_321, new_falling=True, new_rising=True)
    mark = decode_one(raw)
    assert isinstance(mark, TimeMark)
    assert mark.count == 7
    assert mark.falling_t_gps_ns == t_gps_ns(WEEK, 100_000, 123_456)
    assert mark.rising_t_gps_ns == t_gps_ns(WEEK, 100_014, 654_321)
    assert mark.new_falling and mark.new_rising
    assert mark.time_base == 1 and mark.time_base_name == "GPS"
    assert mark.valid and mark.utc_valid and mark.mode_running and mark.run
    assert mark.acc_ns == 21
    assert mark.flags == raw[7]


def test_tim_tm2_utc_time_base_adds_leap_seconds() -> None:
    # Week 2026 (2018): GPS - UTC = 18 s.
    raw = tim_tm2(0, 2026, 59_963_608, 930_556, None, time_base=2)
    mark = decode_one(raw)
    assert isinstance(mark, TimeMark)
    assert mark.rising_t_gps_ns is None
    assert mark.falling_t_gps_ns == t_gps_ns(2026, 59_981_608, 930_556)
    assert mark.leap_s_applied == 18


def test_unknown_message_passes_through_as_frame() -> None:
    raw = build_frame(0x0A, 0x09, bytes(60))  # MON-HW
    out = decode_one(raw)
    assert isinstance(out, Frame)
    assert message_name(0x0A, 0x09) == "MON-HW"
    assert message_name(0x7F, 0x7E) == "UBX-7F-7E"


def test_unparseable_frame_is_kept_and_counted() -> None:
    # RXM-RAW claiming 3 satellites but carrying one: valid checksum, nonsense payload.
    body = struct.pack("<iHBB", 1000, WEEK, 3, 0) + bytes(24)
    raw = build_frame(0x02, 0x10, body)
    decoder = Decoder()
    out = decode_one(raw, decoder)
    assert isinstance(out, UndecodedFrame)
    assert out.frame.raw == raw
    assert decoder.stats.undecodable == 1
    assert decoder.stats.undecodable_by_type == {"RXM-RAW": 1}
    with pytest.raises(DecodeError):
        decode_one(raw, Decoder(raise_on_error=True))
