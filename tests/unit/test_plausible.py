"""The plausibility rule (rules/plausible.py): which epochs, marks and fixes can belong to a
session; its streaming form (the decoder) and its bulk form (fastraw, RINEX) give the same
verdicts, on crafted sequences and on streams with frames that passed their checksum by chance."""

from __future__ import annotations

import random
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from real_files import REAL_UBX_FILES
from streams import TOW0_MS, WEEK, flight_stream, rxm_raw, t_gps_ns, tim_tm2

from groundstation import messages
from groundstation.gpstime import NS_PER_S, NS_PER_WEEK, gps_to_unix_ns
from groundstation.offline.inspect import inspect_path
from groundstation.offline.rinex.convert import observations_of, read_frames, time_marks_of
from groundstation.records import RawEpoch, TimeMark, UndecodedFrame
from groundstation.rules import plausible as P
from groundstation.ubx import layouts as L
from groundstation.ubx.build import build_frame
from groundstation.ubx.decode import Decoder
from groundstation.ubx.fastraw import (
    decode_raw,
    decode_rawx,
    index_frames,
    index_timed_chunks,
    plausible_epochs,
)
from groundstation.ubx.framer import UbxFramer

SATS = [(3, 0), (7, 0), (11, 0)]
NOW = gps_to_unix_ns(t_gps_ns(WEEK + 10, 0))  # the host's clock: ten weeks after the data
S = NS_PER_S


def epoch_t(k: int, week: int = WEEK) -> int:
    return t_gps_ns(week, TOW0_MS + 200 * k)


def verdicts(times: list[int], host: list[int] | None = None) -> list[str | None]:
    clock = P.SessionClock(NOW)
    return [clock.epoch(t, host[i] if host else 0) for i, t in enumerate(times)]


# -- the rule, one case at a time ---------------------------------------------------------------


@pytest.mark.parametrize("ahead_ns", [
    86_400 * S, NS_PER_WEEK, 3600 * S, -3600 * S, 61 * S,
], ids=["a_day", "a_week", "an_hour", "an_hour_back", "61_s"])
def test_a_lone_epoch_off_the_clock_is_refused_and_its_neighbours_kept(ahead_ns: int) -> None:
    times = [epoch_t(k) for k in range(10)]
    times.insert(5, epoch_t(5) + ahead_ns)
    got = verdicts(times)
    assert [k for k, v in enumerate(got) if v is not None] == [5]
    assert "from the session's clock" in str(got[5])


def test_a_jump_confirmed_by_the_next_epoch_moves_the_clock() -> None:
    times = [epoch_t(k) for k in range(5)] + [epoch_t(k, WEEK + 1) for k in range(5, 10)]
    clock = P.SessionClock(NOW)
    got = [clock.epoch(t, 0) for t in times]
    assert [k for k, v in enumerate(got) if v is not None] == [5]  # the first after the jump
    assert clock.jumps == [P.Jump(epoch_t(4), epoch_t(6, WEEK + 1), epoch_t(5, WEEK + 1))]


@pytest.mark.parametrize("timed", [False, True], ids=["ubx", "host_times"])
def test_a_burst_of_chance_frames_that_agree_with_each_other_does_not_move_the_clock(
    timed: bool,
) -> None:
    h0 = NOW - 3600 * S
    times, host = [], []
    for k in range(10):
        times.append(epoch_t(k))
        host.append(h0 + k * S // 5)
        if k == 4:  # three frames of one burst: a minute ahead, 2 s apart
            times += [epoch_t(k) + 59 * S, epoch_t(k) + 61 * S, epoch_t(k) + 63 * S]
            host += [host[-1]] * 3
    clock = P.SessionClock(NOW)
    got = [clock.epoch(t, host[i] if timed else 0) for i, t in enumerate(times)]
    refused = [k for k, v in enumerate(got) if v is not None]
    assert clock.state is not None and clock.state.t_gps_ns == epoch_t(9)
    assert not clock.jumps
    if timed:  # the host clock says no time went by: all three refused
        assert refused == [5, 6, 7]
    else:  # a minute is allowed without host times: taken, then found odd by the next epoch
        assert refused == [] and sorted(clock.refuted) == times[5:8]


def test_two_chance_frames_one_interval_apart_in_one_burst_confirm_nothing() -> None:
    """Their GPS times follow as a receiver's would (found by the fuzz run: a field shifted
    twice, by ten minutes and by 0.2 s), but they arrived together."""
    h0 = NOW - 3600 * S
    times = [epoch_t(k) for k in range(5)] + [epoch_t(4) + 600 * S, epoch_t(5) + 600 * S]
    host = [h0 + k * S // 5 for k in range(5)] + [h0 + S, h0 + S]
    times += [epoch_t(5), epoch_t(6)]
    host += [h0 + S + S // 5, h0 + S + 2 * S // 5]
    clock = P.SessionClock(NOW)
    got = [clock.epoch(t, h) for t, h in zip(times, host, strict=True)]
    assert [k for k, v in enumerate(got) if v is not None] == [5, 6] and not clock.jumps


def test_an_odd_epoch_within_the_allowance_gives_way_to_the_next() -> None:
    clock = P.SessionClock(NOW)
    times = [epoch_t(0), epoch_t(1), epoch_t(2) + 50 * S, epoch_t(3), epoch_t(4)]
    assert [clock.epoch(t, 0) for t in times] == [None] * 5  # 50 s ahead: within the minute
    assert clock.state is not None and clock.state.t_gps_ns == epoch_t(4) and not clock.jumps
    assert clock.refuted == [epoch_t(2) + 50 * S]  # readers that collect epochs drop it


def test_an_epoch_a_little_behind_the_clock_refutes_nothing() -> None:
    clock = P.SessionClock(NOW)
    times = [epoch_t(0), epoch_t(1), epoch_t(2), epoch_t(2) - S // 2, epoch_t(3), epoch_t(3)]
    assert [clock.epoch(t, 0) for t in times] == [None] * 6  # behind both: a repeat, kept
    assert clock.refuted == []


def test_a_false_first_epoch_is_replaced_by_the_next_two_that_agree() -> None:
    times = [epoch_t(0, 1500)] + [epoch_t(k) for k in range(1, 8)]
    clock = P.SessionClock(NOW)
    got = [clock.epoch(t, 0) for t in times]
    assert got[0] is None and got[1] is not None and got[2:] == [None] * 6
    assert clock.state is not None and clock.state.t_gps_ns == epoch_t(7)
    assert len(clock.jumps) == 1


def test_a_first_epoch_far_after_the_host_clock_needs_the_next_to_confirm_it() -> None:
    behind = gps_to_unix_ns(epoch_t(0)) - P.HOST_CLOCK_SLACK_NS - 3600 * S  # a clock from 2005
    clock = P.SessionClock(behind)
    got = [clock.epoch(epoch_t(k), 0) for k in range(4)]
    assert got[0] is not None and "after the host's clock" in got[0]
    assert got[1:] == [None, None, None]
    assert clock.jumps[0].from_t_gps_ns is None


def test_a_week_4000_first_epoch_is_refused_by_the_host_clock() -> None:
    got = verdicts([epoch_t(0, 4000)] + [epoch_t(k) for k in range(1, 4)])
    assert got[0] is not None and got[1:] == [None, None, None]


def test_with_host_times_a_gap_is_what_the_host_clock_says_went_by() -> None:
    h0 = NOW - 3600 * S
    times = [epoch_t(0), epoch_t(1), epoch_t(1) + 1800 * S, epoch_t(1) + 1800 * S + 40 * S]
    host = [h0, h0 + S // 5, h0 + S // 5 + 1800 * S, h0 + S // 5 + 1800 * S + S // 5]
    got = verdicts(times, host)
    # half an hour of silence on the host's clock too: taken at once; 40 s on 0.2 s: refused
    assert got[:3] == [None, None, None] and got[3] is not None


def test_a_slow_receiver_costs_one_epoch_then_its_interval_sets_the_allowance() -> None:
    times = [t_gps_ns(WEEK, TOW0_MS + 120_000 * k) for k in range(8)]  # every 2 min
    got = verdicts(times)
    assert [k for k, v in enumerate(got) if v is not None] == [1]


def test_marks_new_edges_near_the_clock_repeated_edges_not_after_it() -> None:
    clock = P.SessionClock(NOW)
    assert clock.epoch(epoch_t(100), 0) is None
    near, old = epoch_t(100) + S // 10, epoch_t(100) - 3600 * S
    assert clock.mark(((near, True), (old, False)), 0) is None  # a pulse an hour ago repeated
    assert clock.mark(((old, True), (None, False)), 0) is not None  # an hour-old edge is not new
    assert clock.mark(((near, True), (near + 86_400 * S, False)), 0) is not None  # the future
    assert clock.mark(((None, False), (None, False)), 0) is None


def test_fixes_with_a_time_of_week_only_wrap_at_the_week() -> None:
    clock = P.SessionClock(NOW)
    assert clock.epoch(t_gps_ns(WEEK, 604_799_800), 0) is None
    assert clock.fix(0, 0, None, 0) is None  # 0.2 s later, in the next week
    assert clock.fix(302_400_000, 0, None, 0) is not None  # half a week off
    assert clock.fix(604_800_000, 0, None, 0) is not None  # out of range
    assert clock.fix(604_799_800, 600_000, None, 0) is not None  # fTOW beyond 0.5 ms
    assert clock.fix(604_799_800, 0, WEEK, 0) is None
    assert clock.fix(604_799_800, 0, 32767, 0) is not None


def test_ranges() -> None:
    assert P.week_problem(-1) and P.week_problem(0) and P.week_problem(P.MAX_WEEK + 1)
    assert P.week_problem(1) and P.week_problem(1023)
    assert P.week_problem(1024) is None and P.week_problem(P.MAX_WEEK) is None
    assert (P.MAX_WEEK + 1) * NS_PER_WEEK <= P.MAX_T_GPS_NS == messages.MAX_TIME_NS
    assert P.tow_ms_problem(2**31 - 1) and P.tow_ms_problem(604_800_000) and P.tow_ms_problem(-1)
    assert P.tow_s_problem(float("nan")) and P.tow_s_problem(float("inf"))
    assert P.tow_s_problem(604_799.999) is None
    assert P.sub_ms_problem(1_000_000) and P.sub_ms_problem(999_999) is None
    assert P.leap_problem(18, epoch_t(0)) is None and P.leap_problem(100, epoch_t(0))
    assert P.leap_problem(15, t_gps_ns(1700, 0)) is None  # 2012: GPS - UTC was 15 s
    assert P.edge_range_problem(0, 0, 0) is None and P.edge_range_problem(65535, 1, 0)
    for bad in ((float("nan"), 1.0, 2.0), (1.0, float("inf"), 2.0), (1e308, 1e308, 0.0),
                (2e9, 1e8, 0.0), (2e7, 2e10, 0.0), (2e7, 1e8, -2e6)):
        assert not P.measurement_ok(*bad)
        assert not P.measurement_rows(*(np.array([v]) for v in bad))[0]
    assert P.measurement_ok(4.2e7, 2.2e8, -5600.0)
    assert P.measurement_rows(*(np.array([v]) for v in (4.2e7, 2.2e8, -5600.0)))[0]


# -- streaming and bulk forms give the same verdicts --------------------------------------------


def random_sequence(rng: random.Random, n: int) -> tuple[list[int], list[int], list[int]]:
    """Weeks, times of week and host times of a stream with gaps, jumps, repeats, false frames."""
    weeks, tows, hosts = [], [], []
    t = t_gps_ns(WEEK, TOW0_MS)
    h = NOW - 7200 * S
    timed = rng.random() < 0.5
    for _ in range(n):
        r = rng.random()
        step = 200_000_000
        if r < 0.05:
            step = rng.choice((2, 30, 59, 61, 120, 3600, 86_400)) * S
        t += step
        h += step + rng.randint(-50, 50) * 1_000_000
        wt, ht = t, h
        if r > 0.9:  # a false frame: random week, time or host
            wt = t + rng.choice((-1, 1)) * rng.choice((S, 30 * S, 3600 * S, NS_PER_WEEK))
        if r > 0.97:
            weeks.append(rng.choice((0, -1, 32767, 65535, P.MAX_WEEK + 1)))
            tows.append(rng.randrange(0, NS_PER_WEEK))
        elif rng.random() < 0.02:  # a repeat
            weeks.append(weeks[-1] if weeks else WEEK)
            tows.append(tows[-1] if tows else 0)
        else:
            weeks.append(wt // NS_PER_WEEK)
            tows.append(wt % NS_PER_WEEK)
        hosts.append(ht if timed else 0)
    return weeks, tows, hosts


def streaming(weeks: list[int], tows: list[int], hosts: list[int]) -> tuple[
        list[bool], list[P.ClockState | None]]:
    clock = P.SessionClock(NOW)
    ok: list[bool] = []
    states = []
    taken: list[int] = []
    for k, (w, tow, h) in enumerate(zip(weeks, tows, hosts, strict=True)):
        if P.week_problem(w) is not None and w != 0:
            ok.append(False)
        elif w == 0:
            ok.append(True)
        else:
            refuted, jumps = len(clock.refuted), len(clock.jumps)
            ok.append(clock.epoch(w * NS_PER_WEEK + tow, h) is None)
            if ok[-1]:
                for _ in range(len(clock.refuted) - refuted):  # the epochs taken were odd
                    ok[taken.pop()] = False
                if len(clock.jumps) != jumps:
                    taken.clear()
                taken.append(k)
        states.append(clock.state)
    return ok, states


@pytest.mark.parametrize("seed", range(40))
def test_streaming_and_bulk_verdicts_agree(seed: int) -> None:
    rng = random.Random(seed)
    weeks, tows, hosts = random_sequence(rng, rng.choice((5, 50, 400)))
    ok, states = streaming(weeks, tows, hosts)
    static = {k: "x" for k, w in enumerate(weeks) if w != 0 and P.week_problem(w) is not None}
    v = P.epoch_verdicts(np.array(weeks, dtype=np.int64), np.array(tows, dtype=np.int64), static,
                         np.array(hosts, dtype=np.int64), NOW)
    assert v.ok.tolist() == ok
    assert [v.state_after(k) for k in range(len(weeks))] == states


def test_bulk_fast_path_on_a_clean_sequence_equals_streaming() -> None:
    weeks = [WEEK] * 300 + [0] * 3 + [WEEK] * 300
    tows = [TOW0_MS * 1_000_000 + 200_000_000 * k for k in range(603)]
    hosts = [NOW - 600 * S + 200_000_000 * k for k in range(603)]
    ok, states = streaming(weeks, tows, hosts)
    v = P.epoch_verdicts(np.array(weeks), np.array(tows), {}, np.array(hosts), NOW)
    assert all(ok) and v.ok.all() and not v.jumps
    assert [v.state_after(k) for k in range(603)] == states


# -- the decoder and the bulk decoder, on whole streams ------------------------------------------


def fuzz_frames(rng: random.Random, k: int) -> Iterator[bytes]:
    """Frames with valid checksums and times that cannot belong to the session (and some that
    can), as a lossy radio's chance frames would be, around epoch ``k``."""
    tow = TOW0_MS + 200 * k
    yield rxm_raw(rng.choice((32767, -1, 4000, WEEK + 1, WEEK - 1)), tow, SATS)
    yield rxm_raw(WEEK, rng.choice((2**31 - 1, 604_800_000, tow + 86_400_000, tow + 150)), SATS)
    yield L.RXM_RAWX.frame([], rcvTow=rng.choice((float("nan"), float("inf"), 1e300,
                                                  tow / 1000 + 0.1)),
                           week=rng.choice((WEEK, 65535)), leapS=18, recStat=1, version=1)
    yield tim_tm2(rng.randrange(65536), rng.choice((WEEK, 65535, 0)), tow + 10, 0,
                  rng.choice((None, tow + 20)))
    yield tim_tm2(7, WEEK, tow + 86_400_000, 0, None)
    yield L.RXM_RAWX.frame([], rcvTow=tow / 1000 + 0.05, week=WEEK, leapS=rng.choice((18, 100, -5)),
                           recStat=1, version=1)
    yield L.NAV_SOL.frame(iTOW=rng.choice((tow, 2**31, tow + 3_600_000)), fTOW=0,
                          week=rng.choice((WEEK, 32767)), flags=0x0D, gpsFix=3)
    yield L.NAV_PVT.frame(iTOW=rng.choice((tow, 604_800_001, tow - 7_200_000)))
    payload = bytearray(L.RXM_RAW.payload(
        [{"cpMes": 1.0, "prMes": 2.0, "doMes": 3.0, "sv": 5}], iTOW=tow + 100, week=WEEK))
    struct.pack_into("<d", payload, 8, rng.choice((float("nan"), float("-inf"))))
    yield build_frame(0x02, 0x10, bytes(payload))


def fuzzed_stream(seed: int) -> bytes:
    rng = random.Random(seed)
    _, frames = flight_stream(120, drop_epochs={40, 41, 42, 90}, mark_every=4)
    out: list[bytes] = []
    k = 0
    for f in frames:
        out.append(f)
        if f[2:4] == b"\x02\x10":
            k += 1
            if rng.random() < 0.3:
                out.extend(rng.sample(list(fuzz_frames(rng, k)), 2))
    return b"".join(out)


def decode_streaming(data: bytes, chunk: int, host0: int | None) -> tuple[
        list[int], list[TimeMark], dict[str, int]]:
    framer, decoder = UbxFramer(), Decoder(now_ns=NOW)
    epochs: list[int] = []
    marks: list[TimeMark] = []
    for i in range(0, len(data), chunk):
        t = host0 + i * 1000 if host0 is not None else 0
        for frame in framer.feed(data[i : i + chunk], t):
            rec = decoder.decode(frame)
            if isinstance(rec, RawEpoch):
                epochs.append(frame.offset)
            elif isinstance(rec, TimeMark):
                marks.append(rec)
            elif isinstance(rec, UndecodedFrame):
                assert rec.implausible, rec.error
    odd = set(decoder.refuted_offsets)  # found to be the odd ones after they were decoded
    return [o for o in epochs if o not in odd], marks, decoder.stats.implausible_by_type


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("timed", [False, True], ids=["ubx", "host_times"])
def test_decoder_and_bulk_decoder_keep_the_same_epochs_and_marks(seed: int, timed: bool) -> None:
    data = fuzzed_stream(seed)
    chunk = 97
    host0 = NOW - 3600 * S if timed else None
    epochs, marks, implausible = decode_streaming(data, chunk, host0)
    if timed:
        pieces = [(data[i : i + chunk], (host0 or 0) + i * 1000)
                  for i in range(0, len(data), chunk)]
        frames, index = index_timed_chunks(pieces)
        offsets = index_frames(data).start  # the index's starts are into the frames' bytes
    else:
        frames, index = data, index_frames(data)
        offsets = index.start
    block, _, _, times = observations_of(frames, index, NOW)
    bulk_marks = time_marks_of(frames, index, block, times)
    rawx, raw, _ = plausible_epochs(index, decode_rawx(frames, index), decode_raw(frames, index),
                                    NOW)
    assert sorted(offsets[np.concatenate((rawx.frame, raw.frame))].tolist()) == epochs
    assert [(m.count, m.falling_t_gps_ns, m.rising_t_gps_ns) for m in bulk_marks] == [
        (m.count, m.falling_t_gps_ns, m.rising_t_gps_ns) for m in marks]
    assert implausible.get("RXM-RAW", 0) == raw.implausible.size > 0
    assert implausible.get("RXM-RAWX", 0) == rawx.implausible.size > 0
    assert times.implausible == raw.implausible.size + rawx.implausible.size
    # every real epoch and mark of the flight is kept (the false ones never displace them)
    _, clean = flight_stream(120, drop_epochs={40, 41, 42, 90}, mark_every=4)
    real = set(clean)
    dec = Decoder(now_ns=NOW)
    kept = [f.raw for f in UbxFramer().feed(data, 0)
            if not isinstance(dec.decode(f), UndecodedFrame)]
    assert real - set(kept) == set()


@pytest.mark.shared_data
@pytest.mark.parametrize("rel", REAL_UBX_FILES)
def test_no_frame_of_a_real_recording_is_implausible(shared_data: Path, rel: str) -> None:
    """Every real receiver's epochs, marks and fixes belong to their session: the rule refuses
    none of them, streaming or in bulk (u-blox 4 to F9, 1 Hz to polled every 10 s, cold starts)."""
    path = shared_data / "real" / rel
    summary = inspect_path(path)
    data, index = read_frames(path)
    _, _, _, times = observations_of(data, index)
    assert summary.implausible == {} and summary.time_jumps == 0
    assert times.implausible == 0 and not times.verdicts.jumps


def test_inspect_leaves_out_an_odd_epoch_not_the_real_one_at_its_time(tmp_path: Path) -> None:
    frames = [rxm_raw(WEEK, TOW0_MS + 200 * k, SATS) for k in range(10)]
    frames.insert(4, rxm_raw(WEEK, TOW0_MS + 200 * 6, SATS))  # epoch 6's time, after epoch 3
    (tmp_path / "f.ubx").write_bytes(b"".join(frames))
    summary = inspect_path(tmp_path / "f.ubx")
    assert summary.epochs == 10 and summary.gaps == () and summary.implausible == {"RXM-RAW": 1}
