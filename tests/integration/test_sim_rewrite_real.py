"""Real u-blox 8 recordings (jdesbonnet 2018) rewritten as a LEA-6T would have sent them and passed
through the simulator's link: what the stream holds, the LLI against the lock times, the
ephemerides, and the fault log against what ``groundstation inspect`` finds."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest
from pyubx2 import UBXReader
from real_files import real_bytes

from groundstation import jsonio
from groundstation.cli import main
from groundstation.gpstime import NS_PER_WEEK
from groundstation.offline.ephemeris import collect_ephemerides
from groundstation.records import Frame, RawEpoch, TimeMark
from groundstation.rules.marks import mark_number
from groundstation.sim.faults import FaultConfig
from groundstation.sim.rewrite import (
    LOCK_MAX_MS,
    RewriteConfig,
    RewriteResult,
    replay_frames,
    rewrite,
)
from groundstation.ubx.decode import Decoder, message_name
from groundstation.ubx.fastraw import index_frames
from groundstation.ubx.framer import iter_frames

# One worker runs this module's tests (pytest-xdist): its module fixtures rewrite a real
# recording, made once.
pytestmark = [pytest.mark.shared_data, pytest.mark.xdist_group("test_sim_rewrite_real")]

JD = "real/jdesbonnet__GNSS_RTK_data"
ROVER = f"{JD}/20181009/rover-20181009-1221.ubx.gz"


@pytest.fixture(scope="module")
def rover(shared_data: Path) -> Path:
    return shared_data / ROVER


@pytest.fixture(scope="module")
def original(shared_data: Path) -> list[Frame]:
    return iter_frames(real_bytes(shared_data, ROVER.removeprefix("real/")))


@pytest.fixture(scope="module")
def lea6t(rover: Path) -> RewriteResult:
    return rewrite(rover)


def _decoded(frames: list[Frame]) -> list[object]:
    dec = Decoder(raise_on_error=True)
    return [dec.decode(f) for f in frames]


def test_a_lea6t_stream_gps_l1_rxm_raw_same_epochs_and_marks(
    original: list[Frame], lea6t: RewriteResult
) -> None:
    frames = iter_frames(lea6t.data)
    assert Counter(message_name(f.cls, f.id) for f in frames) == {
        "RXM-RAW": 2072, "RXM-SFRB": 3545, "TIM-TM2": 1178, "NAV-SOL": 2072, "NAV-SVINFO": 2072}
    ours = [r for r in _decoded(frames) if isinstance(r, RawEpoch)]
    theirs = [r for r in _decoded(original) if isinstance(r, RawEpoch)]
    assert [e.t_gps_ns for e in ours] == [e.t_gps_ns for e in theirs]
    assert {e.source for e in ours} == {"RXM-RAW"}
    blank = 0
    for a, b in zip(ours, theirs, strict=True):
        gps = {s.sv: s for s in b.sats if s.gnss == 0 and s.sig_id == 0 and s.pr_valid}
        assert [s.sv for s in a.sats] == list(gps)
        for s in a.sats:
            o = gps[s.sv]
            assert s.gnss == 0 and 1 <= s.sv <= 32
            assert (s.pseudorange_m, s.doppler_hz, s.cno_dbhz) == (
                o.pseudorange_m, o.doppler_hz, o.cno_dbhz)
            assert s.carrier_phase_cyc == (o.carrier_phase_cyc if o.cp_valid else 0.0)
            assert s.mes_qi == (4 if not o.cp_valid else 5 if s.slip else
                                6 if s.half_cycle_unresolved else 7)
            blank += not o.cp_valid
    assert blank == 2972
    # the marks are the recording's, record for record
    assert ([f.raw for f in frames if message_name(f.cls, f.id) == "TIM-TM2"]
            == [f.raw for f in original if message_name(f.cls, f.id) == "TIM-TM2"])
    # pyubx2 reads the u-blox 6 messages as such
    for f in frames[:400]:
        UBXReader.parse(f.raw, validate=1)


def test_lli_bit_0_exactly_where_the_lock_time_restarted(
    original: list[Frame], lea6t: RewriteResult
) -> None:
    """Bit 0 where a satellite's usable phase follows an epoch without one, or where its lock
    time grew by less than the time since its last usable phase (20 ms: one step of the
    counter), or where the half cycle was subtracted or put back other than at the resolution.
    Bit 1 where trkStat's half-cycle-valid bit is clear."""
    expected: set[tuple[int, int]] = set()
    half: set[tuple[int, int]] = set()
    last: dict[int, tuple[int, int, bool, bool]] = {}
    usable_before: set[int] = set()
    rtklib_slips: set[tuple[int, int]] = set()
    resolutions: set[tuple[int, int]] = set()
    grew_too_little: set[tuple[int, int]] = set()
    for e in (r for r in _decoded(original) if isinstance(r, RawEpoch)):
        usable_now = set()
        for s in e.sats:
            if s.gnss != 0 or not s.pr_valid or not s.cp_valid:
                continue
            assert s.locktime_ms is not None and s.trk_stat is not None
            key = (e.t_gps_ns, s.sv)
            half_valid = bool(s.trk_stat & 4)
            if not half_valid:
                half.add(key)
            if s.slip:
                rtklib_slips.add(key)
            if s.sv not in last or s.sv not in usable_before:
                expected.add(key)
            else:
                t, lock, was_valid, sub = last[s.sv]
                elapsed_ms = (e.t_gps_ns - t) // 1_000_000
                if s.locktime_ms < min(lock + elapsed_ms, LOCK_MAX_MS) - 20:
                    expected.add(key)
                    if s.locktime_ms >= lock:
                        grew_too_little.add(key)
                elif s.half_cycle_subtracted != sub:
                    if half_valid and not was_valid:
                        resolutions.add(key)
                    else:
                        expected.add(key)
            last[s.sv] = (e.t_gps_ns, s.locktime_ms, half_valid, s.half_cycle_subtracted)
            usable_now.add(s.sv)
        usable_before = usable_now
    got_slip = set()
    got_half = set()
    for e in (r for r in _decoded(iter_frames(lea6t.data)) if isinstance(r, RawEpoch)):
        for s in e.sats:
            if s.carrier_phase_cyc == 0.0:  # no usable phase: both bits, as a u-blox 6 says
                assert (s.lli, s.mes_qi) == (3, 4)
                continue
            if s.slip:
                got_slip.add((e.t_gps_ns, s.sv))
            if s.half_cycle_unresolved:
                got_half.add((e.t_gps_ns, s.sv))
    assert got_slip == expected and len(expected) == 634
    assert got_half == half
    # the log names them all
    assert {(ev["t_gps_ns"], ev["sv"]) for ev in lea6t.log["lock_events"]} == expected
    # RTKLIB's RINEX rule on the RXM-RAWX (rules/phase) finds a subset: all but the half-cycle
    # resolutions (a u-blox 6 clears bit 1 there, no loss of lock) are ours; it misses lock
    # times that restarted and grew past their old value within one interval
    assert rtklib_slips - resolutions <= expected
    assert resolutions and resolutions <= rtklib_slips
    assert grew_too_little and not grew_too_little & rtklib_slips


def test_ephemerides_from_the_sfrb_equal_those_from_the_sfrbx(
    original: list[Frame], lea6t: RewriteResult
) -> None:
    raw = b"".join(f.raw for f in original)
    theirs = collect_ephemerides(raw, index_frames(raw), 2022)
    ours = collect_ephemerides(lea6t.data, index_frames(lea6t.data), 2022)
    assert set(ours.subframes) == {"RXM-SFRB"} and set(theirs.subframes) == {"RXM-SFRBX"}
    assert ours.ephemerides == theirs.ephemerides and len(ours.ephemerides) >= 15
    assert ours.iono_utc == theirs.iono_utc is not None
    assert ours.parity_errors == theirs.parity_errors == 0  # the 8 failures: subframes 4/5
    assert lea6t.log["conversion"]["subframes_parity_failed"] == 8


@pytest.mark.parametrize("name", [
    "20181009/base-20181009-1220.ubx.gz",
    "20181004/rover-20181004-1532.ubx.gz",
    "20181004/base-20181004-1452.ubx.gz",
])
def test_every_epoch_of_the_other_recordings_becomes_an_rxm_raw(
    shared_data: Path, name: str
) -> None:
    path = shared_data / JD / name
    res = rewrite(path)
    frames = iter_frames(res.data)
    names = Counter(message_name(f.cls, f.id) for f in frames)
    rawx = res.log["conversion"]["converted"]["RXM-RAWX -> RXM-RAW"]
    assert names["RXM-RAW"] == rawx == res.log["epochs"] > 500
    assert not {"RXM-RAWX", "RXM-SFRBX", "NAV-SVIN"} & set(names)
    assert all(s.gnss == 0 for r in _decoded(frames) if isinstance(r, RawEpoch) for s in r.sats)
    # a LEA-6T's stream is sent as it is: rewriting it again changes nothing
    assert replay_frames(frames).data == res.data


def test_the_original_form_is_the_recordings_frames(rover: Path, original: list[Frame]) -> None:
    res = rewrite(rover, RewriteConfig(form="original"))
    assert res.data == b"".join(f.raw for f in original)  # NMEA between them not carried
    assert res.log["epochs"] == 2072 and res.log["lock_events"] == []


def test_same_seed_same_bytes(rover: Path) -> None:
    cfg = RewriteConfig(faults=FaultConfig.seed(), seed=7)
    a, b = rewrite(rover, cfg), rewrite(rover, cfg)
    assert a.data == b.data and a.log == b.log
    assert rewrite(rover, RewriteConfig(faults=FaultConfig.seed(), seed=8)).data != a.data


def test_fault_log_counts_equal_what_inspect_finds(
    rover: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, log_path = tmp_path / "r.ubx", tmp_path / "r.json"
    assert main(["simulate", "--from-recording", str(rover), "--faults", "seed", "--seed", "3",
                 "--out", str(out), "--truth", str(log_path)]) == 0
    said = capsys.readouterr().out
    res = rewrite(rover, RewriteConfig(faults=FaultConfig.seed(), seed=3))
    assert out.read_bytes() == res.data  # the command line and the API agree
    log = json.loads(log_path.read_text())
    assert log == jsonio.loads(jsonio.dumps(res.log))
    assert main(["inspect", "--json", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    fs = log["fault_summary"]
    lost = set(fs["epochs_lost_tow_ms"])
    gaps = [g for g in log["link_gaps"] if g["after_tow_ms"] is not None
            and g["before_tow_ms"] is not None]
    assert summary["epochs"] == log["epochs"] - len(lost)
    assert len(summary["gaps"]) == len(gaps) > 100
    assert summary["missing_epochs"] == sum(g["missing_epochs"] for g in gaps) == len(lost)
    assert [g["after_t_gps_ns"] % NS_PER_WEEK // 1_000_000 for g in summary["gaps"]] == [
        g["after_tow_ms"] for g in gaps]
    assert summary["frames"] == fs["frames_intact"]
    assert summary["damaged_frames"] == fs["sync_words_in_damage"] > 0
    damaged = fs["damaged_by_type"]
    for name, sent in log["messages"].items():
        extra = (log["timemark_messages"] - sent) if name == "TIM-TM2" else 0  # mark faults
        assert summary["messages"][name] == sent + extra - damaged.get(name, 0), name
    # marks: the log's lost ones are those of which no record came through
    records = [r for r in _decoded(iter_frames(res.data)) if isinstance(r, TimeMark)]
    assert summary["timemarks"]["records"] == len(records)
    assert {mark_number(r) for r in records} == set(range(log["marks"])) - set(log["marks_lost"])
    assert len(log["marks_lost"]) > 10
    assert f"{len(gaps)} gaps, {len(lost)} epochs and {len(log['marks_lost'])} marks lost" in said
