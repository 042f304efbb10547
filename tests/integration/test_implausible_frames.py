"""One bad frame must never stop a flight (issue 27, items 1-4): frames with a valid checksum and
a time that cannot belong to the session, live through a pty into ``groundstation run`` and
offline through ``run --file``, ``replay``, ``inspect``, ``rinex`` and ``solve``.

Each frame here is one a lossy radio delivers now and then (a 16-bit checksum passes about one
random candidate in 65 536): the daemon goes on recording every byte, the monitor keeps its
clock, and the offline tools keep every real epoch and mark and leave the bad ones out.
"""

from __future__ import annotations

import asyncio
import struct
import subprocess
import sys
import time
from functools import cache
from pathlib import Path

import pytest
from peers import Daemon, ItemCollector, Pty, cli_env
from streams import TOW0_MS, WEEK, epoch_with_mark, rxm_raw

from groundstation import jsonio, messages
from groundstation.bus import encode
from groundstation.config import FileSourceSettings, load_settings
from groundstation.live.daemon import Pipeline
from groundstation.live.fanout import Overflow, SinkSpec
from groundstation.live.monitor import Monitor
from groundstation.live.sources import FileSource
from groundstation.records import RawEpoch, Status, TimeMark
from groundstation.sim.stream import SimConfig, simulate
from groundstation.storage import iter_messages
from groundstation.ubx import layouts as L
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import UbxFramer

SATS = [(3, 0), (7, 0), (11, 2), (19, 0), (23, 0), (27, 0)]
TIMEOUT_S = 120  # a hang guard, not a speed target
SOL_WKN = L.NAV_SOL_FLAGS.compose(gpsfixOK=1, wknSet=1, towSet=1)


def beyond_2554() -> list[bytes]:
    """Frames whose GPS week puts their time past what an MCAP publish time holds (item 1)."""
    tow = TOW0_MS + 200 * 30
    flags = L.TIM_TM2_FLAGS.compose(mode=1, run=1, timeBase=1, time=1, newFallingEdge=1,
                                    newRisingEdge=1)
    return [
        rxm_raw(32767, tow, SATS[:2]),
        L.RXM_RAWX.frame([], rcvTow=tow / 1000, week=65535, leapS=18, recStat=1, version=1),
        L.NAV_SOL.frame(iTOW=tow, week=32767, gpsFix=3, flags=SOL_WKN, ecefX=1, numSV=5),
        L.TIM_TM2.frame(ch=0, flags=flags, count=99, wnR=65535, wnF=65535, towMsR=tow + 14,
                        towMsF=tow, accEst=20),
    ]


# -- item 1: one frame with week >= 29 978 ended `run` --------------------------------------------


def test_run_through_a_pty_records_on_after_frames_dated_past_2554(
    tmp_path: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    conf = tmp_path / "fast.toml"
    conf.write_text("[recorder]\nflush_interval_s = 0.2\n")
    out = tmp_path / "out"
    d = Daemon("--port", str(pty.link), "--station", "bad", "--out-dir", str(out), "--no-zenoh",
               "--config", str(conf))
    daemons.append(d)
    d.wait_for("connected", timeout_s=30)
    sent: list[bytes] = []
    for k in range(60):
        piece = epoch_with_mark(k, k // 5 if k % 5 == 0 else None, SATS, WEEK, TOW0_MS)
        if k == 30:
            piece += b"".join(beyond_2554())
        pty.write(piece)
        sent.append(piece)
        time.sleep(0.02)
    time.sleep(1.0)
    assert d.proc.poll() is None, d.stderr  # still running
    rc, _ = d.stop()
    assert rc == 0 and "internal error" not in d.stderr, d.stderr
    (sidecar,) = out.glob("*.ubx")
    assert sidecar.read_bytes() == b"".join(sent)  # every byte recorded, before and after
    (mcap,) = out.glob("*.mcap")
    epochs = list(iter_messages(mcap, ["/gnss/epoch"]))
    marks = list(iter_messages(mcap, ["/gnss/timemark"]))
    assert len(epochs) == 60 and len(marks) == 12
    assert all(0 < m.publish_time_ns < 1 << 63 for m in epochs + marks)
    assert "implausible RXM-RAW" in d.stderr and "implausible TIM-TM2" in d.stderr


# -- item 2: a future-dated epoch hung `run --file` and `replay` -----------------------------------


class StatusCounter(ItemCollector):
    """Counts the statuses the monitor publishes."""

    name = "statuses"
    accepts = frozenset({Status})


def statuses_of_run_file(path: Path) -> int:
    settings = load_settings(None, environ={}, overrides={
        "source": {"path": path}, "zenoh": {"enabled": False},
        "recorder": {"out_dir": path.parent}})
    assert isinstance(settings.source, FileSourceSettings)
    counter = StatusCounter()
    pipeline = Pipeline(settings, source=FileSource(settings.source),
                        sinks=(SinkSpec(counter, 1_000_000, Overflow.NEVER_DROP),))
    summary = asyncio.run(pipeline.run())
    assert summary.stopped_by == "end of source"
    return len(counter.items)


def five_hz(n: int, week: int = WEEK, tow0_ms: int = TOW0_MS) -> list[bytes]:
    return [rxm_raw(week, tow0_ms + 200 * k, SATS) for k in range(n)]


def test_run_file_with_one_epoch_a_day_ahead_does_not_tick_through_the_day(tmp_path: Path) -> None:
    frames = five_hz(300)  # 60 s of data
    frames.insert(150, rxm_raw(WEEK, TOW0_MS + 200 * 150 + 86_400_000, SATS))
    path = tmp_path / "ahead.ubx"
    path.write_bytes(b"".join(frames))
    # one status a second of the data's 60 s (the day-ahead epoch made it 86 400)
    assert statuses_of_run_file(path) <= 62


def test_run_file_across_a_confirmed_day_long_jump_ticks_only_the_monitors_horizon(
    tmp_path: Path,
) -> None:
    frames = five_hz(150) + five_hz(150, tow0_ms=TOW0_MS + 86_400_000 + 30_000)
    path = tmp_path / "jump.ubx"
    path.write_bytes(b"".join(frames))
    # 60 s of data and a day of silence between: the silence is ticked for the monitor's
    # horizon (every alert threshold and hold), then once at its end, not 864 000 times
    assert statuses_of_run_file(path) <= 62 + 70


@pytest.mark.parametrize("bad", [
    rxm_raw(32767, TOW0_MS + 200 * 20, SATS),
    rxm_raw(WEEK, 2**31 - 1, SATS),
    rxm_raw(WEEK, 604_800_000, SATS),
    rxm_raw(WEEK + 1, TOW0_MS + 200 * 20, SATS),
], ids=["week_32767", "itow_2_31", "itow_a_week", "a_week_ahead"])
@pytest.mark.parametrize("command", ["run", "replay"])
def test_run_file_and_replay_finish_on_a_future_dated_epoch(
    tmp_path: Path, bad: bytes, command: str
) -> None:
    frames = five_hz(60)
    frames.insert(20, bad)
    path = tmp_path / "f.ubx"
    path.write_bytes(b"".join(frames))
    argv = (["run", "--file", str(path), "--out-dir", str(tmp_path / "o")] if command == "run"
            else ["replay", str(path)])
    proc = subprocess.run([sys.executable, "-m", "groundstation.cli", *argv, "--no-zenoh"],
                          cwd=tmp_path, env=cli_env(), capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr
    assert "internal error" not in proc.stderr and "implausible RXM-RAW" in proc.stderr


# -- item 3: the monitor blinded by one future epoch; a first epoch of week -1 ---------------------


def monitor_over(data: bytes) -> tuple[Monitor, list[Status]]:
    """The daemon's path, sans-I/O: framer, decoder, monitor, 5 chunks a second of data."""
    framer, decoder, monitor = UbxFramer(), Decoder(), Monitor("m")
    statuses: list[Status] = []
    t = 1_700_000_000 * 10**9
    for i in range(0, len(data), 200):
        t += 40_000_000
        monitor.on_bytes(len(data[i : i + 200]), t)
        for frame in framer.feed(data[i : i + 200], t):
            monitor.observe(decoder.decode(frame), t)
        status, _ = monitor.tick(t)
        if status is not None:
            statuses.append(status)
    return monitor, statuses


@pytest.mark.parametrize("bad", [
    rxm_raw(4000, TOW0_MS + 200 * 100, SATS),
    rxm_raw(WEEK, 2**31 - 1, SATS),
    rxm_raw(WEEK, TOW0_MS + 200 * 100 + 3_600_000, SATS),
], ids=["week_4000", "itow_2_31", "an_hour_ahead"])
def test_one_future_epoch_does_not_blind_the_monitor(bad: bytes) -> None:
    frames = five_hz(400)
    frames.insert(100, bad)
    monitor, statuses = monitor_over(b"".join(frames))
    last = statuses[-1]
    assert monitor.epochs == 400 and last.link.dropouts == 0
    assert last.link.completeness_session == 1.0 and last.link.completeness_10s == 1.0
    assert not any("dropout" in a for a in last.alerts)


def test_a_first_epoch_of_week_minus_1_leaves_every_status_readable_on_the_bus() -> None:
    frames = [rxm_raw(-1, TOW0_MS, SATS)] + five_hz(100)[1:]
    monitor, statuses = monitor_over(b"".join(frames))
    assert statuses and monitor.epochs == 99
    for st in statuses:
        messages.parse(encode("status", st), "status")  # the views and the solver read it
    first = statuses[-1].link.first_epoch_t_gps_ns
    assert first is not None and first > 0
    session = {"type": "session", "first_epoch_t_gps_ns": first,
               "last_epoch_t_gps_ns": statuses[-1].link.last_epoch_t_gps_ns}
    messages.check(jsonio.loads(jsonio.dumps(session)), "session")


# -- item 4: the offline tools ------------------------------------------------------------------


@cache
def sim_frames() -> tuple[bytes, ...]:
    """A minute of a simulated LEA-6T flight (RXM-RAW, RXM-SFRB, NAV-SOL, NAV-SVINFO, TIM-TM2)."""
    sim = simulate(SimConfig(duration_s=60, seed=4, with_base=False))
    return tuple(m.raw for m in sim.rover_messages)


def with_frame(bad: bytes, at: float = 0.5) -> tuple[bytes, int, int]:
    """The simulated stream with ``bad`` inserted; its RXM-RAW epochs and marks (falling)."""
    frames = list(sim_frames())
    frames.insert(int(len(frames) * at), bad)
    epochs = sum(f[2:4] == b"\x02\x10" for f in sim_frames())
    dec = Decoder()
    marks = sum(isinstance(r, TimeMark) and r.new_falling
                for r in (dec.decode(f) for f in UbxFramer().feed(b"".join(sim_frames()), 0)))
    return b"".join(frames), epochs, marks


def cli(cwd: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], cwd=cwd,
                          env=cli_env(), capture_output=True, text=True, timeout=TIMEOUT_S)
    assert "internal error" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    return proc


def sim_week_tow() -> tuple[int, int]:
    raw = next(f for f in sim_frames() if f[2:4] == b"\x02\x10")
    itow, week = struct.unpack_from("<ih", raw, 6)
    return week, itow


def test_rinex_and_solve_leave_out_a_time_mark_of_week_65535(tmp_path: Path) -> None:
    week, itow = sim_week_tow()
    flags = L.TIM_TM2_FLAGS.compose(mode=1, run=1, timeBase=1, time=1, newFallingEdge=1)
    bad = L.TIM_TM2.frame(ch=0, flags=flags, count=77, wnF=65535, towMsF=itow, wnR=week,
                          towMsR=itow, accEst=20)
    data, epochs, marks = with_frame(bad)
    (tmp_path / "f.ubx").write_bytes(data)
    proc = cli(tmp_path, "rinex", "f.ubx", "-o", "rnx")
    assert proc.returncode == 0, proc.stderr
    assert f"{marks} marks" in proc.stdout and "implausible: 1 " in proc.stdout
    proc = cli(tmp_path, "solve", "--no-pdf", "f.ubx", "--source", "receiver", "--out", "sol",
               "--no-progress")
    assert proc.returncode in (0, 1), proc.stderr  # 1: a run that positions no mark is said
    assert f"{marks} camera marks" in proc.stderr


def test_run_file_and_replay_leave_out_an_rxm_rawx_with_rcvtow_nan(tmp_path: Path) -> None:
    week, _ = sim_week_tow()
    bad = L.RXM_RAWX.frame([], rcvTow=float("nan"), week=week, leapS=18, recStat=1, version=1)
    data, _, _ = with_frame(bad)
    (tmp_path / "f.ubx").write_bytes(data)
    for argv in (("run", "--file", "f.ubx", "--out-dir", "o"), ("replay", "f.ubx")):
        proc = cli(tmp_path, *argv, "--no-zenoh")
        assert proc.returncode == 0, proc.stderr
        assert "implausible RXM-RAWX" in proc.stderr
    (mcap,) = (tmp_path / "o").glob("*.mcap")
    assert len(list(iter_messages(mcap, ["/gnss/epoch"]))) == sum(
        f[2:4] == b"\x02\x10" for f in sim_frames())


def test_rinex_and_inspect_of_one_epoch_at_itow_2_31(tmp_path: Path) -> None:
    week, _ = sim_week_tow()
    data, epochs, _ = with_frame(rxm_raw(week, 2**31 - 1, SATS), at=0.3)
    (tmp_path / "f.ubx").write_bytes(data)
    proc = cli(tmp_path, "rinex", "f.ubx", "-o", "rnx")
    assert proc.returncode == 0, proc.stderr
    assert f"{epochs} epochs (RXM-RAW)" in proc.stdout  # none dropped "out of order"
    assert "0 epochs not written" in proc.stdout
    proc = cli(tmp_path, "inspect", "--json", "f.ubx")
    summary = jsonio.loads(proc.stdout)
    assert summary["epochs"] == epochs and summary["implausible"] == {"RXM-RAW": 1}
    assert summary["missing_epochs"] < 100  # the simulated link's own dropouts, not 10 million


def test_epochs_decoded_live_equal_the_recordings_epochs() -> None:
    """The decoder keeps exactly the stream's real epochs around a bad one."""
    week, itow = sim_week_tow()
    data, epochs, _ = with_frame(rxm_raw(week + 2, itow, SATS))
    dec = Decoder()
    got = [r for r in (dec.decode(f) for f in UbxFramer().feed(data, 0))
           if isinstance(r, RawEpoch)]
    assert len(got) == epochs and dec.stats.implausible_by_type == {"RXM-RAW": 1}


def test_the_solver_reads_the_same_marks_as_rinex(tmp_path: Path) -> None:
    """The solver's reading of the marks judges them by the session's clock too (it reads only
    marks and fixes: the epochs still set the clock), so a mark an hour off is left out by both."""
    from groundstation.offline.rinex.convert import observations_of, read_frames, time_marks_of
    from groundstation.solve.flight import read_flight

    week, itow = sim_week_tow()
    flags = L.TIM_TM2_FLAGS.compose(mode=1, run=1, timeBase=1, time=1, newFallingEdge=1)
    off = L.TIM_TM2.frame(ch=0, flags=flags, count=50, wnF=week, towMsF=itow + 3_600_000,
                          accEst=20)
    data, _, marks = with_frame(off)
    path = tmp_path / "f.ubx"
    path.write_bytes(data)
    frames, index = read_frames(path)
    block, _, _, times = observations_of(frames, index)
    offline = time_marks_of(frames, index, block, times)
    solver = read_flight(path).timemarks
    assert [(m.count, m.falling_t_gps_ns) for m in solver] == [
        (m.count, m.falling_t_gps_ns) for m in offline]
    assert sum(m.new_falling for m in solver) == marks


def test_phase_conditioning_survives_a_slip_on_a_satellite_without_an_ephemeris(
    tmp_path: Path,
) -> None:
    """Found by benchmarks/fuzz_valid_frames.py: a slip on a satellite the conditioning has no
    orbit for (a plausible chance frame's random satellite; a satellite risen before its
    ephemeris came) is started again, not an internal error (round() of an infinite jump)."""
    from dataclasses import replace
    from typing import Any

    import numpy as np

    from groundstation.offline import rinex
    from groundstation.offline.rinex.observations import ObsSet
    from groundstation.solve import conditioning

    (tmp_path / "f.ubx").write_bytes(b"".join(sim_frames()))
    reports: list[conditioning.ConditioningReport] = []

    def hook(obs: ObsSet, ephs: Any, approx: tuple[float, float, float]) -> ObsSet:
        gps = np.flatnonzero(obs.sys == "G")
        sv = int(obs.prn[gps[0]])
        rows = gps[obs.prn[gps] == sv]
        lli = obs.lli.copy()
        lli[rows[len(rows) // 2]] |= 1  # a slip, mid-flight
        orbits = [e for e in ephs if e.sv != sv]  # and no orbit for it
        new, rep = conditioning.condition(replace(obs, lli=lli), orbits, approx)
        reports.append(rep)
        return new

    rinex.convert(tmp_path / "f.ubx", tmp_path / "rnx", obs_hook=hook)
    assert reports and reports[0].applied
