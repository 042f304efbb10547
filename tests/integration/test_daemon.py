"""`groundstation run` as a real process on a real pty: exact bytes, unplug, kill -9, SIGTERM."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from peers import Daemon, Pty, cli_env

from groundstation.ubx.build import build_frame

REPO = Path(__file__).resolve().parents[2]
SHARED_DATA = REPO.parent / "shared" / "data"
REAL_CAPTURE = SHARED_DATA / "real" / "tridge__pyUblox" / "data" / "6P-raw-PPP.ubx"


def start(daemons: list[Daemon], pty: Pty, out: Path, *extra: str) -> Daemon:
    d = Daemon("--port", str(pty.link), "--baud", "115200", "--station", "t",
               "--out-dir", str(out), "--no-zenoh", *extra)
    daemons.append(d)
    d.wait_for("connected")  # pyserial flushes the input queue on open: write only after
    return d


def wait_for_size(path: Path, size: int, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and path.stat().st_size >= size:
            return
        time.sleep(0.02)
    have = path.stat().st_size if path.exists() else None
    raise AssertionError(f"{path} has {have} bytes, expected {size}")


def one(out: Path, pattern: str) -> Path:
    (path,) = sorted(out.glob(pattern))
    return path


def raw_from_mcap(path: Path) -> tuple[bytes, list[int], list[dict[str, object]]]:
    """Raw bytes, raw log times and events, read with the mcap library's streaming reader,
    stopping quietly at a torn tail (what any tool can do with an unfinished file)."""
    raw = bytearray()
    times: list[int] = []
    events: list[dict[str, object]] = []
    channels: dict[int, str] = {}
    with path.open("rb") as f:
        try:
            for record in StreamReader(f).records:
                kind = type(record).__name__
                if kind == "Channel":
                    channels[record.id] = record.topic  # type: ignore[attr-defined]
                elif kind == "Message":
                    topic = channels[record.channel_id]  # type: ignore[attr-defined]
                    if topic == "/ubx/raw":
                        raw += record.data  # type: ignore[attr-defined]
                        times.append(record.log_time)  # type: ignore[attr-defined]
                    elif topic == "/groundstation/event":
                        events.append(json.loads(record.data))  # type: ignore[attr-defined]
        except Exception:  # the torn tail of a killed writer
            pass
    return bytes(raw), times, events


def generated_stream() -> bytes:
    out = bytearray()
    for i in range(600):
        out += build_frame(0x0A, 0x04, bytes((i + k) % 251 for k in range(i % 90)))
        if i % 7 == 0:
            out += b"\x00\x11garbage\xb5"  # noise, and a lone sync byte
        if i % 11 == 0:
            out += build_frame(0x02, 0x10, bytes(8))[:9]  # a frame cut by a dropout
    return bytes(out)


def check_finished_recording(out: Path, sent: bytes) -> list[dict[str, object]]:
    mcap_path, ubx_path = one(out, "t_*.mcap"), one(out, "t_*.ubx")
    assert mcap_path.stem == ubx_path.stem
    assert ubx_path.read_bytes() == sent
    raw, _, events = raw_from_mcap(mcap_path)
    assert raw == sent
    with mcap_path.open("rb") as f:  # finished: the seeking reader finds the summary
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.chunk_indexes
        seeking_raw = b"".join(m.data for _, _, m in reader.iter_messages(topics=["/ubx/raw"]))
    assert seeking_raw == sent
    return events


@pytest.mark.shared_data
def test_real_capture_through_pty_is_recorded_byte_for_byte(
    tmp_path: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    if not REAL_CAPTURE.exists():
        pytest.skip(f"shared data absent: {REAL_CAPTURE} (../shared/data next to the repo)")
    sent = REAL_CAPTURE.read_bytes()
    out = tmp_path / "out"
    d = start(daemons, pty, out)
    pty.write(sent)
    wait_for_size(one(out, "t_*.ubx"), len(sent))
    rc, stdout = d.stop(signal.SIGTERM)
    assert rc == 0, d.stderr
    assert "recording to" in stdout and "stopped by SIGTERM" in stdout
    assert "RXM-RAW" in stdout
    check_finished_recording(out, sent)


def test_generated_stream_and_sigint(tmp_path: Path, pty: Pty, daemons: list[Daemon]) -> None:
    sent = generated_stream()
    out = tmp_path / "out"
    d = start(daemons, pty, out)
    pty.write(sent, piece=333)
    wait_for_size(one(out, "t_*.ubx"), len(sent))
    rc, stdout = d.stop(signal.SIGINT)
    assert rc == 0, d.stderr
    assert "stopped by SIGINT" in stdout
    check_finished_recording(out, sent)


def test_unplug_and_replug_keeps_the_session(
    tmp_path: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    out = tmp_path / "out"
    d = start(daemons, pty, out)
    first, second = generated_stream()[:20_000], generated_stream()[20_000:]
    pty.write(first)
    ubx = one(out, "t_*.ubx")
    wait_for_size(ubx, len(first))
    t_unplug = time.monotonic()
    pty.unplug()
    d.wait_for("lost", timeout_s=1.0, after=t_unplug)  # noticed within a second
    time.sleep(1.0)
    t_plug = time.monotonic()
    pty.plug()
    t_back = d.wait_for("back after", timeout_s=3.0, after=t_plug)
    assert t_back - t_plug < 2.0
    pty.write(second)
    wait_for_size(ubx, len(first) + len(second))
    rc, _ = d.stop()
    assert rc == 0, d.stderr
    events = check_finished_recording(out, first + second)  # one session, one file
    outages = [e for e in events if e["kind"] == "source.outage"]
    assert len(outages) == 1
    data = outages[0]["data"]
    assert isinstance(data, dict)
    assert 0.9 < data["duration_s"] < 3.0
    assert data["end_ns"] - data["start_ns"] == pytest.approx(data["duration_s"] * 1e9, abs=1e3)
    assert any(e["kind"] == "source.lost" for e in events)


def test_kill_9_loses_at_most_a_second(tmp_path: Path, pty: Pty, daemons: list[Daemon]) -> None:
    out = tmp_path / "out"
    d = start(daemons, pty, out)
    stream = generated_stream() * 2
    sent = bytearray()
    written_at: list[tuple[float, int]] = []  # (wall time, bytes sent so far)
    t_end = time.monotonic() + 2.5
    i = 0
    while time.monotonic() < t_end:  # about 115200 baud
        piece = stream[i : i + 576]
        pty.write(piece)
        sent += piece
        written_at.append((time.time(), len(sent)))
        i += len(piece)
        time.sleep(0.05)
    wait_for_size(one(out, "t_*.ubx"), len(sent))  # the daemon has read what was written
    t_kill = time.time()
    os.kill(d.proc.pid, signal.SIGKILL)
    d.proc.wait(timeout=5)
    ubx = one(out, "t_*.ubx").read_bytes()
    assert ubx == bytes(sent)  # every byte received before the kill
    raw, times, _ = raw_from_mcap(one(out, "t_*.mcap"))
    assert sent.startswith(raw)
    sent_a_second_before = max(n for t, n in written_at if t <= t_kill - 1.0)
    assert len(raw) >= sent_a_second_before
    assert times and times[-1] / 1e9 >= t_kill - 1.0


@pytest.mark.parametrize(
    ("args", "toml", "key"),
    [
        (["--port", "/dev/null"], "bogus_key = 1\n", "bogus_key"),
        ([], 'station = "x"\n', "source"),
        (["--port", "/dev/null", "--baud", "12345"], "", "source.baud"),
        (["--port", "/dev/null", "--baud", "fast"], "", "source.baud"),
    ],
)
def test_bad_configuration_exits_2_naming_the_key(
    tmp_path: Path, args: list[str], toml: str, key: str
) -> None:
    cfg = tmp_path / "gs.toml"
    cfg.write_text(toml)
    env = cli_env()
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "run", "--config", str(cfg), *args],
        cwd=REPO, capture_output=True, text=True, timeout=30, env=env,
    )
    assert proc.returncode == 2, proc.stderr
    assert f"configuration error: {key}:" in proc.stderr
