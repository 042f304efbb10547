"""The Zenoh peer the daemon connects to goes away and comes back: recording is unaffected and
publishing resumes (the daemon is a real process; the peer is a session of this test)."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import pytest
from peers import Daemon, Pty, free_port, wait_until
from streams import epoch_with_mark
from test_daemon import one, raw_from_mcap, wait_for_size
from test_zenoh import SATS, STATION, TOW0_MS, WEEK, Collector

from groundstation.bus import decode, key, open_bus
from groundstation.config import ZenohSettings


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["peer", "client"])
def test_peer_gone_and_back_publishing_resumes_recording_exact(
    tmp_path: Path, pty: Pty, daemons: list[Daemon], mode: str
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    peer = open_bus(ZenohSettings(listen=(endpoint,)))  # the router/solver the daemon joins
    col = Collector(peer)
    out = tmp_path / "out"
    cfg = tmp_path / "gs.toml"
    listen = f'"tcp/127.0.0.1:{free_port()}"' if mode == "peer" else ""
    cfg.write_text(f'[zenoh]\nmode = "{mode}"\nlisten = [{listen}]\nconnect = ["{endpoint}"]\n')
    d = Daemon("--port", str(pty.link), "--station", STATION, "--out-dir", str(out),
               "--config", str(cfg))
    daemons.append(d)
    d.wait_for("connected")
    d.wait_for("publishing on Zenoh")
    sent = bytearray()
    lock = threading.Lock()
    stop = threading.Event()

    def fly() -> None:  # 5 Hz epochs, a mark every other epoch, until told to stop
        k = 0
        while not stop.is_set():
            data = epoch_with_mark(k, k // 2 if k % 2 == 0 else None, SATS, WEEK, TOW0_MS)
            with lock:
                pty.write(data)
                sent.extend(data)
            k += 1
            time.sleep(0.2)

    flight = threading.Thread(target=fly, daemon=True)
    flight.start()
    try:
        wait_until(lambda: len(col.of("timemark")) >= 5)
        peer.close()  # the peer goes away mid-stream
        gone_at = time.monotonic()
        d.wait_for("alert: Zenoh: no peer or router connected", timeout_s=6.0, after=gone_at)
        peer = open_bus(ZenohSettings(listen=(endpoint,)))  # back, on the same port
        d.wait_for("alert cleared: OK: Zenoh connected again", timeout_s=10.0,
                   after=gone_at)
        col = Collector(peer)
        wait_until(lambda: len(col.of("timemark")) >= 5, timeout_s=15)
        back = col.of("timemark")
        assert [int(m["count"]) for m in back] == list(  # type: ignore[call-overload]
            range(int(back[0]["count"]), int(back[0]["count"]) + len(back)))  # type: ignore[call-overload]
        wait_until(lambda: len(col.of("status")) >= 2)
        assert time.monotonic() - gone_at < 20
        # the marks published while the peer was away are not lost: the queryable has them all
        replies = peer.get(key(STATION, "q/timemarks"), timeout_s=3.0)
        counts = [decode(p)["count"] for _, p in replies]
        assert counts == list(range(len(counts))) and counts[-1] >= back[-1]["count"]
    finally:
        stop.set()
        flight.join()
        peer.close()
    wait_for_size(one(out, "zt_*.ubx"), len(sent))
    rc, _ = d.stop(signal.SIGTERM)
    assert rc == 0, d.stderr
    assert one(out, "zt_*.ubx").read_bytes() == bytes(sent)
    raw, _, events = raw_from_mcap(one(out, "zt_*.mcap"))
    assert raw == bytes(sent)
    kinds = [e["kind"] for e in events if str(e["kind"]).startswith("zenoh.")]
    assert kinds == ["zenoh.disconnected", "zenoh.connected"]
