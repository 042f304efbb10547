"""The simulated stream: clean decoding, fault accounting against the truth, determinism."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from pyubx2 import UBXReader

from groundstation.gnss.lnav import EphemerisAssembler
from groundstation.gpstime import NS_PER_WEEK
from groundstation.pacing import paced
from groundstation.records import RawEpoch, Subframe, TimeMark
from groundstation.sim.faults import FaultConfig
from groundstation.sim.stream import SimConfig, SimResult, simulate
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer


def _frames(data: bytes) -> tuple[list, UbxFramer]:  # type: ignore[type-arg]
    framer = UbxFramer()
    # Odd chunking on purpose: the framer must not care.
    frames = []
    for i in range(0, len(data), 997):
        frames += framer.feed(data[i : i + 997], 0)
    frames += framer.flush(0)
    return frames, framer


@pytest.fixture(scope="module")
def clean() -> SimResult:
    return simulate(SimConfig(duration_s=240.0, seed=3))


@pytest.fixture(scope="module")
def faulty() -> SimResult:
    faults = FaultConfig(dropout_per_min=6.0, corrupt_per_min=6.0, truncate_per_min=4.0,
                         missed_mark_prob=0.1, duplicate_mark_prob=0.1)
    return simulate(SimConfig(duration_s=300.0, seed=11, faults=faults))


def test_clean_stream_has_no_damage_and_decodes(clean: SimResult) -> None:
    frames, framer = _frames(clean.rover_bytes)
    st = framer.stats
    assert st.damaged_frames == 0 and st.garbage_bytes == 0
    assert st.frames == len(clean.rover_messages)
    decoder = Decoder(raise_on_error=True)
    records = [decoder.decode(f) for f in frames]
    epochs = [r for r in records if isinstance(r, RawEpoch)]
    assert len(epochs) == clean.truth["receivers"]["rover"]["epochs"]
    assert {r.__class__.__name__ for r in records} == {
        "RawEpoch", "Subframe", "NavSolution", "SvInfo", "TimeMark"}
    # 5 Hz, no gaps, 4-16 satellites, half-cycle flags present after acquisition.
    tows = [e.tow_ns for e in epochs]
    assert all(b - a == 200_000_000 for a, b in zip(tows, tows[1:], strict=False))
    assert all(4 <= len(e.sats) <= 16 for e in epochs)
    assert any(s.half_cycle_unresolved for e in epochs for s in e.sats)
    # pyubx2 agrees on every frame.
    for f in frames:
        UBXReader.parse(f.raw, validate=1)


def test_marks_are_falling_then_rising_14ms_later(clean: SimResult) -> None:
    frames, _ = _frames(clean.rover_bytes)
    decoder = Decoder()
    marks = [m for m in (decoder.decode(f) for f in frames) if isinstance(m, TimeMark)]
    truth = clean.truth["exposures"]
    assert truth, "the flight must trigger the camera"
    rising = {m.count: m for m in marks if m.new_rising}
    assert sorted(rising) == [e["count"] for e in truth]
    for e in truth:
        m = rising[e["count"]]
        assert m.time_base == 1 and m.valid and m.mode_running
        assert m.falling_t_gps_ns is not None and m.rising_t_gps_ns is not None
        assert abs(m.falling_t_gps_ns - e["falling_t_gps_ns"]) < 100
        assert 13_000_000 < m.rising_t_gps_ns - m.falling_t_gps_ns < 15_500_000


def test_subframes_give_back_the_simulated_ephemerides(clean: SimResult) -> None:
    frames, _ = _frames(clean.rover_bytes)
    decoder = Decoder()
    asm = EphemerisAssembler(week_hint=clean.truth["start_gps_ns"] // NS_PER_WEEK)
    got = {}
    for rec in (decoder.decode(f) for f in frames):
        if isinstance(rec, Subframe):
            eph = asm.add(rec.sv, rec.data_words())
            if eph is not None:
                got[eph.sv] = dataclasses.replace(eph, tow_s=None)
    assert got and asm.errors == 0
    for sv, eph in got.items():
        assert eph in clean.constellation.ephemerides[sv]


def test_faults_match_the_truth(faulty: SimResult) -> None:
    frames, framer = _frames(faulty.rover_bytes)
    summary = faulty.truth["fault_summary"]
    kinds = {f["kind"] for f in faulty.truth["faults"]}
    assert {"dropout", "corruption", "truncation", "missed_mark", "duplicate_mark"} <= kinds
    st = framer.stats
    assert st.frames == summary["frames_intact"]
    assert st.damaged_frames == summary["sync_words_in_damage"]
    assert st.damaged_frames > 0
    decoder = Decoder()
    records = [decoder.decode(f) for f in frames]
    # Epoch gaps: exactly the epochs the truth says the link lost.
    first = faulty.truth["receivers"]["rover"]["first_tow_ms"]
    n = faulty.truth["receivers"]["rover"]["epochs"]
    all_tows = {first + 200 * i for i in range(n)}
    seen = {r.tow_ns // 1_000_000 for r in records if isinstance(r, RawEpoch)}
    assert all_tows - seen == set(summary["epochs_lost_tow_ms"])
    assert summary["epochs_lost_tow_ms"]
    # Count jumps: missed by the receiver or lost on the link, nothing else.
    marks = [r for r in records if isinstance(r, TimeMark) and r.new_rising]
    counts = sorted({m.count for m in marks})
    expected_missing = {
        e["count"] for e in faulty.truth["exposures"] if e["missed"]
    } | set(summary["marks_lost_in_link"])
    all_counts = {e["count"] for e in faulty.truth["exposures"]}
    assert all_counts - set(counts) <= expected_missing
    assert any(e["missed"] for e in faulty.truth["exposures"])
    # Duplicates arrive twice unless the link hit one of the copies.
    dup = [e["count"] for e in faulty.truth["exposures"] if e["duplicated"]]
    assert dup
    seen_twice = [c for c in dup if sum(m.count == c for m in marks) == 2]
    assert seen_twice or set(dup) <= set(summary["marks_lost_in_link"])


def test_same_seed_same_bytes_other_seed_other_bytes() -> None:
    cfg = SimConfig(duration_s=60.0, seed=5, faults=FaultConfig.default())
    a, b = simulate(cfg), simulate(cfg)
    assert a.rover_bytes == b.rover_bytes and a.truth["faults"] == b.truth["faults"]
    c = simulate(dataclasses.replace(cfg, seed=6))
    assert c.rover_bytes != a.rover_bytes


def test_truth_file_is_complete(clean: SimResult, tmp_path: Path) -> None:
    path = tmp_path / "truth.json"
    clean.write_truth(path)
    truth = json.loads(path.read_text())
    traj = truth["trajectory"]
    assert traj["rate_hz"] >= 50
    assert len(traj["t_gps_ns"]) == len(traj["x_m"]) > 50 * 240
    assert truth["base"]["ecef_m"] and len(truth["ephemerides"]) >= 31
    speeds = traj["speed_m_s"]
    assert max(speeds) > 1.5 and speeds[0] == 0.0 and speeds[-1] == 0.0


def test_fault_file_and_unknown_key(tmp_path: Path) -> None:
    good = tmp_path / "f.toml"
    good.write_text("[faults]\ndropout_per_min = 3\n")
    assert FaultConfig.load(str(good)).dropout_per_min == 3.0
    bad = tmp_path / "f.json"
    bad.write_text('{"dropouts": 1}')
    from groundstation.errors import ConfigError

    with pytest.raises(ConfigError):
        FaultConfig.load(str(bad))


def test_paced_respects_speed() -> None:
    now = [0.0]
    slept: list[float] = []

    def sleep(s: float) -> None:
        slept.append(s)
        now[0] += s

    chunks = [(0, b"a"), (1_000_000_000, b"b"), (3_000_000_000, b"c")]
    out = list(paced(chunks, 2.0, clock=lambda: now[0], sleep=sleep))
    assert [c for _, c in out] == [b"a", b"b", b"c"]
    assert slept == pytest.approx([0.5, 1.0])
    assert list(paced(chunks, None)) == chunks
