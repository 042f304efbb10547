"""What the operator sees is true: a silent source, a missing port, an acknowledgement, a replay.

Real parts only: a TCP server that accepts and never sends, the daemon as a subprocess, a real
Zenoh session on loopback for the acknowledgement, the demo's MCAP for the replay.
"""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import threading
import time
from pathlib import Path

from peers import Daemon, Pty, Received, StatusEventCollector, free_port

from groundstation import events as kinds
from groundstation import jsonio
from groundstation.bus import decode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.live.demo import DemoOptions, run_demo
from groundstation.live.fanout import Overflow, SinkSpec
from groundstation.live.replay import run_replay
from groundstation.records import Event, Status
from groundstation.storage import iter_messages


def test_silent_tcp_source_raises_an_alert_within_10_s(
    tmp_path: Path, daemons: list[Daemon]
) -> None:
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    accepted: list[socket.socket] = []
    threading.Thread(target=lambda: accepted.append(server.accept()[0]), daemon=True).start()
    try:
        daemon = Daemon("--tcp", f"127.0.0.1:{port}", "--station", "silent", "--no-zenoh",
                        "--out-dir", str(tmp_path))
        daemons.append(daemon)
        t_connected = daemon.wait_for("connected")
        t_alert = daemon.wait_for("alert: no data from the source", timeout_s=10.0)
        assert accepted, "the daemon never connected to the server"
        assert "since the start" in daemon.stderr
        assert t_alert >= t_connected
        daemon.proc.send_signal(signal.SIGTERM)
        daemon.wait_for("no data received from the TCP 127.0.0.1", timeout_s=15.0)
        assert daemon.proc.wait(timeout=15) == 1  # an error, not a quiet "0 outages"
    finally:
        for s in accepted:
            s.close()
        server.close()


def test_missing_port_at_start_is_one_line_and_nothing_else(
    tmp_path: Path, daemons: list[Daemon]
) -> None:
    """A device that does not exist at the start: one line, exit 1, no recording made,
    announced or served (a Zenoh peer on loopback listening for the station hears nothing)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = open_bus(ZenohSettings(mode="peer", connect=(), listen=(endpoint,)))
    try:
        heard = Received(bus, key("gone", "**"), parse=lambda p: {"bytes": len(p)})
        daemon = Daemon("--port", str(tmp_path / "nonexistent"), "--station", "gone",
                        "--zenoh-connect", endpoint, "--out-dir", str(tmp_path / "out"),
                        "--duration", "4")
        daemons.append(daemon)
        assert daemon.proc.wait(timeout=30) == 1
        _, out = daemon.stop()  # (already ended: collects its stdout, joins the stderr pump)
        lines = daemon.stderr.splitlines()
        assert len(lines) == 1, daemon.stderr
        assert lines[0].startswith(
            f"groundstation run: error: {tmp_path / 'nonexistent'} does not exist (")
        assert "plug the receiver in or name its device with --port" in lines[0]
        assert out == ""  # no "recording to", no summary of a session that never was
        assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
        # nothing served: a query for the station's status finds no one
        assert bus.get(key("gone", "q/status"), timeout_s=1.0) == []
        assert heard.all() == []
    finally:
        bus.close()


def test_an_acknowledgement_travels_to_the_daemon_and_back(
    tmp_path: Path, pty: Pty, daemons: list[Daemon]
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    daemon = Daemon("--port", str(pty.link), "--station", "ackst", "--out-dir", str(tmp_path),
                    "--zenoh-listen", endpoint)
    daemons.append(daemon)
    daemon.wait_for("publishing on Zenoh")
    bus = open_bus(ZenohSettings(mode="client", connect=(endpoint,), listen=()))
    got: list[dict[str, object]] = []
    try:
        bus.subscribe(key("ackst", "event"), lambda _k, p: got.append(decode(p)))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not any(
                e.get("kind") == kinds.OPERATOR_ACK for e in got):
            bus.put(key("ackst", "ack"), jsonio.dumps({"alert": "marks_missed", "by": "test"}))
            time.sleep(0.5)
    finally:
        bus.close()
    acks = [e for e in got if e.get("kind") == kinds.OPERATOR_ACK]
    assert acks and acks[0]["data"] == {"alert": "marks_missed", "by": "test"}
    daemon.wait_for("operator acknowledged marks_missed (test)")
    daemon.stop()
    (mcap,) = tmp_path.glob("*.mcap")
    recorded = [json.loads(m.data) for m in iter_messages(mcap, ["/groundstation/event"])]
    assert any(e["kind"] == kinds.OPERATOR_ACK for e in recorded)  # kept with the session




def test_replay_at_speed_4_shows_no_silence_or_dropout_the_recording_lacks(
    tmp_path: Path,
) -> None:
    """The demo recorded as a field session would be (real time pacing, scaled 8x), replayed at
    x4: the live views get no ``no_data`` and no dropout that the recording does not hold, and
    no negative or huge ages."""
    opts = DemoOptions(flight_s=80, speed=8.0, seed=5, faults="none",
                       out_dir=tmp_path / "live", zenoh=False)
    live = asyncio.run(run_demo(opts, on_payload=lambda k, p: None))
    (mcap,) = live.summary.files
    recorded = [json.loads(m.data) for m in iter_messages(mcap, ["/groundstation/event"])]
    rec_dropouts = sum(e["kind"] == kinds.LINK_DROPOUT for e in recorded)
    sink = StatusEventCollector()
    asyncio.run(run_replay(mcap, speed=4.0,
                           sinks=(SinkSpec(sink, 1_000_000, Overflow.NEVER_DROP),)))
    events = [e for e in sink.items if isinstance(e, Event)]
    statuses = [s for s in sink.items if isinstance(s, Status)]
    assert statuses
    no_data = [e.message for e in events if e.kind == kinds.ALERT_RAISED
               and e.data.get("alert") == kinds.ALERT_NO_DATA]
    assert no_data == []
    assert sum(e.kind == kinds.LINK_DROPOUT for e in events) == rec_dropouts
    for s in statuses[1:]:
        age = s.link.last_byte_age_s
        assert age is None or 0 <= age < 3.0, age
