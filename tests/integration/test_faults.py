"""Faults the daemon survives, on real processes and a real pty: random bytes (a wrong baud
rate), a second daemon on the same port, and a recording disk that fills up (a 2 MB tmpfs)."""

from __future__ import annotations

import contextlib
import random
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from peers import Daemon, Pty
from streams import flight_stream
from test_daemon import generated_stream, one, raw_from_mcap, start, wait_for_size


def _write_slowly(pty: Pty, data: bytes) -> None:
    """``data`` in 1152-byte pieces every 0.1 s (what 115200 baud delivers)."""
    for i in range(0, len(data), 1152):
        pty.write(data[i : i + 1152])
        time.sleep(0.1)


def _frames_clear_it(
    d: Daemon, pty: Pty, out: Path, written: int
) -> tuple[bytes, list[dict[str, Any]]]:
    """After ``written`` bytes of noise with the alert raised: a flight's frames clear it; the
    daemon stops cleanly. Returns the recorded bytes and the ``no_frames`` alert events."""
    stream, _ = flight_stream(50)
    _write_slowly(pty, stream)
    wait_for_size(one(out, "t_*.ubx"), written + len(stream))
    d.wait_for("(was: no valid frames")  # the new frames reached the monitor
    rc, _ = d.stop(signal.SIGTERM)
    assert rc == 0, d.stderr
    raw, _, events = raw_from_mcap(one(out, "t_*.mcap"))
    return raw, [e for e in events if isinstance(e["data"], dict)
                 and e["data"].get("alert") == "no_frames"]


def test_wrong_baud_raises_no_valid_frames_and_frames_clear_it(
    tmp_path: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    cfg = tmp_path / "gs.toml"
    cfg.write_text("[monitor]\nno_frames_s = 1.5\n")
    out = tmp_path / "out"
    d = start(daemons, pty, out, "--config", str(cfg))
    # What a UART at the wrong rate delivers: bytes, but random ones (a pty has no baud rate).
    rng = random.Random(9)
    noise = bytes(rng.randrange(256) for _ in range(3 * 11520))
    _write_slowly(pty, noise)
    d.wait_for("no valid frames", timeout_s=3.0)
    raw, alerts = _frames_clear_it(d, pty, out, len(noise))
    assert raw == noise + flight_stream(50)[0]
    assert [e["kind"] for e in alerts] == ["alert.raised", "alert.cleared"]
    msg = str(alerts[0]["message"])
    assert msg.startswith("no valid frames for ")
    assert msg.endswith("likely cause: wrong baud rate (bytes arrive but no frame checks out), "
                        "or noise on the line")


def test_second_daemon_on_the_same_port_is_refused(
    tmp_path: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    out = tmp_path / "out"
    first = start(daemons, pty, out)
    out2 = tmp_path / "out2"
    second = Daemon("--port", str(pty.link), "--station", "t", "--out-dir", str(out2),
                    "--no-zenoh")
    daemons.append(second)
    rc2, _ = second.proc.wait(timeout=20), None
    second._thread.join(timeout=2)
    assert rc2 == 1, second.stderr  # a runtime conflict, not a configuration error (2)
    assert "refusing to start" in second.stderr
    assert f"in use by process {first.proc.pid}" in second.stderr
    assert not out2.exists() or not any(out2.iterdir())  # no empty recording left behind
    # the first daemon never noticed
    stream, _ = flight_stream(30)
    pty.write(stream)
    wait_for_size(one(out, "t_*.ubx"), len(stream))
    rc, _ = first.stop()
    assert rc == 0, first.stderr
    assert one(out, "t_*.ubx").read_bytes() == stream
    assert raw_from_mcap(one(out, "t_*.mcap"))[0] == stream


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 2 MB tmpfs (mounting needs root, as in CI; skipped where it is refused)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip() or proc.returncode}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def fill(path: Path) -> None:
    """Write zeros until the file system refuses."""
    with path.open("wb", buffering=0) as f, contextlib.suppress(OSError):
        while True:
            f.write(bytes(65536))


def wait_for_total(out: Path, size: int, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    total = 0
    while time.monotonic() < deadline:
        total = sum(p.stat().st_size for p in out.glob("t_*.ubx"))
        if total >= size:
            return
        time.sleep(0.05)
    raise AssertionError(f"sidecars hold {total} bytes, expected {size}")


def test_disk_full_keeps_every_byte_and_resumes(
    tmp_path: Path, small_disk: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    cfg = tmp_path / "gs.toml"
    cfg.write_text("[recorder]\nretry_s = 0.3\nflush_interval_s = 0.2\n")
    out = small_disk / "out"
    d = start(daemons, pty, out, "--config", str(cfg))
    stream = generated_stream() * 3
    a, b, c = stream[:15_000], stream[15_000:75_000], stream[75_000:]
    pty.write(a)
    wait_for_size(one(out, "t_*.ubx"), len(a))
    filler = small_disk / "filler"
    fill(filler)
    t_full = time.monotonic()
    for i in range(0, len(b), 2000):
        pty.write(b[i : i + 2000])
        time.sleep(0.02)
    d.wait_for("cannot write", timeout_s=5.0, after=t_full)
    d.wait_for("alert: cannot write the recording (No space left on device", after=t_full)
    time.sleep(1.0)  # retries against the full disk
    t_free = time.monotonic()
    filler.unlink()
    d.wait_for("recording resumed in", timeout_s=5.0, after=t_free)
    pty.write(c)
    wait_for_total(out, len(stream))
    rc, stdout = d.stop(signal.SIGTERM)
    assert rc == 0, d.stderr
    assert "recording failed 1 time(s) (disk full?): nothing dropped" in stdout
    mcaps, sides = sorted(out.glob("t_*.mcap")), sorted(out.glob("t_*.ubx"))
    assert len(mcaps) == len(sides) >= 2
    assert b"".join(p.read_bytes() for p in sides) == stream
    parts = [raw_from_mcap(p) for p in mcaps]
    assert b"".join(raw for raw, _, _ in parts) == stream
    events = [e for _, _, evs in parts for e in evs]
    kinds = [(e["kind"], dict(e["data"]).get("alert")) for e in events  # type: ignore[call-overload]
             if str(e["kind"]).startswith(("recorder.", "alert."))]
    assert ("recorder.write_failed", None) in kinds
    assert ("alert.raised", "disk_full") in kinds and ("alert.cleared", "disk_full") in kinds
    assert ("recorder.recovered", None) in kinds
    assert not any(k == "recorder.dropped" for k, _ in kinds)


def test_a_full_disk_at_start_is_refused_with_a_message(
    tmp_path: Path, small_disk: Path, pty: Pty
) -> None:
    fill(small_disk / "filler")
    d = Daemon("--port", str(pty.link), "--station", "t", "--out-dir", str(small_disk / "out"),
               "--no-zenoh")
    try:
        rc = d.proc.wait(timeout=20)
    finally:
        d.kill()
    d._thread.join(timeout=2)
    assert rc == 1, d.stderr
    assert "cannot create the recording in" in d.stderr
    assert "No space left on device" in d.stderr
    assert "Traceback" not in d.stderr


def test_no_frames_alert_stays_raised_through_noise_with_stray_frames(
    tmp_path: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    """A link that still delivers noise, with a stray valid frame now and then, for longer
    than the clear hold: the alert is raised once and not cleared (one stray frame cleared it,
    and the next noise raised it again); it clears once frames decode steadily again."""
    from groundstation.ubx.build import build_frame

    cfg = tmp_path / "gs.toml"
    cfg.write_text("[monitor]\nno_frames_s = 1.5\n")
    out = tmp_path / "out"
    d = start(daemons, pty, out, "--config", str(cfg))
    rng = random.Random(5)
    stray = build_frame(0x01, 0x22, bytes(20))  # a valid NAV-CLOCK amid the noise
    written = 0
    for i in range(100):  # 10 s of noise (> 1.5 s to raise + 1.5 s clear hold), and a
        chunk = bytes(rng.randrange(256) for _ in range(1152))  # frame every 2.5 s
        if i % 25 == 24:
            chunk = chunk[:500] + stray + chunk[500:]
        pty.write(chunk)
        written += len(chunk)
        time.sleep(0.1)
    d.wait_for("no valid frames", timeout_s=1.0)
    _, alerts = _frames_clear_it(d, pty, out, written)
    assert [e["kind"] for e in alerts] == ["alert.raised", "alert.cleared"], [
        (e["kind"], e["message"]) for e in alerts]


def test_a_dashboard_port_in_use_is_a_runtime_failure_in_one_line(tmp_path: Path) -> None:
    """A busy web port is a condition of the machine, not a bad setting: exit 1 (it was 2,
    "configuration error: port: ... [Errno 98]"), one line that says what to do."""
    import socket
    import sys

    from peers import cli_env

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        proc = subprocess.run(
            [sys.executable, "-m", "groundstation.cli", "dashboard", "--port", str(port),
             "--duration", "5"],
            capture_output=True, text=True, timeout=60, check=False, env=cli_env(),
            cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "groundstation dashboard" in ln]
    assert lines == [(f"groundstation dashboard: error: port {port} is in use on 127.0.0.1 "
                      "(another dashboard?); choose another with --port")], proc.stderr
    assert "Traceback" not in proc.stderr
