"""Decoder: records equal pyubx2's own fields; unparseable frames are kept and counted."""

from __future__ import annotations

import dataclasses
import random
import struct
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from pyubx2 import UBXMessage, UBXReader
from real_files import REAL_UBX_FILES
from streams import WEEK, rxm_raw, t_gps_ns, tim_tm2

from groundstation.errors import DecodeError
from groundstation.records import (
    Frame,
    NavSolution,
    RawEpoch,
    SatObs,
    TimeMark,
    UndecodedFrame,
    positional_constructor,
)
from groundstation.sim.stream import SimConfig, simulate
from groundstation.storage.reading import iter_chunks
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame
from groundstation.ubx.decode import Decoder, gnss_of_svid, message_name
from groundstation.ubx.framer import UbxFramer, iter_frames


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


# -- field for field against pyubx2: layouts and records, real recordings and the simulator ----

# pyubx2 spells these differently from the u-blox specification we follow (or merges reserved
# bytes with a neighbour); every other field must exist in pyubx2 under the same name.
NOT_IN_PYUBX2 = {"RXM-RAWX": {"version"}}


def _pyubx2_value(msg: Any, name: str) -> Any:
    value = getattr(msg, name)
    return int.from_bytes(value, "little") if isinstance(value, bytes) else value


def _check_fields(layout: L.Message, values: dict[str, Any], msg: Any, suffix: str) -> int:
    """Our raw values of one fixed part / group row against pyubx2's attributes."""
    checked = 0
    for f in (*layout.fields, *layout.group):
        if f.name not in values or f.name.startswith("reserved"):
            continue
        bits = layout.bits.get(f.name)
        if bits is not None:  # pyubx2 exposes a flag field as its named bits
            for bit in bits.parts:
                if hasattr(msg, bit + suffix):
                    assert bits.get(values[f.name], bit) == getattr(msg, bit + suffix), bit
                    checked += 1
            continue
        if f.name in NOT_IN_PYUBX2.get(layout.name, ()):
            continue
        theirs = _pyubx2_value(msg, f.name + suffix)
        assert layout.scaled(f.name, values[f.name]) == theirs, (layout.name, f.name + suffix)
        checked += 1
    return checked


def _expected_record(msg: Any, frame: Frame) -> dict[str, Any]:
    """What the record of a hot message must hold, from pyubx2's parse (the mapping the decoder
    had when it used pyubx2). Fields the phase rule derives (LLI, slips, half cycles, usable phase)
are left to tests/unit/test_rules_phase.py and tests/integration/test_rules_equivalence.py."""
    name = msg.identity

    def n(attr: str, i: int) -> Any:
        return getattr(msg, f"{attr}_{i:02d}")

    if name == "RXM-RAW":
        return {"gps_week": msg.week, "tow_ns": msg.iTOW * 1_000_000, "sats": [
            {"sv_id": n("sv", i), "carrier_phase_cyc": n("cpMes", i),
             "pseudorange_m": n("prMes", i), "doppler_hz": n("doMes", i),
             "cno_dbhz": n("cno", i), "mes_qi": n("mesQI", i)}
            for i in range(1, msg.numSV + 1)]}
    if name == "RXM-RAWX":
        return {"gps_week": msg.week, "tow_ns": round(msg.rcvTow * 1e9),
                "leap_s": msg.leapS if msg.leapSec else None, "clock_reset": bool(msg.clkReset),
                "sats": [
            {"gnss": n("gnssId", i), "sv": n("svId", i), "sig_id": n("sigId", i),
             "freq_id": n("freqId", i), "carrier_phase_cyc": n("cpMes", i),
             "pseudorange_m": n("prMes", i), "doppler_hz": n("doMes", i), "cno_dbhz": n("cno", i),
             "locktime_ms": n("locktime", i), "pr_valid": bool(n("prValid", i)),
             "half_cycle_subtracted": bool(n("subHalfCyc", i)),
             "pr_stdev_idx": n("prStd", i), "cp_stdev_idx": n("cpStd", i),
             "do_stdev_idx": n("doStd", i)} for i in range(1, msg.numMeas + 1)]}  # fmt: skip
    if name == "TIM-TM2":
        return {"channel": msg.ch, "count": msg.count, "new_rising": bool(msg.newRisingEdge),
                "new_falling": bool(msg.newFallingEdge), "time_base": msg.timeBase,
                "valid": bool(msg.time), "acc_ns": msg.accEst, "mode_running": bool(msg.mode),
                "run": bool(msg.run), "utc_valid": bool(msg.utc), "flags": frame.payload[1]}
    if name == "RXM-SFRB":
        return {"channel": msg.chn, "svid": msg.svid, "words": tuple(
            int.from_bytes(n("dwrd", i), "little") for i in range(1, 11))}
    if name == "RXM-SFRBX":
        return {"gnss": msg.gnssId, "sv": msg.svId, "sig_id": msg.sigId, "freq_id": msg.freqId,
                "channel": msg.chn,
                "words": tuple(n("dwrd", i) for i in range(1, msg.numWords + 1))}
    if name == "AID-EPH":

        def sf(k: int) -> tuple[int, ...]:
            return tuple(getattr(msg, f"sf{k}d{j}_01") for j in range(1, 9))

        full = len(frame.payload) >= 104
        return {"sv": msg.svid, "how": msg.how, "sf1": sf(1) if full else (),
                "sf2": sf(2) if full else (), "sf3": sf(3) if full else ()}
    if name == "NAV-SOL":
        return {"tow_ns": msg.iTOW * 1_000_000 + msg.fTOW, "fix_type": msg.gpsFix,
                "gps_week": msg.week if msg.wknSet else None, "fix_ok": bool(msg.gpsfixOK),
                "num_sv": msg.numSV, "p_acc_m": msg.pAcc / 100.0,
                "ecef_m": (msg.ecefX / 100, msg.ecefY / 100, msg.ecefZ / 100)
                if (msg.ecefX, msg.ecefY, msg.ecefZ) != (0, 0, 0) else None}
    if name in ("NAV-PVT", "NAV-POSLLH"):
        has = not (msg.lat == 0 and msg.lon == 0)
        out = {"tow_ns": msg.iTOW * 1_000_000, "lat_deg": msg.lat if has else None,
               "lon_deg": msg.lon if has else None,
               "height_m": msg.height / 1000.0 if has else None, "h_acc_m": msg.hAcc / 1000.0,
               "v_acc_m": msg.vAcc / 1000.0}
        if name == "NAV-PVT":
            out |= {"fix_type": msg.fixType, "fix_ok": bool(msg.gnssFixOk), "num_sv": msg.numSV}
        return out
    if name == "NAV-SVINFO":
        return {"tow_ns": msg.iTOW * 1_000_000, "sats": [
            {"svid": n("svid", i), "cno_dbhz": n("cno", i), "elev_deg": n("elev", i),
             "azim_deg": n("azim", i), "used": bool(n("svUsed", i)),
             "quality": n("qualityInd", i), "healthy": not n("unhealthy", i)}
            for i in range(1, msg.numCh + 1)]}
    assert name == "NAV-SAT", name
    return {"tow_ns": msg.iTOW * 1_000_000, "sats": [
        {"gnss": n("gnssId", i), "sv": n("svId", i), "cno_dbhz": n("cno", i),
         "elev_deg": n("elev", i), "azim_deg": n("azim", i), "used": bool(n("svUsed", i)),
         "quality": n("qualityInd", i), "healthy": n("health", i) != 2}
        for i in range(1, msg.numSvs + 1)]}


def _check_record(record: Any, expected: dict[str, Any]) -> None:
    for key, want in expected.items():
        if key == "sats":
            assert len(record.sats) == len(want)
            for sat, w in zip(record.sats, want, strict=True):
                for k, v in w.items():
                    if k == "sv_id" or k == "svid":  # single-number id of u-blox 6
                        gnss, sv = gnss_of_svid(v)
                        assert (sat.gnss, sat.sv) == ((gnss, sv) if gnss != 1 else (1, v))
                    else:
                        assert getattr(sat, k) == v, k
        elif key == "svid":
            assert (record.gnss, record.sv) == gnss_of_svid(want)
        else:
            assert getattr(record, key) == want, key


def check_against_pyubx2(frames: list[Frame]) -> Counter[str]:
    """Every hot frame: layout values and record fields equal pyubx2's parse. Returns how many
    frames of each type were checked."""
    decoder = Decoder(raise_on_error=True)
    seen: Counter[str] = Counter()
    for frame in frames:
        record = decoder.decode(frame)
        layout = L.MESSAGES.get(frame.key)
        if layout is None:
            assert record is frame
            continue
        msg = UBXReader.parse(frame.raw)
        assert msg.identity == layout.name == message_name(*frame.key)
        head, rows = layout.unpack(frame.payload)
        assert _check_fields(layout, head, msg, "") > 0 or layout.name == "AID-EPH"
        for i, row in enumerate(rows, start=1):
            _check_fields(layout, row, msg, f"_{i:02d}")
        _check_record(record, _expected_record(msg, frame))
        seen[layout.name] += 1
    return seen


def _frames_of(data: bytes) -> list[Frame]:
    framer = UbxFramer()
    return framer.feed(data, 0) + framer.flush(0)


@pytest.mark.slow
@pytest.mark.shared_data
@pytest.mark.parametrize("rel", REAL_UBX_FILES)
def test_every_hot_frame_of_real_recordings_equals_pyubx2(shared_data: Path, rel: str) -> None:
    data = b"".join(c for c, _ in iter_chunks(shared_data / "real" / rel))
    seen = check_against_pyubx2(_frames_of(data))
    assert sum(seen.values()) > 0


def test_simulator_output_equals_pyubx2() -> None:
    result = simulate(SimConfig(duration_s=30.0, seed=5))
    seen = check_against_pyubx2(_frames_of(result.rover_bytes))
    assert {"RXM-RAW", "NAV-SOL", "NAV-SVINFO", "TIM-TM2"} <= set(seen)


def test_layout_encoders_round_trip_through_pyubx2() -> None:
    # Every message built from its layout (the encoders the simulator and tests use) parses in
    # pyubx2 to the values given, including scaled fields and flag bits.
    for layout in L.MESSAGES.values():
        values = {name: (k * 37 + 5) % 100 for k, name in enumerate(layout.head_names)}
        if isinstance(layout.count, str):
            del values[layout.count]
        rows = [{name: (k * 11 + r) % 50 for k, name in enumerate(layout.block_names)}
                for r in range(3 if layout.count != 10 else 10)]
        if layout.count == L.BY_SIZE:
            rows = rows[:1]
        if not layout.group:
            rows = []
        raw = layout.frame(rows, **values)
        (frame,) = iter_frames(raw)
        msg = UBXReader.parse(raw)
        head, got_rows = layout.unpack(frame.payload)
        assert {k: head[k] for k in values} == values
        assert got_rows == [{**dict.fromkeys(layout.block_names, 0), **r} for r in rows]
        _check_fields(layout, head, msg, "")
        for i, row in enumerate(got_rows, start=1):
            _check_fields(layout, row, msg, f"_{i:02d}")
        assert Decoder(raise_on_error=True).decode(frame) is not frame


def test_layouts_agree_with_pyubx2_on_ids_and_sizes() -> None:
    for key, layout in L.MESSAGES.items():
        assert message_name(*key) == layout.name
        # pyubx2 builds the same fixed part from all-zero fields
        assert len(UBXMessage(layout.cls, layout.id, 0).payload) in (0, layout.head.size)


def test_flag_bits_compose_and_decompose() -> None:
    flags = L.TIM_TM2_FLAGS.compose(mode=1, run=1, timeBase=2, newRisingEdge=1)
    assert flags == 0x01 | 0x02 | 0x10 | 0x80
    assert L.TIM_TM2_FLAGS.decompose(flags)["timeBase"] == 2
    with pytest.raises(ValueError, match="does not fit"):
        L.TIM_TM2_FLAGS.compose(timeBase=4)
    with pytest.raises(ValueError, match="no field"):
        L.TIM_TM2.payload(bogus=1)


@pytest.mark.parametrize("key", sorted(L.MESSAGES))
def test_short_payload_is_undecoded_not_guessed(key: tuple[int, int]) -> None:
    layout = L.MESSAGES[key]
    rows: list[dict[str, Any]] = [{}] * (2 if isinstance(layout.count, str) else 0)
    payload = layout.payload(rows) if layout.count != 10 else layout.payload([{}] * 10)
    cut = build_frame(*key, payload[: (layout.min_length or layout.head.size) - 1])
    decoder = Decoder()
    out = decode_one(cut, decoder)
    assert isinstance(out, UndecodedFrame), layout.name
    assert decoder.stats.undecodable_by_type == {layout.name: 1}
    if rows:  # the count claims more repeats than the payload holds
        out = decode_one(build_frame(*key, payload[:-1]), decoder)
        assert isinstance(out, UndecodedFrame), layout.name


def test_positional_constructor_equals_dataclass_init() -> None:
    make = positional_constructor(SatObs)
    args = (0, 5, 1.5, 2.5, -3.5, 40, 7, 1, False, True)
    assert make(*args) == SatObs(*args)
    assert make(*args, 1, 2, 3, 4, False, True, True, 5, 6, 7) == SatObs(
        *args, 1, 2, 3, 4, False, True, True, 5, 6, 7
    )
    with pytest.raises(dataclasses.FrozenInstanceError):
        make(*args).sv = 3  # type: ignore[misc]
    obs = make(*args, locktime_ms=9, cp_valid=False)
    assert type(obs) is SatObs
    assert obs == SatObs(*args, locktime_ms=9, cp_valid=False)
    assert hash(obs) == hash(SatObs(*args, locktime_ms=9, cp_valid=False))
    assert make(*args) != make(*args[:-1], False)
    with pytest.raises(TypeError):
        make(*args[:-1])  # a field without a default is missing
    # a field named like a local of the generated code (Frame.cls) does not shadow it
    frame = positional_constructor(Frame)(1, 2, b"p", b"raw", 3)
    assert type(frame) is Frame and frame == Frame(1, 2, b"p", b"raw", 3, 0)


def test_positional_constructor_refuses_what_it_cannot_build() -> None:
    @dataclasses.dataclass(frozen=True)
    class NoSlots:
        a: int

    @dataclasses.dataclass(frozen=True, slots=True)
    class Factory:
        a: list[int] = dataclasses.field(default_factory=list)

    for cls in (NoSlots, Factory):
        with pytest.raises(TypeError):
            positional_constructor(cls)


def test_latitude_and_longitude_are_the_scaled_fields_for_any_int32() -> None:
    """The decoder's ``raw / 1e7`` equals pyubx2's ``round(raw * 1e-7, 12)`` (the layout's
    ``scaled``) bit for bit, over the whole int32 range and its ends."""
    rng = random.Random(7)
    values = [-(2**31), 2**31 - 1, -1, 1, 5, -5, 1_800_000_000, -1_800_000_000]
    values += [rng.randrange(-(2**31), 2**31) for _ in range(3000)]
    decoder = Decoder()
    for lat, lon in zip(values, reversed(values), strict=True):
        for layout in (L.NAV_POSLLH, L.NAV_PVT):
            sol = decode_one(build_frame(*layout.key, layout.payload(lat=lat, lon=lon)), decoder)
            assert isinstance(sol, NavSolution)
            if (lat, lon) != (0, 0):
                assert sol.lat_deg == layout.scaled("lat", lat)
                assert sol.lon_deg == layout.scaled("lon", lon)
