"""The dashboard's local web server: Zenoh in, the page and a Server-Sent Events stream out.

:class:`Hub` subscribes to every station's status, events, time marks and session on the bus,
discovers stations from their liveliness tokens, catches up from the ``q/status`` and
``q/timemarks`` queryables whenever a daemon (re)appears, and folds everything into one
:class:`~groundstation.view.dashboard.state.StationView` per station. :class:`DashboardServer`
(standard library ``ThreadingHTTPServer``) serves the static page shipped in the package and
pushes a JSON snapshot of the selected station over ``/events`` (chunked ``text/event-stream``)
whenever something changes, and at least once a second so that staleness shows.
"""

from __future__ import annotations

import logging
import queue
import shutil
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import parse_qs, urlsplit

from groundstation import jsonio
from groundstation.bus import KEY_ROOT, key, open_bus
from groundstation.config import CLIENT_ZENOH, STATION_NAME, ZenohSettings
from groundstation.view.dashboard.state import FileInfo, StationView

log = logging.getLogger("groundstation.dashboard")

LEAVES = ("status", "event", "timemark", "session", "solution", "rtk")
"""What the dashboard subscribes to (not ``epoch``/``ubx``: they are heavy and not shown)."""
HEARTBEAT_S = 1.0
MIN_PUSH_INTERVAL_S = 0.2
SSE_RETRY_MS = 1000
CATCH_UP_TIMEOUT_S = 2.0
FILE_INFO_TTL_S = 2.0
MAX_STATIONS = 256
MAX_CONNECTIONS = 32
"""Connections served at once, each on its own thread (an open page holds one for its event
stream); one more is answered 503 at once and closed, without a thread."""
IDLE_TIMEOUT_S = 10.0
"""A client that sends nothing (or takes no bytes of the event stream) for this long is
dropped: a slow or stalled client cannot keep a thread for ever."""
MAX_BODY_BYTES = 4096
"""The largest request body read (``POST /api/ack`` needs none)."""
OVERFLOW_STATION = "_more"
"""Where payloads of stations beyond :data:`MAX_STATIONS` are counted."""
STATIC_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
}


SECURITY_HEADERS = (
    ("Content-Security-Policy",
     ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
      "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")),
    ("X-Content-Type-Options", "nosniff"),
    ("X-Frame-Options", "DENY"),
    ("Referrer-Policy", "no-referrer"),
)
"""Sent with every response: the page runs only its own script and style, cannot be framed,
and no type is sniffed (``docs/security.md``)."""


def allowed_hosts(bind: str) -> frozenset[str]:
    """Host names the server answers to: its bind address, the loopback names and this
    machine's names. Any IP literal is accepted too (a DNS-rebinding attack needs a name that
    the attacker's DNS resolves to us; a literal address names the server directly)."""
    import socket

    # gethostname only: getfqdn would ask DNS, which may hang without a network
    names = {bind.lower().strip("[]"), "localhost", "127.0.0.1", "::1",
             socket.gethostname().lower()}
    return frozenset(n for n in names if n)


def origin_ok(header: str | None, hosts: frozenset[str], port: int) -> bool:
    """Whether a request's ``Origin`` header (sent by browsers) is this server's own origin:
    ``http://<a name of ours or an IP literal>:<our port>``. No header is no browser page (a
    page's ``fetch`` and form posts always send one), so nothing to check; ``null`` (a
    sandboxed or file page) is refused."""
    if header is None:
        return True
    try:
        parts = urlsplit(header.strip())
        got_port = parts.port or 80
    except ValueError:
        return False
    if parts.scheme != "http" or parts.path not in ("", "/") or got_port != port:
        return False
    return host_ok(parts.netloc, hosts, port)


def host_ok(header: str | None, hosts: frozenset[str], port: int) -> bool:
    """Whether a request's ``Host`` header names this server (name and port)."""
    import ipaddress

    if not header:
        return False
    try:
        parts = urlsplit("//" + header.strip())
        host, got_port = (parts.hostname or "").lower(), parts.port
    except ValueError:  # a malformed port
        return False
    if got_port is not None and got_port != port:
        return False
    if host in hosts:
        return True
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


class BusLike(Protocol):
    """The part of :class:`groundstation.bus.Bus` the hub uses (a fake in unit tests)."""

    def subscribe(self, key_expr: str, callback: Callable[[str, bytes], None]) -> None: ...

    def subscribe_liveliness(
        self, key_expr: str, callback: Callable[[str, bool], None]
    ) -> None: ...

    def get(self, selector: str, timeout_s: float = 2.0) -> list[tuple[str, bytes]]: ...

    def put(self, key_expr: str, payload: bytes) -> None: ...

    def close(self) -> None: ...


def station_of(key_expr: str) -> str | None:
    """``groundstation/<station>/...`` -> ``<station>``."""
    parts = key_expr.split("/")
    if len(parts) < 3 or parts[0] != KEY_ROOT or not STATION_NAME.fullmatch(parts[1]):
        return None
    return parts[1]


class LocalFiles:
    """Size of the recording and free disk space, when the daemon writes on this machine.

    Cached for :data:`FILE_INFO_TTL_S` per path: every SSE push asks.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._cache: dict[str, tuple[float, FileInfo]] = {}
        self._lock = threading.Lock()

    def __call__(self, path: str) -> FileInfo:
        now = self._clock()
        with self._lock:
            hit = self._cache.get(path)
            if hit is not None and now - hit[0] < FILE_INFO_TTL_S:
                return hit[1]
        info = _probe(path)
        with self._lock:
            self._cache[path] = (now, info)
        return info


def _probe(path: str) -> FileInfo:
    p = Path(path)
    try:
        size: int | None = p.stat().st_size
    except OSError:
        size = None
    try:
        usage = shutil.disk_usage(p.parent)
        return FileInfo(size, usage.free, usage.total)
    except OSError:
        return FileInfo(size, None, None)


@dataclass(frozen=True, slots=True)
class DashboardSettings:
    """What ``groundstation dashboard`` runs with.

    Attributes:
        stations: stations shown even before they are heard of (others are discovered).
        bind: address of the web server (loopback by default).
        port: web server port (0: any free port).
        bus: how to join Zenoh.
        ppk_ready_min: satellites with clean phase the PPK gauge asks for (None: the
            daemon's ``[monitor]`` ``ppk_ready_min``, which its status carries).
    """

    stations: tuple[str, ...] = ()
    bind: str = "127.0.0.1"
    port: int = 8080
    bus: ZenohSettings = CLIENT_ZENOH
    ppk_ready_min: int | None = None


class Hub:
    """Every station's view, fed from the bus; thread-safe (Zenoh threads write, HTTP threads
    read)."""

    def __init__(
        self,
        stations: tuple[str, ...] = (),
        *,
        clock: Callable[[], float] = time.monotonic,
        file_info: Callable[[str], FileInfo] | None = None,
        ppk_ready_min: int | None = None,
    ) -> None:
        self._clock = clock
        self._file_info = file_info or LocalFiles(clock)
        self.ppk_ready_min = ppk_ready_min
        self.views: dict[str, StationView] = {s: StationView(s) for s in stations}
        self.cond = threading.Condition()
        self.version = 0
        self.closed = False
        self._bus: BusLike | None = None
        self._catch_up: queue.Queue[str | None] = queue.Queue()
        self._worker: threading.Thread | None = None

    # -- bus side ------------------------------------------------------------------------

    def attach(self, bus: BusLike) -> None:
        """Subscribe to all stations, and catch up with the ones already listed."""
        self._bus = bus
        self._worker = threading.Thread(target=self._catch_up_loop, name="dashboard-catch-up",
                                        daemon=True)
        self._worker.start()
        for leaf in LEAVES:
            bus.subscribe(key("*", leaf), self.on_payload)
        bus.subscribe_liveliness(key("*", "alive/**"), self.on_alive)
        for station in list(self.views):
            self._catch_up.put(station)

    def _view(self, station: str) -> StationView:
        view = self.views.get(station)
        if view is None and len(self.views) >= MAX_STATIONS:
            # a flood of invented names must not grow the hub: fold them into one view
            station = OVERFLOW_STATION
            view = self.views.get(station)
        if view is None:
            log.info("station %s discovered", station)
            view = self.views[station] = StationView(station)
        return view

    def _changed(self) -> None:
        self.version += 1
        self.cond.notify_all()

    def on_payload(self, key_expr: str, payload: bytes) -> None:
        """A sample from the bus (on a Zenoh thread)."""
        station = station_of(key_expr)
        if station is None:
            return
        with self.cond:
            view = self._view(station)
            if view.on_payload(key_expr, payload, self._clock()):
                self._changed()
            again = view.session_changed
            view.session_changed = False
        if again:  # a new daemon session: its marks so far arrived before we knew
            self._catch_up.put(station)

    def on_alive(self, key_expr: str, alive: bool) -> None:
        """A daemon's liveliness token (``.../alive/<id>``) appeared (daemon started) or went
        away."""
        station = station_of(key_expr)
        if station is None:
            return
        instance = key_expr.split("/alive", 1)[-1].lstrip("/")
        with self.cond:
            self._view(station).on_alive(alive, instance)
            self._changed()
        log.info("station %s %s", station, "alive" if alive else "gone")
        if alive:
            self._catch_up.put(station)  # a (re)started daemon: fetch its state now

    def _catch_up_loop(self) -> None:
        """Query a station's latest status and marks (off the Zenoh threads: ``get`` blocks)."""
        while True:
            station = self._catch_up.get()
            if station is None or self._bus is None:
                return
            for leaf in ("q/status", "q/timemarks"):
                try:
                    replies = self._bus.get(key(station, leaf), timeout_s=CATCH_UP_TIMEOUT_S)
                except Exception:  # the bus may be closing; the subscription still feeds us
                    log.warning("query %s failed", key(station, leaf), exc_info=True)
                    continue
                for k, payload in replies:
                    self.on_payload(k, payload)

    def acknowledge(self, station: str, alert: str, by: str) -> bool:
        """Put an operator's acknowledgement on ``groundstation/<station>/ack``: the daemon
        clears the alert for every view (and records it). False without a bus."""
        bus = self._bus
        if bus is None or station not in self.views:
            return False
        bus.put(key(station, "ack"), jsonio.dumps({"alert": alert, "by": by}))
        return True

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()
        self._catch_up.put(None)
        if self._worker is not None:
            self._worker.join(timeout=CATCH_UP_TIMEOUT_S + 1)

    # -- page side -------------------------------------------------------------------------

    def stations(self) -> list[dict[str, Any]]:
        now = self._clock()
        with self.cond:
            return [
                {"name": v.station, "alive": v.alive, "stale": v.stale(now),
                 "has_status": v.status is not None, "finished": v.finished(),
                 "status_age_s": v.status_age_s(now),
                 "alerts": len((v.status or {}).get("alerts") or [])}
                for v in sorted(self.views.values(), key=lambda v: v.station)
            ]

    def default_station(self) -> str | None:
        with self.cond:
            if not self.views:
                return None
            live = [s for s, v in self.views.items() if v.status is not None]
            return live[0] if live else next(iter(self.views))

    def report_path(self, station: str | None, pdf: bool) -> Path | None:
        """The latest report file the solver announced for a station (None if none)."""
        with self.cond:
            view = self.views.get(station or self.default_station() or "")
            msg = view.report if view is not None else None
        value = msg.get("report_pdf" if pdf else "report") if msg else None
        return Path(value) if isinstance(value, str) else None

    def document(self, station: str | None) -> dict[str, Any]:
        """What one SSE message carries: the station list and the chosen station's view."""
        chosen = station or self.default_station()
        stations = self.stations()
        now = self._clock()
        with self.cond:
            view = self.views.get(chosen) if chosen else None
            snap = (view.snapshot(now, file_info=self._file_info,
                                  ppk_ready_min=self.ppk_ready_min)
                    if view is not None else None)
        return {"stations": stations, "station": chosen, "view": snap,
                "server_time_s": time.time()}


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server: DashboardHTTPServer

    def setup(self) -> None:
        super().setup()
        self.connection.settimeout(self.server.idle_timeout_s)  # every read and write

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (stdlib signature)
        log.debug("%s " + format, self.address_string(), *args)

    def log_error(self, format: str, *args: Any) -> None:  # noqa: A002 (stdlib signature)
        """The standard library's own refusals (a malformed request line or header, a request
        that timed out): counted, logged at debug."""
        self.server.count("bad_requests")
        log.debug("%s " + format, self.address_string(), *args)

    def end_headers(self) -> None:
        for name, value in SECURITY_HEADERS:
            self.send_header(name, value)
        super().end_headers()

    def _foreign(self, *, origin: bool) -> bool:
        """Refuse (421, and True) a request that does not name this server: its ``Host``,
        and for a state-changing request its ``Origin`` too (``docs/security.md``: a page of
        another origin whose name resolves to us, DNS rebinding, names itself in both)."""
        srv = self.server
        host = self.headers.get("Host")
        if not host_ok(host, srv.hosts, srv.server_port):
            what = f"Host {host!r}"
        elif origin and not origin_ok(self.headers.get("Origin"), srv.hosts, srv.server_port):
            what = f"Origin {self.headers.get('Origin')!r}"
        else:
            return False
        srv.count("refused_foreign")
        log.warning("refused a %s request for %s from %s (DNS rebinding?)", self.command, what,
                    self.address_string())
        self.close_connection = True
        self._send(HTTPStatus.MISDIRECTED_REQUEST, b"unknown host\n", "text/plain; charset=utf-8")
        return True

    def _bad_request(self, why: str) -> None:
        """A malformed request: 400 with the reason, the connection closed (what follows on
        it cannot be trusted to start a request); counted, logged at debug."""
        self.server.count("bad_requests")
        log.debug("bad request from %s: %s", self.address_string(), why)
        self.close_connection = True
        self._send(HTTPStatus.BAD_REQUEST, why.encode() + b"\n", "text/plain; charset=utf-8")

    def do_GET(self) -> None:
        if self._foreign(origin=False):
            return
        url = urlsplit(self.path)
        query = parse_qs(url.query)
        station = (query.get("station") or [""])[0] or None
        hub = self.server.hub
        if url.path == "/events":
            self._events(station)
        elif url.path == "/api/snapshot":
            self._json(hub.document(station))
        elif url.path == "/api/stations":
            self._json(hub.stations())
        elif url.path == "/report":
            self._report(station, (query.get("format") or [""])[0] == "pdf")
        elif url.path in ("/", "/index.html"):
            self._static("index.html")
        elif url.path.startswith("/static/"):
            self._static(url.path.removeprefix("/static/"))
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")

    def do_POST(self) -> None:
        """``POST /api/ack?station=S&alert=A``: the operator's acknowledgement. The custom
        header makes a cross-site form or fetch impossible without a CORS preflight, which
        this server never grants, so only the dashboard page itself can acknowledge."""
        if self._foreign(origin=True):
            return
        url = urlsplit(self.path)
        query = parse_qs(url.query)
        declared = (self.headers.get("Content-Length") or "0").strip()
        # digits only: int() takes "+5", " 5", "5_0" and other scripts' digits ("²" fails)
        if not (declared.isascii() and declared.isdigit()):
            self._bad_request(f"bad Content-Length {declared[:20]!r}")
            return
        length = int(declared)
        if length > MAX_BODY_BYTES:
            self._bad_request(f"body of {length} bytes (at most {MAX_BODY_BYTES})")
            return
        if length:
            self.rfile.read(length)
        if url.path != "/api/ack" or self.headers.get("X-Groundstation") != "ack":
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")
            return
        station = (query.get("station") or [""])[0]
        alert = (query.get("alert") or ["marks_missed"])[0][:64]
        by = f"dashboard {self.address_string()}"
        ok = self.server.hub.acknowledge(station, alert, by)
        self._send(HTTPStatus.OK if ok else HTTPStatus.SERVICE_UNAVAILABLE,
                   jsonio.dumps({"acknowledged": ok}), "application/json")

    def _send(self, code: HTTPStatus, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, doc: Any) -> None:
        self._send(HTTPStatus.OK, jsonio.dumps(doc), "application/json")

    def _static(self, name: str) -> None:
        if "/" in name or name.startswith(".") or Path(name).suffix not in STATIC_TYPES:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")
            return
        res = resources.files("groundstation.view.dashboard").joinpath("static", name)
        if not res.is_file():
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8")
            return
        self._send(HTTPStatus.OK, res.read_bytes(), STATIC_TYPES[Path(name).suffix])

    def _report(self, station: str | None, pdf: bool) -> None:
        """The latest report of a station, when the solver wrote it on this machine. Only the
        exact file the solver announced is served (named report.html or report.pdf)."""
        path = self.server.hub.report_path(station, pdf)
        name = "report.pdf" if pdf else "report.html"
        if path is None or path.name != name or not path.is_file():
            self._send(HTTPStatus.NOT_FOUND, b"no report on this machine yet\n",
                       "text/plain; charset=utf-8")
            return
        ctype = "application/pdf" if pdf else "text/html; charset=utf-8"
        self._send(HTTPStatus.OK, path.read_bytes(), ctype)

    def _chunk(self, data: bytes) -> None:
        self.wfile.write(f"{len(data):x}\r\n".encode() + data + b"\r\n")
        self.wfile.flush()

    def _events(self, station: str | None) -> None:
        """Server-Sent Events: a snapshot on every change (at most every 0.2 s) and at least
        every second; the browser's EventSource reconnects by itself (``retry``)."""
        hub = self.server.hub
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream; charset=utf-8")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Transfer-Encoding", "chunked")
        self.end_headers()
        self.close_connection = True
        seen = -1
        try:
            self._chunk(f"retry: {SSE_RETRY_MS}\n\n".encode())
            while True:
                with hub.cond:
                    if hub.version == seen and not hub.closed:
                        hub.cond.wait(HEARTBEAT_S)
                    if hub.closed:
                        break
                    seen = hub.version
                doc = jsonio.dumps(hub.document(station)).decode()
                self._chunk(f"event: snapshot\ndata: {doc}\n\n".encode())
                time.sleep(MIN_PUSH_INTERVAL_S)
            self.wfile.write(b"0\r\n\r\n")
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            log.debug("event stream closed by %s", self.address_string())


class DashboardHTTPServer(ThreadingHTTPServer):
    """``ThreadingHTTPServer`` that knows its hub, serves at most ``max_connections`` at once
    (:data:`MAX_CONNECTIONS`) and takes a client's going away quietly.

    What the clients did wrong is counted in :attr:`stats` (``disconnects``, ``bad_requests``
    (timed out included), ``refused_busy``, ``refused_foreign``, ``errors``; ``connections``
    served) and logged at debug: a client that
    disconnects, times out or sends a malformed request is routine for a web server, never a
    traceback on the operator's terminal.
    """

    daemon_threads = True
    block_on_close = False
    request_queue_size = 64  # the listen backlog: a burst of connections waits, not retries

    def __init__(self, address: tuple[str, int], hub: Hub,
                 max_connections: int = MAX_CONNECTIONS) -> None:
        self.hub = hub
        self.hosts = allowed_hosts(address[0])
        self.max_connections = max_connections
        self.idle_timeout_s = IDLE_TIMEOUT_S
        self._slots = threading.BoundedSemaphore(max_connections)
        self.stats: Counter[str] = Counter()
        self._stats_lock = threading.Lock()
        super().__init__(address, _Handler)

    def count(self, what: str) -> None:
        with self._stats_lock:
            self.stats[what] += 1

    def process_request(self, request: Any, client_address: Any) -> None:
        """A thread for the connection while fewer than ``max_connections`` are served;
        otherwise a 503 written at once (non-blocking) and the connection closed."""
        if not self._slots.acquire(blocking=False):
            self.count("refused_busy")
            log.debug("busy: %d connections served; refused %s", self.max_connections,
                      client_address)
            try:
                request.setblocking(False)
                request.send(b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 5\r\n"
                             b"Retry-After: 1\r\nConnection: close\r\n\r\nbusy\n")
            except OSError:
                pass  # the client's buffer is full or it is gone: closing says enough
            self.shutdown_request(request)
            return
        self.count("connections")
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()  # no thread was started to release it
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    def handle_error(self, request: Any, client_address: Any) -> None:
        """What a handler raised (``socketserver`` would print a traceback): a client gone or
        too slow is counted and logged at debug; anything else is one warning line, its
        traceback at debug."""
        err = sys.exc_info()[1]
        if isinstance(err, (ConnectionError, TimeoutError)):
            # logged before it is counted: whoever sees the count sees the line too
            log.debug("client %s went away: %s", client_address, err)
            self.count("disconnects")
            return
        self.count("errors")
        log.warning("request from %s failed: %s: %s", client_address, type(err).__name__, err)
        log.debug("request from %s failed", client_address, exc_info=True)

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        return f"http://{host!s}:{port}/"


class Dashboard:
    """The bus, the hub and the web server together; a context manager."""

    def __init__(self, settings: DashboardSettings,
                 bus_factory: Callable[[ZenohSettings], BusLike] = open_bus) -> None:
        self.settings = settings
        self.hub = Hub(settings.stations, ppk_ready_min=settings.ppk_ready_min)
        self.http = DashboardHTTPServer((settings.bind, settings.port), self.hub)
        try:
            self.bus = bus_factory(settings.bus)
        except Exception:
            self.http.server_close()
            raise
        self.hub.attach(self.bus)
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        return self.http.url

    def start(self) -> None:
        """Serve in a background thread."""
        self._thread = threading.Thread(target=self.http.serve_forever, name="dashboard-http",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop serving, end the event streams, leave the bus (reverse order of start)."""
        errors: list[BaseException] = []
        steps: list[Callable[[], None]] = [self.hub.close]
        if self._thread is not None:  # shutdown() waits for serve_forever: only if it runs
            steps.append(self.http.shutdown)
        steps += [self.http.server_close, self.bus.close]
        for step in steps:
            try:
                step()
            except Exception as err:  # keep closing the rest
                errors.append(err)
        if self._thread is not None:
            self._thread.join(timeout=5)
        if errors:
            log.warning("dashboard close: %s", "; ".join(map(str, errors)))

    def __enter__(self) -> Dashboard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
