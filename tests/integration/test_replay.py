"""Replay an MCAP the live daemon recorded: the monitor reaches the same events and status."""

from __future__ import annotations

import asyncio
import json
import re
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from peers import EventCollector, ItemCollector, cli_env, interrupted_cli

from groundstation import jsonio
from groundstation.live.demo import DemoOptions, run_demo
from groundstation.live.fanout import Overflow, SinkSpec
from groundstation.live.replay import run_replay
from groundstation.records import RawChunk, RawEpoch
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


def test_each_replay_is_a_session_of_its_own_for_the_views(tmp_path: Path) -> None:
    """Two recordings replayed one after the other into one dashboard view (the payloads the
    publisher puts on Zenoh, and the hub's catch-up of the run's marks when a new session
    shows): the second run's statuses name a new session, dated by its data, so the view
    shows only its marks, with ages on its data clock."""
    from groundstation.live.demo import ViewSink
    from groundstation.sim.stream import SimConfig, simulate
    from groundstation.view.dashboard.state import StationView

    view = StationView("replay")
    sessions: list[str] = []
    run_marks: list[bytes] = []  # what the run's q/timemarks queryable answers

    def on_payload(kind: str, payload: bytes) -> None:
        if kind == "timemark":
            run_marks.append(payload)
        view.on_payload(f"groundstation/replay/{kind}", payload, time.monotonic())
        if view.session_changed:  # as the hub does: fetch the new session's marks again
            view.session_changed = False
            for p in list(run_marks):
                view.on_payload("groundstation/replay/q/timemarks", p, time.monotonic())
        if kind == "status":
            sessions.append(json.loads(payload)["session_id"])

    marks = []
    for n, flight_s in enumerate((160.0, 110.0)):
        sim = simulate(SimConfig(duration_s=flight_s, seed=3 + n, with_base=False))
        path = tmp_path / f"flight{n}.ubx"
        path.write_bytes(sim.rover_bytes)
        run_marks.clear()
        marks.append([e["falling_t_gps_ns"] for e in sim.truth["exposures"] if e["sent"]])
        asyncio.run(run_replay(path, speed=None, sinks=(
            SinkSpec(ViewSink(on_payload, "replay"), 100_000, Overflow.NEVER_DROP),)))
    assert len(marks[0]) != len(marks[1])
    first, second = sessions[0], sessions[-1]
    assert first != second and {first, second} == set(sessions)
    for sid in (first, second):
        assert re.fullmatch(r"replay_replay-\d{8}T\d{6}Z-[0-9a-f]{6}_\d{8}T\d{6}Z", sid), sid
    snap = view.snapshot(time.monotonic())
    assert snap["session_id"] == second
    assert snap["marks"]["received"] == len(set(marks[1]))
    assert abs(snap["marks"]["last_t_gps_ns"] - max(marks[1])) < 1000  # ns, as decoded
    assert snap["marks"]["last_age_s"] >= 0


def test_replay_reads_the_environment_like_every_command(tmp_path: Path) -> None:
    """``GROUNDSTATION_*`` goes through the one resolver (it was ignored): Zenoh and the
    monitor switched off from the environment; a bad variable exits 2 naming it."""
    from groundstation.sim.stream import SimConfig, simulate

    path = tmp_path / "flight.ubx"
    path.write_bytes(simulate(SimConfig(duration_s=60, seed=2, with_base=False)).rover_bytes)
    def replay(**settings: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "groundstation.cli", "replay", str(path)],
            capture_output=True, text=True, timeout=120, check=False, env=cli_env(**settings))

    proc = replay(GROUNDSTATION_ZENOH_ENABLED="false", GROUNDSTATION_MONITOR_ENABLED="no")
    assert proc.returncode == 0, proc.stderr
    assert "publishing on Zenoh" not in proc.stderr
    assert proc.stdout.startswith("replayed ") and "link:" not in proc.stdout  # no monitor
    proc = replay(GROUNDSTATION_ZENOH_ENABLED="false", GROUNDSTATION_STATION="no/slash")
    assert proc.returncode == 2 and "GROUNDSTATION_STATION" in proc.stderr, proc.stderr
    proc = replay(GROUNDSTATION_MONITR_ENABLED="no")
    assert proc.returncode == 2 and "GROUNDSTATION_MONITR_ENABLED" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_replay_of_a_ubx_file_keeps_the_pace_of_its_data(tmp_path: Path) -> None:
    """A ``.ubx`` holds no reception times: ``--speed N`` paces it on its own GPS time, so
    ``N`` seconds of data come through in about one second (it was paced as a 115 200-baud
    link: a 1 Hz rover went ~5 times too fast at ``--speed 1``), and the chunks carry that
    time (the UTC of the epochs) for the monitor."""
    from groundstation.gpstime import gps_to_unix_ns
    from groundstation.sim.stream import SimConfig, simulate

    sim = simulate(SimConfig(duration_s=14, seed=5, with_base=False))
    path = tmp_path / "short.ubx"
    path.write_bytes(sim.rover_bytes)
    sink = ItemCollector(RawChunk, RawEpoch)  # the raw chunks' times and the epochs' GPS times
    speed = 10.0
    t0 = time.monotonic()
    summary, _ = asyncio.run(run_replay(path, speed=speed, sinks=(
        SinkSpec(sink, 100_000, Overflow.NEVER_DROP),)))
    wall_s = time.monotonic() - t0
    assert summary.bytes_in == len(sim.rover_bytes)
    chunks = [i.t_host_ns for i in sink.items if isinstance(i, RawChunk)]
    epochs = [i.t_gps_ns for i in sink.items if isinstance(i, RawEpoch)]
    span_s = (epochs[-1] - epochs[0]) / 1e9
    assert span_s > 10
    ratio = span_s / wall_s  # data seconds per wall second: about the speed
    assert speed / 2 < ratio < speed * 1.2, (span_s, wall_s)
    # the chunks' times are the data's (UTC of its epochs), not today's
    first = gps_to_unix_ns(epochs[0])
    assert first <= chunks[0] < first + 10**9
    assert chunks[-1] == gps_to_unix_ns(epochs[-1])


def test_replay_summary_says_the_satellites_are_those_at_the_end_of_the_recording(
        shared_data: Path) -> None:
    """The real rover of 2018-10-09 flies with ~22 satellites (89 % fixed) but its last minute
    holds 6-9 with at most 2 clean phases (the receiver was carried away): the summary at
    ``--speed max`` showed "7 tracked, 0 PPK-ready" as if it were the flight's. That state is
    real (the monitor runs on data time whatever the speed); the summary now says when."""
    rover = (shared_data / "real" / "jdesbonnet__GNSS_RTK_data" / "20181009"
             / "rover-20181009-1221.ubx.gz")
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "replay", str(rover), "--no-zenoh"],
        capture_output=True, text=True, timeout=300, check=False, env=cli_env(),
    )
    assert proc.returncode == 0, proc.stderr
    line = next(ln for ln in proc.stdout.splitlines() if "PPK-ready" in ln)
    assert line.strip().startswith("at the end of the recording: "), line
    tracked = int(re.search(r"(\d+) satellites tracked", line).group(1))  # type: ignore[union-attr]
    assert tracked < 12  # the end of the file, not the flight's ~22


def _reading(path: Path) -> bool:
    """A process has ``path`` open and has read some of it (``/proc``: its descriptors and their
    positions)."""
    for fd in Path("/proc").glob("[0-9]*/fd/*"):
        try:
            if fd.readlink() == path:
                info = (fd.parent.parent / "fdinfo" / fd.name).read_text()
                if int(info.split()[1]) > 0:
                    return True
        except (OSError, ValueError, IndexError):  # a process or descriptor gone meanwhile
            continue
    return False


def test_an_interrupted_replay_prints_its_summary_and_exits_130(tmp_path: Path) -> None:
    """``replay`` ends by itself, so Ctrl-C is an interruption (README: 130), unlike the
    daemon's normal end; the summary still comes, its satellites "where the replay stopped"."""

    from groundstation.sim.stream import SimConfig, simulate

    sim = simulate(SimConfig(duration_s=120, seed=2, with_base=False))
    path = tmp_path / "flight.ubx"
    path.write_bytes(sim.rover_bytes)
    # Ctrl-C 3 s after the replay has begun reading (on a loaded machine its start alone
    # can take longer than 3 s)
    returncode, out, err = interrupted_cli(
        ["replay", str(path), "--speed", "1", "--no-zenoh"], ready=lambda: _reading(path),
        after_s=3.0)
    assert returncode == 130, err
    assert "(SIGINT)" in out and "where the replay stopped: " in out, out
    assert "Traceback" not in err
