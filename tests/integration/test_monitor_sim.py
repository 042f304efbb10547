"""The monitor against the simulator's truth: every injected dropout, missed mark and
half-cycle/slip episode is reported, and a clean stream gives no false dropout."""

from __future__ import annotations

from collections import Counter

import pytest

from groundstation.gpstime import NS_PER_WEEK
from groundstation.live.monitor import Monitor
from groundstation.records import Event, RawEpoch, TimeMark
from groundstation.sim.faults import FaultConfig
from groundstation.sim.stream import SimConfig, SimResult, simulate
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer, iter_frames

# One worker runs this module's tests (pytest-xdist):
# its module fixture simulates a 600 s flight, made once.
pytestmark = pytest.mark.xdist_group("test_monitor_sim")

LATENCY_NS = 60_000_000  # host receives a chunk 60 ms after its GPS time
TICK_NS = 100_000_000


def run_monitor(result: SimResult) -> tuple[Monitor, list[Event], list[RawEpoch]]:
    framer, decoder, monitor = UbxFramer(), Decoder(), Monitor("sim")
    events: list[Event] = []
    epochs: list[RawEpoch] = []
    clock = None
    for t_gps, chunk in result.rover_chunks:
        now = t_gps + LATENCY_NS
        if clock is None:
            clock = now
        while clock + TICK_NS < now:  # the daemon ticks the monitor while waiting for bytes
            clock += TICK_NS
            events += monitor.tick(clock)[1]
        clock = now
        monitor.on_bytes(len(chunk), now)
        for frame in framer.feed(chunk, now):
            rec = decoder.decode(frame)
            if isinstance(rec, RawEpoch):
                epochs.append(rec)
            events += monitor.observe(rec, now)
        events += monitor.tick(now)[1]
    return monitor, events, epochs


def groups(tows_ms: list[int], step_ms: int) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for t in sorted(tows_ms):
        if out and t - out[-1][1] == step_ms:
            out[-1] = (out[-1][0], t)
        else:
            out.append((t, t))
    return out


@pytest.fixture(scope="module")
def faulty() -> SimResult:
    return simulate(SimConfig(duration_s=600, seed=5, faults=FaultConfig.default()))


def test_every_injected_dropout_reported_exactly(faulty: SimResult) -> None:
    monitor, events, _ = run_monitor(faulty)
    lost = faulty.truth["fault_summary"]["epochs_lost_tow_ms"]
    assert lost, "the default faults must lose some epochs"
    expected = groups(lost, 200)
    got = sorted(
        ((e.data["start_t_gps_ns"] % NS_PER_WEEK) // 1_000_000,
         (e.data["end_t_gps_ns"] % NS_PER_WEEK) // 1_000_000)
        for e in events if e.kind == "link.dropout"
    )
    assert got == expected
    assert monitor.missing_epochs == len(lost)


def test_every_missed_and_duplicate_mark_reported(faulty: SimResult) -> None:
    monitor, events, _ = run_monitor(faulty)
    exposures = faulty.truth["exposures"]
    dup = sum(e["duplicated"] for e in exposures)
    assert dup >= 1 and monitor.duplicates == dup
    # What reached the ground: the falling-edge times in the TIM-TM2 records that arrived
    # (a rising-edge record repeats its falling edge, so a mark survives the loss of one record).
    decoder = Decoder()
    received = [r for f in iter_frames(faulty.rover_bytes)
                if isinstance(r := decoder.decode(f), TimeMark)]
    falling = {m.falling_t_gps_ns for m in received if m.falling_t_gps_ns is not None}
    counts = {m.count for m in received}

    def arrived(e: dict[str, object]) -> bool:
        t = int(e["falling_t_gps_ns"])  # type: ignore[call-overload]
        return any(abs(t - f) < 1_000 for f in falling)

    got = [e for e in exposures if arrived(e)]
    assert monitor.marks == len(got)
    # Marks the receiver counted but that never reached the ground (the simulator's missed
    # marks, and marks whose every record was lost on the link) show as count jumps; a loss
    # after the last mark that arrives cannot.
    # The truth's count is the receiver's after the pulse's rising edge; a mark's number (the
    # events' counts) is the count at its falling edge, one less (rules/marks.mark_number).
    lost = {int(e["count"]) - 1 for e in exposures
            if not arrived(e) and int(e["count"]) < max(counts)}
    assert lost, "the default faults must lose whole marks"
    assert monitor.missed == len(lost)
    reported = {c for e in events if e.kind == "mark.missed"
                for c in range(e.data["from_count"] + 1, e.data["to_count"])}
    assert reported == lost


def test_every_half_cycle_and_slip_episode_reported(faulty: SimResult) -> None:
    _, events, epochs = run_monitor(faulty)
    received_t = {e.t_gps_ns for e in epochs}
    lock_events = faulty.truth["receivers"]["rover"]["lock_events"]
    # An episode is observable when the epoch that carries its flag reached the ground.
    observable = [e for e in lock_events if e["t_rx_ns"] in received_t]
    want_slips = Counter(f"G{e['sv']:02d}" for e in observable if e["kind"] == "slip")
    got_slips = Counter(e.data["sv"] for e in events if e.kind == "sat.slip")
    assert want_slips and got_slips == want_slips
    want_half = Counter(f"G{e['sv']:02d}" for e in observable if e["half_cycle_s"] > 0)
    got_half = Counter(e.data["sv"] for e in events if e.kind == "sat.half_cycle_set")
    assert got_half == want_half
    cleared = Counter(e.data["sv"] for e in events if e.kind == "sat.half_cycle_cleared")
    assert all(cleared[sv] >= n - 1 for sv, n in want_half.items())


@pytest.mark.parametrize("rate_hz", [5, 1])
def test_clean_stream_has_no_false_dropout(rate_hz: int) -> None:
    result = simulate(SimConfig(duration_s=300, seed=9, rate_hz=rate_hz,
                                faults=FaultConfig.load("none")))
    monitor, events, epochs = run_monitor(result)
    assert len(epochs) > 100
    assert [e for e in events if e.kind.startswith("link.dropout")] == []
    assert monitor.interval_ns == 1_000_000_000 // rate_hz
    assert monitor.missed == 0 and monitor.duplicates == 0
    st = monitor.status(result.rover_chunks[-1][0] + LATENCY_NS)
    assert st.link.completeness_session == 1.0
    assert st.ppk_ready >= 5
