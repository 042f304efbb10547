"""Replay an MCAP the live daemon recorded: the monitor reaches the same events and status."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from peers import EventCollector

from groundstation import jsonio
from groundstation.live.demo import DemoOptions, run_demo
from groundstation.live.fanout import Overflow, SinkSpec
from groundstation.live.replay import run_replay
from groundstation.storage import iter_messages

DATA_EVENTS = ("link.dropout", "sat.slip", "sat.half_cycle_set", "sat.half_cycle_cleared",
               "mark.missed", "mark.duplicate", "mark.in_dropout")


def data_events(events: list[dict[str, object]]) -> Counter[str]:
    return Counter(
        json.dumps({"kind": e["kind"], "data": e["data"]}, sort_keys=True)
        for e in events if e["kind"] in DATA_EVENTS
    )


@pytest.mark.slow
def test_replay_of_a_live_recording_gives_the_same_monitor_output(tmp_path: Path) -> None:
    opts = DemoOptions(flight_s=90, speed=6.0, seed=11, faults="default",
                       out_dir=tmp_path / "live", zenoh=False)
    live = asyncio.run(run_demo(opts, on_payload=lambda k, p: None))
    (mcap,) = live.summary.files
    recorded = [json.loads(m.data) for m in iter_messages(mcap, ["/groundstation/event"])]
    statuses = [json.loads(m.data) for m in iter_messages(mcap, ["/groundstation/status"])]
    assert data_events(recorded), "the faulty flight must have produced monitor events"

    collector = EventCollector()

    summary, pipeline = asyncio.run(run_replay(
        mcap, speed=None, sinks=(SinkSpec(collector, 100_000, Overflow.NEVER_DROP),)))
    replayed_events = [jsonio.plain(e) for e in collector.items]
    assert summary.bytes_in == live.summary.bytes_in
    assert summary.frames == live.summary.frames
    assert pipeline.monitor is not None
    assert data_events(replayed_events) == data_events(recorded)
    final_live = statuses[-1]
    final_replay = pipeline.monitor.last_status
    assert final_replay is not None
    for key in ("epochs", "dropouts", "missing_epochs", "damaged_frames"):
        assert getattr(final_replay.link, key) == final_live["link"][key], key
    assert final_replay.marks.marks == final_live["marks"]["marks"]
    assert final_replay.marks.missed == final_live["marks"]["missed"]
    # the clock-driven view of dropouts (seen while they last) is reproduced too
    started_live = sum(e["kind"] == "link.dropout_started" for e in recorded)
    started_replay = sum(e["kind"] == "link.dropout_started" for e in replayed_events)
    assert abs(started_live - started_replay) <= 1


def test_replay_command_on_a_ubx_file(tmp_path: Path) -> None:
    from groundstation.sim.faults import FaultConfig
    from groundstation.sim.stream import SimConfig, simulate

    sim = simulate(SimConfig(duration_s=90, seed=2, faults=FaultConfig.default()))
    path = tmp_path / "flight.ubx"
    path.write_bytes(sim.rover_bytes)
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "replay", str(path), "--no-zenoh"],
        capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    lost = len(sim.truth["fault_summary"]["epochs_lost_tow_ms"])
    assert f"({lost} epochs missing)" in proc.stdout
