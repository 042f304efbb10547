"""What a peer on the bus may send the daemon: real Zenoh sessions on loopback, a real daemon.

- A ``q/recording`` chunk query with an offset of digits that are not ASCII (``²``: ``isdigit``
  took it, ``int`` did not) gets an error reply, not silence and a traceback; any failure of
  a queryable is answered with an error too.
- Acknowledgements are rate-limited: a flood of them adds a bounded number of ``operator.ack``
  events to the recording, and the daemon says how many it dropped.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest
from peers import Daemon, Pty, free_port

from groundstation import events as kinds
from groundstation import jsonio
from groundstation.bus import Bus, Reply, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.live.publisher import ACK_BURST, ACK_PER_S
from groundstation.live.serve import RecordingServer
from groundstation.storage import iter_messages
from groundstation.storage.transfer import BadRequest, parse_request

SID = "st_20250602T080000Z-abcdef"
NAME = "st_20250602T080000Z.mcap"


@pytest.fixture
def buses() -> Iterator[tuple[Bus, Bus]]:
    """A daemon-side session listening on loopback and a peer connected to it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    daemon = open_bus(ZenohSettings(listen=(endpoint,), connect=()))
    peer = open_bus(ZenohSettings(listen=(), connect=(endpoint,)))
    yield daemon, peer
    peer.close()
    daemon.close()


def _ask(peer: Bus, key_expr: str, params: Mapping[str, str]) -> list[Reply]:
    """A query's replies, once the queryable is known to the peer."""
    deadline = time.monotonic() + 10
    while True:
        replies = peer.ask(key_expr, params, timeout_s=5.0)()
        if replies or time.monotonic() > deadline:
            return replies


@pytest.mark.parametrize("offset", ["\u00b2", "\u0663", "\uff11", "1\u00b2"])
def test_a_chunk_query_with_other_digits_gets_an_error_reply(
    buses: tuple[Bus, Bus], tmp_path: Path, caplog: pytest.LogCaptureFixture, offset: str,
) -> None:
    """``²`` made ``int`` raise in the queryable: no reply (the fetcher waited for its timeout)
    and a traceback in the daemon's log. ``١`` and the full-width ``１`` were taken as 3 and 1."""
    daemon, peer = buses
    path = tmp_path / NAME
    path.write_bytes(bytes(range(256)) * 4)
    server = RecordingServer("st")
    assert server.add(path, SID) is not None
    server.bind(daemon)
    with caplog.at_level(logging.WARNING):
        (reply,) = _ask(peer, key("st", f"q/recording/{SID}"),
                        {"file": NAME, "offset": offset, "length": "16"})
    assert reply.error and b"offset: expected an integer" in reply.payload
    assert server.refused == 1 and server.sent_bytes == 0
    assert "Traceback" not in caplog.text and not any(r.exc_info for r in caplog.records)
    with pytest.raises(BadRequest):
        parse_request({"file": NAME, "offset": "0", "length": offset})


def test_a_failing_queryable_answers_with_an_error(
    buses: tuple[Bus, Bus], caplog: pytest.LogCaptureFixture,
) -> None:
    daemon, peer = buses

    def broken(_key: str, _params: Mapping[str, str | None]) -> list[Reply]:
        raise RuntimeError("a bug")

    daemon.answer(key("st", "q/broken"), broken)
    with caplog.at_level(logging.DEBUG, "groundstation.zenoh"):
        replies = _ask(peer, key("st", "q/broken"), {})
    assert len(replies) == 1, replies
    (reply,) = replies
    assert reply.error and reply.payload == b"failed: RuntimeError"
    errors = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 1 and "a bug" in errors[0].getMessage() and not errors[0].exc_info


def test_a_flood_of_acknowledgements_is_rate_limited(
    tmp_path: Path, pty: Pty, daemons: list[Daemon],
) -> None:
    """Before: each of 50 000 acknowledgements in a second became an ``operator.ack`` event,
    2 MB added to the recording."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    daemon = Daemon("--port", str(pty.link), "--station", "ackst", "--out-dir", str(tmp_path),
                    "--zenoh-listen", endpoint)
    daemons.append(daemon)
    daemon.wait_for("publishing on Zenoh")
    started = time.monotonic()
    bus = open_bus(ZenohSettings(mode="client", connect=(endpoint,), listen=()))
    flood = 5000
    try:
        ack = jsonio.dumps({"alert": "marks_missed", "by": "flood"})
        for _ in range(flood):
            bus.put(key("ackst", "ack"), ack)
        daemon.wait_for("acknowledgements beyond", timeout_s=20)
    finally:
        bus.close()
    daemon.stop()
    elapsed_s = time.monotonic() - started  # the daemon took acknowledgements within this
    (mcap,) = tmp_path.glob("*.mcap")
    recorded = [json.loads(m.data) for m in iter_messages(mcap, ["/groundstation/event"])]
    acks = [e for e in recorded if e["kind"] == kinds.OPERATOR_ACK]
    assert ACK_BURST + ACK_PER_S * elapsed_s + 1 >= len(acks) >= 1, (len(acks), elapsed_s)
    assert len(acks) < flood // 10
    assert "dropped so far" in daemon.stderr
