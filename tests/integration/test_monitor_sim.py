"""The monitor against the simulator's truth: every injected dropout, missed mark and
half-cycle/slip episode is reported, and a clean stream gives no false dropout."""

from __future__ import annotations

from collections import Counter

import pytest

from groundstation.gpstime import NS_PER_WEEK
from groundstation.live.monitor import Monitor
from groundstation.records import Event, RawEpoch
from groundstation.sim.faults import FaultConfig
from groundstation.sim.stream import SimConfig, SimResult, simulate
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

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
    # Counts the ground never got: missed by the receiver, or their TIM-TM2 lost on the link.
    # A loss after the last mark that arrives cannot show as a count jump.
    not_received = {e["count"] for e in exposures if e["missed"]}
    not_received |= set(faulty.truth["fault_summary"]["marks_lost_in_link"])
    last_received = max(e["count"] for e in exposures if e["count"] not in not_received)
    detectable = {c for c in not_received if c < last_received}
    assert len(detectable) >= 2
    assert monitor.missed == len(detectable)
    assert monitor.marks == len(exposures) - len(not_received)
    reported = {c for e in events if e.kind == "mark.missed"
                for c in range(e.data["from_count"] + 1, e.data["to_count"])}
    assert reported == detectable


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
