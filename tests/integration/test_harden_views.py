"""The views against what a peer or a browser may send: real Zenoh on loopback, real HTTP.

- ``watch`` (a real process) draws an event whose values are ``null`` (``messages.py`` allows
  it for any field) instead of ending with a TypeError.
- The dashboard's ``POST /api/ack`` checks ``Host`` and ``Origin``: a page of another origin
  whose name resolves to 127.0.0.1 (DNS rebinding) cannot clear the missed-marks alert.
- 200 held connections keep at most ``MAX_CONNECTIONS`` threads; the rest are told 503.
- A client that disconnects mid-request, or sends a bad ``Content-Length``, is counted and
  logged at debug: no traceback.
"""

from __future__ import annotations

import http.client
import logging
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from peers import Received, free_port, wait_until
from statuses import drawn_status, run_watch

from groundstation import jsonio
from groundstation.bus import Bus, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.view.dashboard.server import MAX_CONNECTIONS, Dashboard, DashboardSettings
from groundstation.view.watch import WatchState, render

NULL_EVENT = (b'{"schema":1,"type":"event","station":"p","kind":"link.dropout",'
              b'"t_host_ns":null,"message":null,"severity":null,"data":null}')


def _status() -> bytes:
    return drawn_status(time.time_ns(), marks=(3, 1), alerts=("marks_missed",))


def test_watch_draws_an_event_of_nulls() -> None:
    state = WatchState("p")
    state.on_payload("groundstation/p/status", _status())
    state.on_payload("groundstation/p/event", NULL_EVENT)
    assert state.rejected == 0 and len(state.events) == 1  # a valid message: shown
    text = _text(render(state))
    assert "--:--:-- link.dropout" in text


def _text(renderable: Any) -> str:
    import io

    from rich.console import Console

    out = io.StringIO()
    Console(file=out, width=160, color_system=None).print(renderable)
    return out.getvalue()


def test_watch_process_keeps_going_after_an_event_of_nulls(tmp_path: Path) -> None:
    """Before: the first refresh after the event ended ``watch`` (TypeError, exit 1)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pub: Bus = open_bus(ZenohSettings(listen=(endpoint,), connect=()))
    stop = threading.Event()

    def talk() -> None:
        while not stop.is_set():
            pub.put(key("p", "status"), _status())
            pub.put(key("p", "event"), NULL_EVENT)
            stop.wait(0.3)

    talker = threading.Thread(target=talk, daemon=True)
    talker.start()
    try:
        watch = run_watch(endpoint, 3, tmp_path / "watch.txt")
        assert watch.returncode == 0, watch.stderr
        assert "Traceback" not in watch.stderr and "TypeError" not in watch.stderr
        assert "--:--:-- link.dropout" in watch.stdout
        assert "bad messages dropped" not in watch.stdout
    finally:
        stop.set()
        talker.join(timeout=5)
        pub.close()


# -- the dashboard over real HTTP ---------------------------------------------------------------


@pytest.fixture
def dashboard() -> Iterator[tuple[Dashboard, Bus]]:
    """A real dashboard server on a free port, on a real Zenoh session (loopback), and the
    test's own session on that bus."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = open_bus(ZenohSettings(listen=(endpoint,), connect=()))
    dash = Dashboard(DashboardSettings(stations=("p",), port=0,
                                       bus=ZenohSettings(listen=(), connect=(endpoint,))))
    dash.start()
    try:
        yield dash, bus
    finally:
        dash.close()
        bus.close()


def _post(dash: Dashboard, path: str, headers: dict[str, str]) -> int:
    addr, port = dash.http.server_address[:2]
    conn = http.client.HTTPConnection(str(addr), int(port), timeout=10)
    try:
        conn.putrequest("POST", path, skip_host=True, skip_accept_encoding=True)
        for name, value in headers.items():
            conn.putheader(name, value)
        conn.endheaders()
        resp = conn.getresponse()
        resp.read()
        return resp.status
    finally:
        conn.close()


def test_ack_from_another_origin_is_refused(dashboard: tuple[Dashboard, Bus]) -> None:
    """What a DNS-rebinding page sends (its own name in Host and Origin, the custom header a
    same-origin fetch may set) must not reach the daemon; the dashboard's own page's does."""
    dash, bus = dashboard
    acks = Received(bus, key("p", "ack"), parse=jsonio.loads)
    port = dash.http.server_address[1]
    path = "/api/ack?station=p&alert=marks_missed"
    ours = f"127.0.0.1:{port}"
    # the subscription reaches the dashboard's session first (on a loaded machine a put made
    # at once could pass before it): the page's own acknowledgement until one arrives
    wait_until(lambda: _post(dash, path, {"Host": ours, "X-Groundstation": "ack"}) == 200
               and len(acks.all()) >= 1, 30, what="the subscription to the acknowledgements",
               poll_s=0.5)
    before = len(acks.all())
    foreign = [
        {"Host": f"rebind.attacker.example:{port}",
         "Origin": f"http://rebind.attacker.example:{port}"},
        {"Host": ours, "Origin": f"http://rebind.attacker.example:{port}"},
        {"Host": ours, "Origin": "null"},
        {"Host": ours, "Origin": f"http://127.0.0.1:{port + 1}"},
        {"Host": ours, "Origin": f"https://127.0.0.1:{port}"},
    ]
    for headers in foreign:
        assert _post(dash, path, {**headers, "X-Groundstation": "ack"}) == 421, headers
    assert dash.http.stats["refused_foreign"] == len(foreign)
    # the page itself (same origin), and a client that is no browser (no Origin)
    assert _post(dash, path, {"Host": ours, "Origin": f"http://{ours}",
                              "X-Groundstation": "ack"}) == 200
    assert _post(dash, path, {"Host": f"localhost:{port}", "X-Groundstation": "ack"}) == 200
    wait_until(lambda: len(acks.all()) >= before + 2, what="the two acknowledgements on the bus")
    assert {a["alert"] for a in acks.all()} == {"marks_missed"}


def test_held_connections_keep_a_bounded_number_of_threads(
    dashboard: tuple[Dashboard, Bus],
) -> None:
    dash, _ = dashboard
    dash.http.idle_timeout_s = 600.0  # none of them dropped for idling during the test
    addr, port = dash.http.server_address[:2]
    before = threading.active_count()
    held: list[socket.socket] = []
    try:
        for _ in range(200):  # slow clients: connected, sending nothing
            held.append(socket.create_connection((str(addr), int(port)), timeout=10))
        wait_until(lambda: dash.http.stats["refused_busy"] == 200 - MAX_CONNECTIONS,
                   what="the connections beyond the bound refused")
        assert dash.http.stats["connections"] == MAX_CONNECTIONS
        assert threading.active_count() <= before + MAX_CONNECTIONS
        assert held[-1].recv(200).startswith(b"HTTP/1.1 503")
    finally:
        for s in held:
            s.close()

    def served() -> bool:  # the slots come back as the held connections close
        conn = http.client.HTTPConnection(str(addr), int(port), timeout=10)
        try:
            conn.request("GET", "/api/stations")
            return conn.getresponse().status == 200
        finally:
            conn.close()

    wait_until(served, what="a request served again")


def test_an_idle_client_is_dropped_and_its_thread_freed(
    dashboard: tuple[Dashboard, Bus],
) -> None:
    dash, _ = dashboard
    dash.http.idle_timeout_s = 0.2
    addr, port = dash.http.server_address[:2]
    with socket.create_connection((str(addr), int(port)), timeout=30) as s:
        s.sendall(b"GET / HTTP/1.1\r\n")  # and never the rest
        assert s.recv(100) == b""  # closed by the server
    wait_until(lambda: dash.http.stats["bad_requests"] == 1, what="the timeout counted")


def _raw(dash: Dashboard, request: bytes, *, reset: bool = False) -> bytes:
    """``request`` sent on a new connection; the reply, or nothing when ``reset`` (the
    connection is then torn down with a TCP reset, as a killed browser tab does)."""
    addr, port = dash.http.server_address[:2]
    with socket.create_connection((str(addr), int(port)), timeout=10) as s:
        s.sendall(request)
        if reset:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            return b""
        out = b""
        while chunk := s.recv(4096):
            out += chunk
        return out


@pytest.mark.parametrize("length", ["abc", "\u00b2", "-5", "+5", "1e3", "99999999999"])
def test_a_bad_content_length_is_a_400_without_a_traceback(
    dashboard: tuple[Dashboard, Bus], capfd: pytest.CaptureFixture[str], length: str,
) -> None:
    dash, _ = dashboard
    port = dash.http.server_address[1]
    reply = _raw(dash, (f"POST /api/ack?station=p HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                        f"X-Groundstation: ack\r\nContent-Length: {length}\r\n\r\n"
                        ).encode())
    assert reply.startswith(b"HTTP/1.1 400"), reply[:100]
    assert dash.http.stats["bad_requests"] == 1
    assert "Traceback" not in capfd.readouterr().err


def test_a_client_gone_mid_request_is_counted_quietly(
    dashboard: tuple[Dashboard, Bus], capfd: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The body announced never comes: the connection is reset while the server reads it."""
    dash, _ = dashboard
    port = dash.http.server_address[1]
    with caplog.at_level(logging.DEBUG, "groundstation.dashboard"):
        _raw(dash, (f"POST /api/ack?station=p HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                    "X-Groundstation: ack\r\nContent-Length: 100\r\n\r\n").encode(),
             reset=True)
        wait_until(lambda: dash.http.stats["disconnects"] == 1, what="the disconnect counted")
    assert "Traceback" not in capfd.readouterr().err
    assert any(r.levelno == logging.DEBUG and "went away" in r.getMessage()
               for r in caplog.records)
