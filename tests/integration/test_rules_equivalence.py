"""Live and offline agree on the same bytes: the monitor's slip and half-cycle events equal the
RINEX LLI, and its mark counts equal the offline marks table.

The monitor side is the daemon's path (framer, decoder, monitor); the offline side is the RINEX
conversion's path (frame index, vectorised decoder, RINEX observations and marks). For each
recording, the demo flight and every real UBX file in ``../shared/data``:

- every LLI bit 0 of a written measurement is one ``sat.slip`` event, except on a signal's first
  epoch after it was new or lost (the receiver just locked: nothing slipped);
- every change of LLI bit 1 from one written epoch of a signal to its next is one
  ``sat.half_cycle_set`` / ``sat.half_cycle_cleared`` event;
- the monitor's received, missed and duplicate marks equal the marks table's.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest
from real_files import REAL_UBX_FILES, real_bytes

from groundstation import events as kinds
from groundstation.live.monitor import Monitor
from groundstation.offline.rinex.convert import observations_of, time_marks_of
from groundstation.offline.rinex.observations import GNSS_LETTER, SIGNAL_CODES, VERSION0_CODES
from groundstation.records import Event
from groundstation.rules.marks import track_marks
from groundstation.rules.phase import LLI_HALF_CYCLE, LLI_SLIP, SIGNAL_LOST_AFTER_EPOCHS
from groundstation.sim.faults import FaultConfig
from groundstation.sim.stream import SimConfig, simulate
from groundstation.ubx.decode import Decoder
from groundstation.ubx.fastraw import index_frames
from groundstation.ubx.framer import UbxFramer

PHASE_KINDS = (kinds.SAT_SLIP, kinds.SAT_HALF_CYCLE_SET, kinds.SAT_HALF_CYCLE_CLEARED)
GNSS_OF_LETTER = {v: k for k, v in GNSS_LETTER.items()}

SignalKey = tuple[str, int, str]  # RINEX system letter, PRN, band+attribute
PhaseEvent = tuple[SignalKey, int, str]  # signal, epoch GPS ns, event kind


@dataclass(frozen=True)
class Live:
    events: list[Event]
    marks: int
    missed: int
    duplicates: int


def run_live(data: bytes) -> Live:
    """The daemon's path: bytes in chunks through the framer, the decoder and the monitor."""
    framer, decoder, monitor = UbxFramer(), Decoder(), Monitor("eq")
    events: list[Event] = []
    now = 0
    for i in range(0, len(data), 4096):
        now += 1_000_000
        for frame in framer.feed(data[i : i + 4096], now):
            events += monitor.observe(decoder.decode(frame), now)
    for frame in framer.flush(now):
        events += monitor.observe(decoder.decode(frame), now)
    return Live(events, monitor.marks, monitor.missed, monitor.duplicates)


def signal_of_label(label: str, v1: bool) -> SignalKey | None:
    """The monitor's signal label (``G05``, ``E11/5``) as the RINEX signal it is written as."""
    sat, _, sig_text = label.partition("/")
    letter, number = sat[0], int(sat[1:])
    gnss = GNSS_OF_LETTER.get(letter)
    if gnss is None:
        return None
    sig = int(sig_text or 0)
    code = SIGNAL_CODES.get((gnss, sig)) if v1 else VERSION0_CODES.get(gnss)
    if code is None:
        return None
    return letter, number + (100 if letter == "S" else 0), code


@dataclass(frozen=True)
class Offline:
    phase: list[PhaseEvent]
    signals: set[SignalKey]
    v1: bool
    marks: int
    missed: int
    duplicates: int


def run_offline(data: bytes) -> Offline:
    """The RINEX conversion's path, and the operator's events read off its LLI."""
    index = index_frames(data)
    block, obs, _, times = observations_of(data, index)
    v1 = block.source == "RXM-RAWX" and bool((block.header["version"] >= 1).any())
    keys = list(zip(obs.sys.tolist(), obs.prn.tolist(), obs.code.tolist(), strict=True))
    by_epoch: dict[int, list[int]] = {}
    for row, ep in enumerate(obs.epoch.tolist()):
        by_epoch.setdefault(ep, []).append(row)
    phase: list[PhaseEvent] = []
    last_t: int | None = None
    absent: dict[SignalKey, int] = {}
    half: dict[SignalKey, bool] = {}
    for ep, t in enumerate(obs.t_gps_ns.tolist()):
        if last_t is not None and t <= last_t:
            continue  # a repeated or out-of-order epoch: neither written nor monitored
        last_t = t
        seen = set()
        for row in by_epoch.get(ep, []):
            key = keys[row]
            lli = int(obs.lli[row])
            new = key not in absent
            seen.add(key)
            absent[key] = 0
            h = bool(lli & LLI_HALF_CYCLE)
            before = half.get(key, False) and not new
            if lli & LLI_SLIP and not new:
                phase.append((key, t, kinds.SAT_SLIP))
            if h and not before:
                phase.append((key, t, kinds.SAT_HALF_CYCLE_SET))
            if before and not h:
                phase.append((key, t, kinds.SAT_HALF_CYCLE_CLEARED))
            half[key] = h
        for key in list(absent):
            if key not in seen:
                absent[key] += 1
                if absent[key] > SIGNAL_LOST_AFTER_EPOCHS:
                    del absent[key]
    marks, tracker = track_marks(time_marks_of(data, index, block, times))
    return Offline(phase, set(keys), v1, len(marks), sum(m.lost_before for m in marks),
                   tracker.duplicates)


def live_phase(live: Live, off: Offline) -> list[PhaseEvent]:
    out: list[PhaseEvent] = []
    for e in live.events:
        if e.kind in PHASE_KINDS:
            key = signal_of_label(e.data["sv"], off.v1)
            if key is not None and key in off.signals:
                out.append((key, e.data["t_gps_ns"], e.kind))
    return out


def assert_equivalent(data: bytes) -> Offline:
    live, off = run_live(data), run_offline(data)
    got, want = sorted(live_phase(live, off)), sorted(off.phase)
    missing = sorted(set(want) - set(got))[:5]
    extra = sorted(set(got) - set(want))[:5]
    assert got == want, f"RINEX LLI events missing from the monitor {missing}, extra {extra}"
    assert (live.marks, live.missed, live.duplicates) == (off.marks, off.missed, off.duplicates)
    return off


@cache
def demo_flight() -> bytes:
    sim = simulate(SimConfig(duration_s=600, seed=5, faults=FaultConfig.default()))
    return b"".join(chunk for _, chunk in sim.rover_chunks)


def test_demo_flight_monitor_equals_rinex() -> None:
    off = assert_equivalent(demo_flight())
    kinds_seen = {k for _, _, k in off.phase}
    # The faulty flight must exercise every rule, else equality proves little.
    assert kinds_seen == set(PHASE_KINDS)
    assert off.marks > 50 and off.missed > 0 and off.duplicates > 0


@pytest.mark.shared_data
@pytest.mark.parametrize("name", REAL_UBX_FILES)
def test_real_file_monitor_equals_rinex(shared_data: Path, name: str) -> None:
    assert_equivalent(real_bytes(shared_data, name))
