"""Faults the daemon survives, on real processes and a real pty: random bytes (a wrong baud
rate) and a second daemon on the same port."""

from __future__ import annotations

import random
import signal
import time
from pathlib import Path

from peers import Daemon, Pty
from streams import flight_stream
from test_daemon import one, raw_from_mcap, start, wait_for_size


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
    for i in range(0, len(noise), 1152):
        pty.write(noise[i : i + 1152])
        time.sleep(0.1)
    d.wait_for("no valid frames", timeout_s=3.0)
    stream, _ = flight_stream(50)
    for i in range(0, len(stream), 1152):
        pty.write(stream[i : i + 1152])
        time.sleep(0.1)
    wait_for_size(one(out, "t_*.ubx"), len(noise) + len(stream))
    time.sleep(1.5)  # a pipeline status with the new frames reaches the monitor
    rc, _ = d.stop(signal.SIGTERM)
    assert rc == 0, d.stderr
    raw, _, events = raw_from_mcap(one(out, "t_*.mcap"))
    assert raw == noise + stream
    alerts = [e for e in events if isinstance(e["data"], dict)
              and e["data"].get("alert") == "no_frames"]
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
