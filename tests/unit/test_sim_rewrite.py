"""The recording rewrite on frames built here: the LEA-6T's LLI rule, what is converted, kept and
dropped, the time moved onto the millisecond, and the link's outages on both forms."""

from __future__ import annotations

from typing import Any

import pytest

from groundstation.gnss import lnav
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.lnav_encode import encode_ephemeris
from groundstation.gnss.orbit import L1_WAVELENGTH_M
from groundstation.gpstime import NS_PER_WEEK
from groundstation.records import Frame, RawEpoch, Subframe
from groundstation.rules.phase import LLI_HALF_CYCLE, LLI_SLIP
from groundstation.sim.constellation import make_constellation
from groundstation.sim.faults import FaultConfig
from groundstation.sim.rewrite import (
    LOCK_MAX_MS,
    LeaLli,
    RewriteConfig,
    convert_frames,
    link_gaps,
    replay_frames,
)
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame
from groundstation.ubx.decode import Decoder, message_name
from groundstation.ubx.framer import iter_frames

WEEK = 2022
PR_VALID, CP_VALID, HALF_VALID, HALF_SUB = 1, 2, 4, 8
LOCKED = PR_VALID | CP_VALID | HALF_VALID


def _lli(seq: list[tuple[int, int, int, int] | None]) -> list[tuple[int, str | None] | None]:
    """LLI and kind of one satellite over epochs 1 s apart: (lock ms, trkStat, ...) or None
    when it has no usable phase at that epoch."""
    rule = LeaLli()
    out: list[tuple[int, str | None] | None] = []
    for k, m in enumerate(seq):
        if m is None:
            out.append(None)
        else:
            out.append(rule.measurement(7, 1000 * k, m[0], m[1]))
        rule.end_epoch()
    return out


def test_lock_time_that_held_is_no_slip_a_restart_is() -> None:
    got = _lli([(5000, LOCKED, 0, 0), (6000, LOCKED, 0, 0), (7000, LOCKED, 0, 0)])
    assert got == [(LLI_SLIP, "acquired"), (0, None), (0, None)]
    # restarted just after the previous epoch: it held longer by the next (580 > 320) but by
    # less than the interval (RTKLIB's "lock time decreased" rule misses this one)
    got = _lli([(320, LOCKED, 0, 0), (580, LOCKED, 0, 0), (540, LOCKED, 0, 0)])
    assert got[1] == (LLI_SLIP, "restart") and got[2] == (LLI_SLIP, "restart")
    # saturated counter: holding at the maximum is holding
    got = _lli([(LOCK_MAX_MS, LOCKED, 0, 0), (LOCK_MAX_MS, LOCKED, 0, 0), (100, LOCKED, 0, 0)])
    assert got[1:] == [(0, None), (LLI_SLIP, "restart")]
    # one step (20 ms) short is the counter's resolution, two are a restart
    assert _lli([(1000, LOCKED, 0, 0), (1980, LOCKED, 0, 0)])[1] == (0, None)
    assert _lli([(1000, LOCKED, 0, 0), (1960, LOCKED, 0, 0)])[1] == (LLI_SLIP, "restart")


def test_no_usable_phase_at_the_previous_epoch_is_a_slip() -> None:
    got = _lli([(5000, LOCKED, 0, 0), None, (7000, LOCKED, 0, 0), (8000, LOCKED, 0, 0)])
    assert got[2] == (LLI_SLIP, "phase_gap") and got[3] == (0, None)
    got = _lli([(5000, LOCKED, 0, 0), None, (500, LOCKED, 0, 0)])
    assert got[2] == (LLI_SLIP, "restart")


def test_half_cycle_flag_and_its_resolution() -> None:
    ambiguous = PR_VALID | CP_VALID
    got = _lli([(1000, ambiguous, 0, 0), (2000, ambiguous, 0, 0),
                (3000, LOCKED | HALF_SUB, 0, 0), (4000, LOCKED | HALF_SUB, 0, 0)])
    assert got[0] == (LLI_SLIP | LLI_HALF_CYCLE, "acquired")
    assert got[1] == (LLI_HALF_CYCLE, None)
    # resolved: bit 1 clears, the half cycle is subtracted, the loop held: no bit 0
    assert got[2:] == [(0, None), (0, None)]
    # the subtracted half cycle put back while the flag stays valid: the phase jumped
    got = _lli([(1000, LOCKED | HALF_SUB, 0, 0), (2000, LOCKED, 0, 0)])
    assert got[1] == (LLI_SLIP, "half_cycle_jump")


def _rawx(tow_s: float, meas: list[dict[str, float | int]], week: int = WEEK) -> Frame:
    raw = L.RXM_RAWX.frame(meas, rcvTow=tow_s, week=week, leapS=18, recStat=1, version=1)
    return iter_frames(raw)[0]


def _meas(gnss: int, sv: int, trk: int, lock: int = 5000, sig: int = 0, cp_std: int = 1,
          pr: float = 2.1e7, cp: float = 1.1e8, do: float = -1234.5) -> dict[str, float | int]:
    return {"prMes": pr, "cpMes": cp, "doMes": do, "gnssId": gnss, "svId": sv, "sigId": sig,
            "locktime": lock, "cno": 44, "prStdev": 3, "cpStdev": cp_std, "doStdev": 5,
            "trkStat": trk}


def _frame(raw: bytes) -> Frame:
    return iter_frames(raw)[0]


def test_rawx_becomes_gps_l1_rxm_raw() -> None:
    frames = [
        _rawx(217330.99, [
            _meas(0, 3, LOCKED),
            _meas(0, 5, PR_VALID, cp_std=15),  # code only
            _meas(0, 9, CP_VALID),  # no valid pseudorange: not sent
            _meas(6, 4, LOCKED),  # GLONASS
            _meas(1, 120, LOCKED),  # SBAS
            _meas(0, 3, LOCKED, sig=3),  # GPS L2C
        ]),
        _rawx(217331.99, [_meas(0, 3, LOCKED, lock=6000), _meas(0, 5, LOCKED, lock=900)]),
    ]
    conv = convert_frames(frames)
    assert [name for _, name, _, _ in conv.messages] == ["RXM-RAW", "RXM-RAW"]
    dec = Decoder(raise_on_error=True)
    epochs = [dec.decode(_frame(raw)) for _, _, raw, _ in conv.messages]
    assert all(isinstance(e, RawEpoch) and e.source == "RXM-RAW" for e in epochs)
    first, second = epochs
    assert isinstance(first, RawEpoch) and isinstance(second, RawEpoch)
    assert first.tow_ns == 217_330_990_000_000 and first.gps_week == WEEK
    assert [(s.gnss, s.sv) for s in first.sats] == [(0, 3), (0, 5)]
    g3, g5 = first.sats
    assert (g3.carrier_phase_cyc, g3.pseudorange_m, g3.mes_qi, g3.lli) == (1.1e8, 2.1e7, 5, 1)
    assert g3.doppler_hz == pytest.approx(-1234.5) and g3.cno_dbhz == 44
    assert (g5.carrier_phase_cyc, g5.mes_qi, g5.lli) == (0.0, 4, 3)  # no carrier lock
    assert [(s.sv, s.lli, s.mes_qi) for s in second.sats] == [(3, 0, 7), (5, LLI_SLIP, 5)]
    st = conv.stats
    assert (st.gps_measurements, st.no_pseudorange, st.other_signals, st.phase_blank) == (
        5, 1, 3, 1)
    assert [(e.sv, e.kind) for e in conv.lock_events] == [(3, "acquired"), (5, "acquired")]


def test_time_off_the_millisecond_moved_along_the_doppler() -> None:
    shift_s = 0.4e-3  # rcvTow ...330.9896 goes to iTOW ...330.990
    conv = convert_frames([_rawx(217330.9896, [_meas(0, 3, LOCKED)])])
    rec = Decoder().decode(_frame(conv.messages[0][2]))
    assert isinstance(rec, RawEpoch) and rec.tow_ns == 217_330_990_000_000
    s = rec.sats[0]
    assert s.pseudorange_m == pytest.approx(2.1e7 + 1234.5 * L1_WAVELENGTH_M * shift_s, abs=1e-6)
    assert s.carrier_phase_cyc == pytest.approx(1.1e8 + 1234.5 * shift_s, abs=1e-6)
    assert conv.stats.time_moved_epochs == 1


def _ublox_words(data_words: tuple[int, ...]) -> tuple[int, ...]:
    """A subframe as u-blox 8 RXM-SFRBX carries it (offline/ephemeris.ublox_sfrbx_data_words
    reads it): data bits as broadcast before polarity, parity complemented after a D30 of 1."""
    d29 = d30 = 0
    out = []
    for d in data_words:
        par = lnav.parity_bits(d, d29, d30) ^ (0x3F if d30 else 0)
        out.append((d << 6) | par)
        d29, d30 = (par >> 1) & 1, par & 1
    return tuple(out)


def _sfrbx(gnss: int, sv: int, words: tuple[int, ...], chn: int = 4) -> Frame:
    return _frame(L.RXM_SFRBX.frame([{"dwrd": w} for w in words], gnssId=gnss, svId=sv,
                                    chn=chn, version=2))


def test_gps_sfrbx_becomes_sfrb_with_the_same_data_words(
    sim_ephemeris: BroadcastEphemeris,
) -> None:
    sf1, sf2, sf3 = encode_ephemeris(sim_ephemeris, WEEK, 216_000)
    broken = list(_ublox_words(sf2))
    broken[4] ^= 1 << 10  # one data bit flipped: parity fails
    frames = [_sfrbx(0, sim_ephemeris.sv, _ublox_words(sf1)),
              _sfrbx(0, sim_ephemeris.sv, tuple(broken)),
              _sfrbx(0, sim_ephemeris.sv, _ublox_words(sf3)),
              _sfrbx(6, 4, _ublox_words(sf1))]
    conv = convert_frames(frames)
    assert [name for _, name, _, _ in conv.messages] == ["RXM-SFRB", "RXM-SFRB"]
    recs = [Decoder().decode(_frame(raw)) for _, _, raw, _ in conv.messages]
    assert all(isinstance(r, Subframe) and r.source == "RXM-SFRB" for r in recs)
    assert [r.data_words() for r in recs if isinstance(r, Subframe)] == [sf1, sf3]
    assert [r.channel for r in recs if isinstance(r, Subframe)] == [4, 4]
    st = conv.stats
    assert (st.subframes_sent, st.subframes_parity_failed, st.subframes_other_systems) == (2, 1, 1)


@pytest.fixture
def sim_ephemeris() -> BroadcastEphemeris:
    t0 = WEEK * NS_PER_WEEK + 216_000 * 10**9
    return make_constellation(1, t0, t0 + 60 * 10**9, 8).ephemeris_at(3, t0)


def test_what_a_lea6t_does_not_send_and_what_it_sends_instead() -> None:
    pvt = L.NAV_PVT.frame(iTOW=1000, lon=-90578363, lat=532804499, height=66800, hMSL=10000,
                          hAcc=1500, vAcc=2500, fixType=3,
                          flags=L.NAV_PVT_FLAGS.compose(gnssFixOk=1))
    svinfo = L.NAV_SVINFO.frame(
        [{"chn": 0, "svid": 3, "cno": 40}, {"chn": 1, "svid": 70, "cno": 38},
         {"chn": 2, "svid": 131, "cno": 35}],
        iTOW=1000, globalFlags=L.NAV_SVINFO_GLOBAL.compose(chipGen=4))
    svin = build_frame(0x01, 0x3B, bytes(40))  # NAV-SVIN (u-blox 8 time mode): not a LEA-6T's
    frames = [_rawx(1.0, [_meas(0, 3, LOCKED)]), *iter_frames(pvt + svinfo + svin)]
    conv = convert_frames(frames)
    names = [name for _, name, _, _ in conv.messages]
    assert names == ["RXM-RAW", "NAV-POSLLH", "NAV-SVINFO"]
    dec = Decoder(raise_on_error=True)
    fix, info = (dec.decode(_frame(raw)) for _, _, raw, _ in conv.messages[1:])
    assert getattr(fix, "lat_deg", None) == pytest.approx(53.2804499)
    assert getattr(fix, "height_m", None) == pytest.approx(66.8)
    assert [s.sv for s in getattr(info, "sats", ())] == [3]
    assert L.NAV_SVINFO.unpack(iter_frames(conv.messages[2][2])[0].payload)[0][
        "globalFlags"] == 2
    assert conv.stats.not_sent == {"NAV-SVIN": 1}
    # with a NAV-POSLLH of its own the recording's NAV-PVT is not turned into a second one
    posllh = L.NAV_POSLLH.frame(iTOW=1000, lat=1, lon=2)
    conv = convert_frames([*iter_frames(pvt), *iter_frames(posllh)])
    assert [n for _, n, _, _ in conv.messages] == ["NAV-POSLLH"]
    assert conv.messages[0][2] == posllh
    # the original form keeps every frame as it was
    conv = convert_frames(frames, "original")
    assert [raw for _, _, raw, _ in conv.messages] == [f.raw for f in frames]
    assert [n for _, n, _, _ in conv.messages] == [message_name(f.cls, f.id) for f in frames]


def _flight(n: int = 240) -> list[Frame]:
    """``n`` 1 Hz epochs of 8 GPS and 8 GLONASS satellites, a mark (two records) every 2 s."""
    frames = []
    tm2 = L.TIM_TM2_FLAGS
    for k in range(n):
        t = 300_000.0 + k
        gps = [_meas(0, sv, LOCKED, lock=min(10_000 + 1000 * k, LOCK_MAX_MS))
               for sv in (2, 5, 8, 12, 15, 21, 24, 29)]
        glo = [_meas(6, sv, LOCKED) for sv in range(1, 9)]
        frames.append(_rawx(t, gps + glo))
        if k % 2 == 1:
            ms = round(t * 1000) - 880
            count = k // 2
            frames += iter_frames(
                L.TIM_TM2.frame(count=count, wnF=WEEK, towMsF=ms,
                                flags=tm2.compose(mode=1, run=1, timeBase=1, time=1,
                                                  newFallingEdge=1))
                + L.TIM_TM2.frame(count=count + 1, wnF=WEEK, towMsF=ms, wnR=WEEK,
                                  towMsR=ms + 14,
                                  flags=tm2.compose(mode=1, run=1, timeBase=1, time=1,
                                                    newRisingEdge=1)))
    return frames


def test_same_seed_same_damage_and_both_forms_get_the_same_outages() -> None:
    frames = _flight()
    seed = RewriteConfig(faults=FaultConfig.seed(), seed=4)
    a, b = replay_frames(frames, seed), replay_frames(frames, seed)
    assert a.data == b.data and a.log == b.log
    other = replay_frames(frames, RewriteConfig(faults=FaultConfig.seed(), seed=5))
    assert other.data != a.data
    lost = set(a.fault_log.epochs_lost_tow_ms)
    assert 10 < len(lost) < 60  # about 21 outages a minute, a third of them on an epoch
    # the RXM-RAWX of an epoch leaves the UART with the RXM-RAW's first byte and lasts longer:
    # every outage that cut the RXM-RAW also cut the RXM-RAWX
    orig = replay_frames(frames, RewriteConfig(form="original", faults=FaultConfig.seed(),
                                               seed=4))
    assert lost <= set(orig.fault_log.epochs_lost_tow_ms)
    starts = {f["start_gps_ns"] for f in a.log["faults"] if f["kind"] == "dropout"}
    assert starts <= {f["start_gps_ns"] for f in orig.log["faults"] if f["kind"] == "dropout"}
    # the mark faults too: the same marks missed and repeated
    def marks(log: dict[str, Any]) -> list[tuple[str, int]]:
        return [(f["kind"], f["count"]) for f in log["faults"]
                if f["kind"] in ("missed_mark", "duplicate_mark")]

    assert marks(a.log) == marks(orig.log) != []


def test_link_gaps_are_runs_of_lost_epochs() -> None:
    tags = [0, 1000, 2000, 3000, 4000, 5000, 6000]
    gaps = link_gaps(tags, {1000, 2000, 5000, 6000}, 1000)
    assert gaps == [
        {"after_tow_ms": 0, "before_tow_ms": 3000, "missing_epochs": 2, "duration_s": 3.0},
        {"after_tow_ms": 4000, "before_tow_ms": None, "missing_epochs": 2, "duration_s": 3.0},
    ]


def test_frames_that_do_not_fit_are_counted_not_fatal() -> None:
    good = _rawx(217331.0, [_meas(0, 3, LOCKED)])
    nan = _rawx(float("nan"), [_meas(0, 3, LOCKED)])
    huge = _rawx(1e300, [_meas(0, 3, LOCKED)])
    short = _frame(build_frame(0x02, 0x15, bytes(10)))  # RXM-RAWX shorter than its header
    conv = convert_frames([nan, huge, short, good])
    assert [n for _, n, _, _ in conv.messages] == ["RXM-RAW"]
    assert conv.stats.undecodable == {"RXM-RAWX": 3}
    assert conv.epoch_t_gps_ns == [WEEK * NS_PER_WEEK + 217_331 * 10**9]
    conv = convert_frames([nan, huge, short, good], "original")
    assert [raw for _, _, raw, _ in conv.messages] == [f.raw for f in (nan, huge, short, good)]
    assert conv.stats.undecodable == {"RXM-RAWX": 3} and len(conv.epoch_t_gps_ns) == 1


def test_a_recording_without_epochs_is_refused() -> None:
    from groundstation.errors import InputError

    with pytest.raises(InputError, match="no measurement epochs"):
        replay_frames(iter_frames(L.NAV_POSLLH.frame(iTOW=1)), source="x.ubx")
