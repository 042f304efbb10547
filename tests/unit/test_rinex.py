"""RINEX writer: RTKLIB's u-blox LLI/validity rules, epoch and event records, RINEX 2.11 layout,
navigation records, and the time-mark table, on synthetic messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from groundstation import gpstime
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.offline import rinex
from groundstation.offline.rinex import marks_table
from groundstation.records import TimeMark
from groundstation.rules import epochs as ep_rule
from groundstation.rules import marks as mk
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame
from groundstation.ubx.fastraw import decode_raw, decode_rawx, index_frames

WEEK = 2026
TOW0_S = 60000.0


def meas(
    sv: int = 5,
    *,
    gnss: int = 0,
    sig: int = 0,
    lock_ms: int = 10000,
    trk: int = 0x0F & ~0x08,
    cp: float = 1.0e8,
    pr: float = 2.0e7,
    cpstd: int = 2,
    cno: int = 40,
    freq: int = 0,
) -> bytes:
    return L.RXM_RAWX.row(
        prMes=pr, cpMes=cp, doMes=-100.5, gnssId=gnss, svId=sv, sigId=sig, freqId=freq,
        locktime=lock_ms, cno=cno, prStdev=3, cpStdev=cpstd, doStdev=1, trkStat=trk,
    )


def rawx(epochs: list[list[bytes]], version: int = 1, step_s: float = 0.2) -> bytes:
    out = []
    for k, ms in enumerate(epochs):
        head = L.RXM_RAWX.payload(rcvTow=TOW0_S + k * step_s, week=WEEK, leapS=18,
                                  numMeas=len(ms), recStat=1, version=version)
        out.append(build_frame(*L.RXM_RAWX.key, head + b"".join(ms)))
    return b"".join(out)


def obs_of(data: bytes) -> rinex.ObsSet:
    return rinex.obs_from_rawx(decode_rawx(data, index_frames(data)))


def lli_of(obs: rinex.ObsSet, sv: int = 5) -> list[int]:
    return [int(v) for v in obs.lli[obs.prn == sv]]


def test_lock_time_reset_and_decrease_are_slips() -> None:
    o = obs_of(rawx([[meas(lock_ms=1000)], [meas(lock_ms=1200)], [meas(lock_ms=0)],
                     [meas(lock_ms=400)], [meas(lock_ms=300)]]))
    assert lli_of(o) == [0, 0, 1, 0, 1]


def test_half_cycle_unresolved_only_on_valid_phase() -> None:
    o = obs_of(rawx([[meas(trk=0x03)], [meas(trk=0x01, lock_ms=10200)]]))
    assert lli_of(o) == [2, 0]
    assert o.cp_cyc[1] == 0.0


def test_half_cycle_subtracted_change_is_a_slip() -> None:
    o = obs_of(rawx([[meas(trk=0x07)], [meas(trk=0x0F, lock_ms=10200)],
                     [meas(trk=0x0F, lock_ms=10400)]]))
    assert lli_of(o) == [0, 1, 0]


def test_slip_during_blank_phase_is_carried_to_next_valid_phase() -> None:
    o = obs_of(rawx([[meas()], [meas(lock_ms=0, trk=0x01)], [meas(lock_ms=200, trk=0x01)],
                     [meas(lock_ms=400)], [meas(lock_ms=600)]]))
    assert lli_of(o) == [0, 0, 0, 1, 0]
    assert o.cp_cyc.tolist()[1:3] == [0.0, 0.0]


def test_cp_stdev_limits_gen8_then_gen9_and_slip_at_15() -> None:
    o = obs_of(rawx([[meas(cpstd=6)], [meas(cpstd=5, lock_ms=10200)],
                     [meas(cpstd=15, lock_ms=10400)]]))
    assert o.cp_cyc.tolist() == [0.0, 1.0e8, 0.0]
    assert lli_of(o) == [0, 0, 0]  # the cpStdev-15 slip waits for a valid phase
    # A second-band signal in an earlier message switches to the u-blox 9 limit (14).
    o9 = obs_of(rawx([[meas(cpstd=6), meas(sig=3)], [meas(cpstd=6, lock_ms=10200), meas(sig=3)]]))
    l1 = (o9.prn == 5) & (o9.code == "1C")
    assert o9.cp_cyc[l1].tolist() == [0.0, 1.0e8]


def test_invalid_pseudorange_and_phase_marker_are_blank() -> None:
    o = obs_of(rawx([[meas(trk=0x06, cp=-0.5)]]))
    assert o.pr_m.tolist() == [0.0]
    assert o.cp_cyc.tolist() == [0.0]


def test_codes_per_signal_and_systems() -> None:
    o = obs_of(rawx([[meas(3), meas(3, sig=3), meas(11, gnss=2, sig=0), meas(11, gnss=2, sig=5),
                      meas(4, gnss=6, sig=2, freq=9), meas(1, gnss=5), meas(7, gnss=3, sig=2),
                      meas(255, gnss=6), meas(33, gnss=0), meas(9, gnss=7)]]))
    got = sorted(zip(o.sys.tolist(), o.prn.tolist(), o.code.tolist(), strict=True))
    assert got == [("C", 7, "7I"), ("E", 11, "1C"), ("E", 11, "7I"), ("G", 3, "1C"),
                   ("G", 3, "2L"), ("J", 1, "1C"), ("R", 4, "2C")]
    assert o.glo_fcn == {4: 2}


def test_bds_geo_phase_half_cycle_shift_and_week_zero_skipped() -> None:
    data = rawx([[meas(3, gnss=3)], [meas(3, gnss=3, lock_ms=10200)]])
    zero = L.RXM_RAWX.frame(rcvTow=18.0, version=1)
    o = obs_of(zero + data)
    assert o.t_gps_ns.size == 2
    assert o.cp_cyc.tolist() == [1.0e8 + 0.5, 1.0e8 + 0.5]


def test_rxm_raw_lli_as_sent_with_slip_carried_over_blank_phase() -> None:
    def raw_msg(itow: int, cp: float, lli: int) -> bytes:
        sv = {"cpMes": cp, "prMes": 2.0e7, "doMes": 1.0, "sv": 26, "mesQI": 7, "cno": 45,
              "lli": lli}
        return L.RXM_RAW.frame([sv], iTOW=itow, week=1481)

    data = b"".join(
        raw_msg(1000 * k, cp, lli)
        for k, (cp, lli) in enumerate([(1e8, 0), (0.0, 3), (1e8, 2), (1e8, 2)])
    )
    o = rinex.obs_from_raw(decode_raw(data, index_frames(data)))
    assert o.lli.tolist() == [0, 3, 3, 2]


def _write(tmp_path: Path, obs: rinex.ObsSet, events: list[int], version: str) -> str:
    p = tmp_path / f"x{version}.obs"
    rinex.write_obs(p, obs, events, rinex.HeaderInfo(marker="M1"), version, 200_000_000)
    return p.read_text()


def test_obs_v3_epochs_events_and_values(tmp_path: Path) -> None:
    o = obs_of(rawx([[meas(5), meas(12, lock_ms=0)], [meas(5, lock_ms=10200)], [meas(5)]]))
    t0 = int(o.t_gps_ns[0])
    # Two marks between epochs 0 and 1, one exactly at epoch 2.
    events = [t0 + 50_000_000, t0 + 123_456_789, t0 + 400_000_000]
    text = _write(tmp_path, o, events, "3.04")
    types, epochs = rinex.read_obs3(tmp_path / "x3.04.obs")
    assert types == {"G": ["C1C", "L1C", "D1C", "S1C"]}
    assert [e.flag for e in epochs] == [0, 5, 5, 0, 5, 0]
    assert epochs[2].time == "2018 11 04 16 40 00.1234568"
    assert epochs[0].sats["G12"]["L1C"] == ("100000000.000", "1")
    assert epochs[0].sats["G05"]["C1C"] == ("20000000.000", "")
    assert "G05  20000000.000 6 100000000.000 6      -100.500          40.000" in text
    assert "TIME OF FIRST OBS" in text and "GLONASS" not in text
    for label in ("MARKER NAME", "REC # / TYPE / VERS", "APPROX POSITION XYZ", "INTERVAL",
                  "TIME OF LAST OBS", "SYS / PHASE SHIFT", "END OF HEADER"):
        assert label in text
    assert all(len(line) <= 80 for line in text.split("END OF HEADER")[0].splitlines())


@pytest.mark.parametrize("block", [1, 2, 1 << 16])
def test_obs_v3_events_before_between_at_and_after_epochs_in_any_block(
    tmp_path: Path, block: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The numpy-assembled epochs (obs_writer._write_v3_single): events before the first
    epoch, between, at and after the last, blocks cut anywhere; text equal to the one
    epoch_line and the satellite lines give one by one."""
    from groundstation.offline.rinex import format as fmt
    from groundstation.offline.rinex import obs_writer

    monkeypatch.setattr(obs_writer, "FORMAT_BLOCK", block)
    o = obs_of(rawx([[meas(5), meas(12)], [], [meas(5)], [meas(5), meas(7), meas(9)]]))
    t = sorted(set(o.t_gps_ns.tolist()))
    events = [t[0] - 5, t[0], t[1] + 1, t[1] + 2, t[-1], t[-1] + 10**9, t[-1] + 2 * 10**9]
    text = _write(tmp_path, o, events, "3.04")
    body = text.split("END OF HEADER")[1].split("\n", 1)[1]
    expect: list[str] = []
    rows = {r: o.epoch == r for r in range(o.t_gps_ns.size)}
    for tt in sorted(set(events) | set(t)):
        expect += [fmt.epoch_line(e, 5, 0, True, []) for e in events if e == tt]
        for r, sel in rows.items():
            if int(o.t_gps_ns[r]) == tt and sel.any():
                idx = np.flatnonzero(sel)[np.argsort(o.prn[sel], kind="stable")]
                expect.append(fmt.epoch_line(tt, 0, idx.size, True, []))
                expect.append(fmt.sat_lines(o, idx, fmt.format_matrix(o, idx)))
    assert body == "".join(expect)


def test_obs_v211_layout(tmp_path: Path) -> None:
    sats = [meas(sv) for sv in range(1, 15)] + [meas(3, sig=3), meas(4, gnss=3)]
    o = obs_of(rawx([sats]))
    text = _write(tmp_path, o, [int(o.t_gps_ns[0]) - 1000], "2.11")
    header, body = text.split("END OF HEADER")
    body = body.split("\n", 1)[1]
    assert "     2.11           OBSERVATION DATA    G: GPS" in header
    assert "     8    C1    L1    D1    S1    C2    L2    D2    S2      # / TYPES OF OBS" in header
    lines = body.splitlines()
    assert lines[0] == " 18 11  4 16 39 59.9999990  5  0"
    assert lines[1].startswith(" 18 11  4 16 40  0.0000000  0 14G01G02")
    assert lines[2].startswith(" " * 32 + "G13G14")
    # G03 has L1 and L2: two 80-column lines; BeiDou is not RINEX 2.11 and is left out.
    assert len([ln for ln in lines[3:] if ln]) == 14 + 1
    assert "C04" not in body


def test_nav_record_round_trip(tmp_path: Path) -> None:
    eph = BroadcastEphemeris(
        sv=7, week=2026, toc_s=64800.0, af0_s=-1.5e-4, af1_s_s=2.2e-12, af2_s_s2=0.0, iodc=33,
        iode=33, tgd_s=-1.1e-8, ura_index=0, health=0, code_on_l2=1, l2p_data_flag=0,
        fit_interval_flag=0, toe_s=64800.0, sqrt_a_sqrt_m=5153.6, e=0.01, i0_rad=0.96,
        omega0_rad=-2.3, omega_rad=1.2, m0_rad=0.5, delta_n_rad_s=4.5e-9,
        omega_dot_rad_s=-8.1e-9, idot_rad_s=1.7e-10, cuc_rad=-3.3e-6, cus_rad=8.4e-6,
        crc_m=213.6, crs_m=-66.8, cic_rad=-6.3e-8, cis_rad=1.7e-7, tow_s=57600.0,
    )
    p = tmp_path / "n.nav"
    assert rinex.write_nav(p, [eph], "3.04", 18) == 1
    lines = p.read_text().split("END OF HEADER")[1].splitlines()[1:]
    assert lines[0].startswith("G07 2018 11 04 18 00 00-1.500000000000E-04")
    vals = [float(ln[4 + 19 * k : 4 + 19 * (k + 1)]) for ln in lines[1:8] for k in range(4)
            if len(ln) >= 4 + 19 * (k + 1)]
    assert vals[0] == 33 and vals[3] == 0.5 and vals[7] == 5153.6 and vals[8] == 64800.0
    assert vals[18] == 2026 and vals[20] == 2.4 and vals[24] == 57600.0 and vals[25] == 4.0


def _tm(count: int, fall_s: float | None, rise_s: float | None, nf: bool, nr: bool) -> TimeMark:
    def ns(s: float | None) -> int | None:
        return None if s is None else gpstime.gps_ns(WEEK, round(s * 1e9))

    flags = 0x41 | 0x08 | (0x04 if nf else 0) | (0x80 if nr else 0)
    return TimeMark(1, count, ns(rise_s), ns(fall_s), nr, nf, 1, True, 20, 0, flags=flags)


def test_marks_pairing_events_and_dropouts() -> None:
    # ``count`` counts rising edges, as in the real logs: a falling-edge record carries the
    # count so far, the rising-edge record the count including its own edge.
    recs = [
        _tm(5, None, 59999.9, False, True),  # rising edge of a pulse begun before logging
        _tm(5, 60000.10, 59999.9, True, False),
        _tm(6, 60000.10, 60000.114, False, True),
        _tm(6, 60000.10, 60000.114, False, False),  # repeated record: nothing new
        _tm(6, 60000.15, 60000.114, True, False),  # two marks inside one 0.2 s epoch
        _tm(7, 60000.15, 60000.164, False, True),
        _tm(9, 60003.30, 60000.164, True, False),  # pulses 8 and 9 lost; no rising edge yet
    ]
    marks = mk.build_marks(recs)
    assert len(marks) == 4
    assert marks[0].falling_t_gps_ns is None
    assert marks[1].pulse_ns == 14_000_000
    assert marks[3].lost_before == 2 and marks[3].rising_t_gps_ns is None
    base = gpstime.gps_ns(WEEK, 0)
    fall = [round((t - base) / 1e6) for t in mk.event_times_ns(marks, "falling", 1_000_000)]
    assert fall == [60_000_101, 60_000_151, 60_003_301]
    assert len(mk.event_times_ns(marks, "both")) == 6
    assert len(mk.event_times_ns(marks, "rising")) == 3
    mids = mk.event_times_ns(marks, "mid")
    assert [(t - base) // 1_000_000 for t in mids] == [60_000_107, 60_000_157]
    epochs = [gpstime.gps_ns(WEEK, round(s * 1e9)) for s in (59999.8, 60000.0, 60000.2, 60003.4)]
    assert ep_rule.nominal_interval_ns(epochs) == 200_000_000
    where = [ep_rule.locate(mk.mark_time_ns(m, "falling") or 0, epochs, 200_000_000) for m in marks]
    assert [(w.in_dropout, w.outside) for w in where] == [
        (False, True), (False, False), (False, False), (True, False)]
    table = marks_table.marks_csv(marks, epochs, "falling").splitlines()
    assert table[0].split(",") == list(marks_table.CSV_COLUMNS)
    row = dict(zip(marks_table.CSV_COLUMNS, table[2].split(","), strict=True))
    assert row["falling_gps_tow_s"] == "60000.100000000"
    assert row["falling_utc"] == "2018-11-04T16:39:42.100000000Z"
    assert row["pulse_ms"] == "14.000000" and row["in_dropout"] == "0"


def _flight_with_one_mark(tmp_path: Path) -> Path:
    """Three RXM-RAWX epochs with one TIM-TM2 mark between the second and the third."""
    recs = rawx([[meas(5)], [meas(5, lock_ms=10200)], [meas(5, lock_ms=10400)]])
    tm = L.TIM_TM2.frame(
        flags=0x4D | 0x80, count=1, wnR=WEEK, wnF=WEEK, towMsR=60000_210, towSubMsR=5,
        towMsF=60000_200, towSubMsF=7, accEst=9,
    )
    src = tmp_path / "flight.ubx"
    cut = len(recs) // 3 * 2
    src.write_bytes(recs[:cut] + tm + recs[cut:])
    return src


@pytest.mark.parametrize("edge", mk.MARK_EDGES)
def test_convert_accepts_every_edge_choice(tmp_path: Path, edge: mk.MarkEdge) -> None:
    src = _flight_with_one_mark(tmp_path)
    res = rinex.convert(src, tmp_path / "out", rinex.RinexOptions(marks=edge))
    assert res.epochs == 3 and res.marks == 1
    assert res.events == (2 if edge == "both" else 1)
    assert res.obs_path.name == "flight.obs" and res.nav_path.exists() and res.marks_path.exists()
    assert np.isclose(res.ephemerides, 0)


def test_convert_without_events_keeps_the_marks(tmp_path: Path) -> None:
    src = _flight_with_one_mark(tmp_path)
    res = rinex.convert(src, tmp_path / "out", rinex.RinexOptions(events=False))
    assert res.epochs == 3 and res.marks == 1 and res.events == 0
    _, epochs = rinex.read_obs3(res.obs_path)
    assert len(epochs) == 3 and all(ep.flag == 0 for ep in epochs)
    assert len(res.marks_path.read_text().splitlines()) == 2  # the header and the mark


def test_events_after_a_change_of_the_epochs_spacing() -> None:
    """RTKLIB's reader drops the epoch after an event when its spacing from the epoch before
    differs from that epoch's own: after a gap, and at the first epoch after one."""
    s = 1_000_000_000
    epochs = [t * s for t in (0, 1, 2, 3, 6, 7, 8, 9)]  # epochs 4 and 5 lost
    events = [t * s // 2 for t in (1, 5, 10, 13, 17)]  # 0.5, 2.5, 5, 6.5, 8.5 s
    # 0.5 s: nothing before to compare; 2.5: 1 s after 1 s; 5: 3 s after 1 s (the gap);
    # 6.5: 1 s after 3 s; 8.5: 1 s after 1 s
    assert rinex.events_after_spacing_change(epochs, events) == 2
    jitter = [e + 10_000_000 * (k % 2) for k, e in enumerate(epochs[:4])]  # 20 ms < 25
    assert rinex.events_after_spacing_change(jitter, events[:2]) == 0
    assert rinex.events_after_spacing_change(epochs[:2], events) == 0


def test_vectorised_field_formatting_equals_python_formatting() -> None:
    import numpy as np

    from groundstation.offline.rinex.format import f14_3 as _f14_3
    from groundstation.offline.rinex.format import format_chunk_exact as _format_chunk_exact

    rng = np.random.default_rng(3)
    edge = [0.0005, 0.0015, -0.0004, -0.0005, 2.0005, 999999999.9994, -99999999.9996, 1e-9,
            999999999.9996, 99999999.9996, 9.9996,
            123456.7895, 0.5, -1.0, 20_000_000.0625, 21_345_678.12349999, 7.0]
    values = np.concatenate([
        np.array(edge),
        rng.uniform(-3e8, 3e8, 20_000),
        rng.uniform(-5e3, 5e3, 20_000),
        np.round(rng.uniform(-1e7, 1e7, 5_000), 4),  # many exact ties at the 4th decimal
    ])
    digits, unsure = _f14_3(values)
    got = [row.tobytes().decode() for row in digits]
    for v, g, u in zip(values.tolist(), got, unsure.tolist(), strict=True):
        if not u:
            assert g == f"{v:14.3f}", (v, g)
    assert unsure.mean() < 0.2
    assert _format_chunk_exact(21e6, 0.0, 1.5, 40.0, 2, 6) == (
        f"{21e6:14.3f} 6" + " " * 14 + "2 " + f"{1.5:14.3f}  " + f"{40.0:14.3f}  "
    )


def test_lost_falling_record_is_recovered_from_the_rising_record() -> None:
    recs = [
        _tm(0, 60000.10, None, True, False),
        _tm(1, 60000.10, 60000.114, False, True),
        # pulse 2's falling-edge record lost on the link; its rising record repeats the edge
        _tm(2, 60001.10, 60001.114, False, True),
        _tm(2, 60002.10, 60001.114, True, False),
        _tm(3, 60002.10, 60002.114, False, True),
    ]
    marks = mk.build_marks(recs)
    assert [m.pulse_ns for m in marks] == [14_000_000] * 3
    assert [m.lost_before for m in marks] == [0, 0, 0]


def test_long_header_comments_go_on_over_several_comment_lines(tmp_path: Path) -> None:
    """A COMMENT's text is 60 characters: a longer one (the LLI legend) was cut off at
    "half cycle unr"; it is wrapped at spaces now, every other header line unchanged."""
    from groundstation.offline.rinex.format import wrap_comment

    src = tmp_path / "flight.ubx"
    src.write_bytes(rawx([[meas(5)], [meas(5, lock_ms=10200)], [meas(5, lock_ms=10400)]]))
    res = rinex.convert(src, tmp_path / "out")
    header = res.obs_path.read_text().split("END OF HEADER")[0].splitlines()
    comments = [ln[:60].rstrip() for ln in header if ln[60:].strip() == "COMMENT"]
    assert all(len(ln) == 80 for ln in header if ln[60:].strip() == "COMMENT")
    text = " ".join(comments)
    assert "LLI bit 0 slip, bit 1 half cycle unresolved" in text, comments
    assert "events (flag 5): falling edge + shutter delay 0 ms" in text, comments
    assert wrap_comment("short") == ["short"] and wrap_comment("") == [""]
    assert all(len(p) <= 60 for p in wrap_comment("word " * 40))
