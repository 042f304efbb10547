"""The Zenoh bus: the one module that imports zenoh. Sessions, keys, JSON payloads.

A session is opened from :class:`~groundstation.config.ZenohSettings` (the one Zenoh settings
type) and listens exactly where it says: an empty ``listen`` list opens no listener (Zenoh's own
default would be every interface, ``tcp/[::]:0``).

Several daemons on one machine share the default settings (``docs/zenoh.md``, "Several
stations on one machine"): a peer whose ``listen`` endpoint is already taken joins it as a
client instead (the first daemon up is the meeting point and routes for the others and for the
views); when the meeting point goes away, a joined session notices within a second, waits a
random moment (so that not every daemon tries at once), takes the endpoint over by listening
on it, or joins whoever took it first, and declares again everything it had declared.

Key space (DESIGN.md): ``groundstation/<station>/{status,timemark,event,epoch,ubx,session,
q/timemarks,q/status,q/session,q/recording/<session_id>,alive,solution,q/solution}`` and the
solver workers' claims ``groundstation/solvers/claim/...``. Payloads are UTF-8 JSON objects
carrying ``schema`` (:data:`~groundstation.records.STATUS_SCHEMA_VERSION`) and ``type``;
``docs/zenoh.md`` lists every key and field.
"""

from __future__ import annotations

import contextlib
import logging
import random
import re
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import zenoh

from groundstation import jsonio
from groundstation.config import ZenohSettings
from groundstation.records import STATUS_SCHEMA_VERSION

log = logging.getLogger("groundstation.zenoh")

KEY_ROOT = "groundstation"

TAKEOVER_GRACE_S = 0.5
"""A joined session with no link for this long has lost its meeting point."""
TAKEOVER_JITTER_S = 1.0
"""Up to this long (random) before trying to take the endpoint over: the joined daemons do not
all try at the same instant, so one wins and the others join it at once."""
_CHECK_S = 0.2


@dataclass(frozen=True, slots=True)
class Reply:
    """One reply to a query (sent by a queryable, or received by :meth:`Bus.ask`).

    Attributes:
        key: the key expression it answers on.
        payload: the bytes; for an ``error`` reply, the queryable's one-line refusal.
        attachment: Zenoh's attachment (the chunk's offset and CRC of a recording chunk).
        error: a refusal (Zenoh's ``reply_err``), not data.
    """

    key: str
    payload: bytes
    attachment: bytes | None = None
    error: bool = False


def intersects(key_a: str, key_b: str) -> bool:
    """Whether two key expressions share a key (False when either is not a key expression)."""
    try:
        return bool(zenoh.KeyExpr(key_a).intersects(zenoh.KeyExpr(key_b)))
    except Exception:  # zenoh's own error type for a malformed key expression
        return False


def key(station: str, leaf: str) -> str:
    """``groundstation/<station>/<leaf>``."""
    return f"{KEY_ROOT}/{station}/{leaf}"


def encode(kind: str, record: Any, **extra: Any) -> bytes:
    """A record (dataclass or dict) as a JSON payload led by ``schema``, ``type`` and ``extra``
    (:func:`groundstation.jsonio.dumps_with`: NaN and infinity become ``null``)."""
    return jsonio.dumps_with({"schema": STATUS_SCHEMA_VERSION, "type": kind, **extra}, record)


def decode(payload: bytes) -> dict[str, Any]:
    """A JSON object payload.

    Raises:
        ValueError: not JSON, or not an object.
    """
    out = jsonio.loads(payload)
    if not isinstance(out, dict):
        raise ValueError("payload is not a JSON object")
    return out


_RUST_WHERE = re.compile(r"\s+at /\S+\.rs:\d+\.?")


def error_text(err: BaseException) -> str:
    """Zenoh's error message on one line, without the Rust source locations it carries."""
    return " ".join(_RUST_WHERE.sub("", str(err)).split()).strip(" .[]") or type(err).__name__


def _address_in_use(err: BaseException) -> bool:
    text = str(err)
    return "Address already in use" in text or "os error 98" in text


def _tls_json(settings: ZenohSettings) -> dict[str, Any]:
    """Zenoh's ``transport/link/tls`` table for these settings (empty: no TLS)."""
    tls: dict[str, Any] = {}
    if settings.tls_ca:
        tls["root_ca_certificate"] = str(settings.tls_ca)
    if settings.tls_certificate:
        # one certificate for both sides: a peer may listen on and connect to tls/ endpoints
        tls.update(connect_certificate=str(settings.tls_certificate),
                   connect_private_key=str(settings.tls_private_key),
                   listen_certificate=str(settings.tls_certificate),
                   listen_private_key=str(settings.tls_private_key),
                   enable_mtls=True)
    return tls


def zenoh_config(settings: ZenohSettings, extra: dict[str, Any] | None = None) -> Any:
    """A ``zenoh.Config`` for these settings; ``extra`` maps more config paths to JSON values
    (the router's access control)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", jsonio.dumps(settings.mode).decode())
    conf.insert_json5("scouting/multicast/enabled", "true" if settings.scouting else "false")
    # Always set, even empty: left out, Zenoh listens on tcp/[::]:0 (every interface).
    conf.insert_json5("listen/endpoints", jsonio.dumps(list(settings.listen)).decode())
    conf.insert_json5("connect/endpoints", jsonio.dumps(list(settings.connect)).decode())
    tls = _tls_json(settings)
    if tls:
        conf.insert_json5("transport/link/tls", jsonio.dumps(tls).decode())
    for path, value in (extra or {}).items():
        conf.insert_json5(path, jsonio.dumps(value).decode())
    return conf


def open_session(settings: ZenohSettings, extra: dict[str, Any] | None = None) -> Any:
    """A raw Zenoh session (the router keeps one open and declares nothing)."""
    return zenoh.open(zenoh_config(settings, extra))


class Bus:
    """An open Zenoh session with the few operations groundstation uses.

    Attributes:
        joined: the session joined another process's listener instead of listening itself
            (that process is the meeting point; see the module docstring).
    """

    def __init__(self, settings: ZenohSettings) -> None:
        self.settings = settings
        self._lock = threading.Lock()
        self._declare: list[Callable[[Any], Any]] = []  # to declare again on a new session
        self._declared: list[Any] = []
        self._publishers: dict[str, Any] = {}
        self._closed = threading.Event()
        self.joined = False
        self._session: Any = self._open()
        self._watcher: threading.Thread | None = None
        if self.joined:
            self._start_watcher()

    # -- opening, joining, taking over -------------------------------------------------------

    def _open(self) -> Any:
        """Listen where the settings say; a peer whose endpoint is taken joins it instead."""
        try:
            session = zenoh.open(zenoh_config(self.settings))
            self.joined = False
            return session
        except Exception as err:
            if not (self.settings.mode == "peer" and self.settings.listen
                    and _address_in_use(err)):
                raise
        joining = replace(self.settings, mode="client", listen=(),
                          connect=self.settings.listen + self.settings.connect)
        try:
            session = zenoh.open(zenoh_config(joining))
        except Exception as err:
            raise RuntimeError(
                f"{', '.join(self.settings.listen)} is taken and joining it failed "
                f"(is it another program?): {error_text(err)}") from err
        self.joined = True
        log.info("Zenoh: %s is taken: joined it (another daemon is the meeting point)",
                 ", ".join(self.settings.listen))
        return session

    def _start_watcher(self) -> None:
        if self._watcher is None:
            self._watcher = threading.Thread(target=self._watch, name="zenoh-takeover",
                                             daemon=True)
            self._watcher.start()

    def _watch(self) -> None:
        """While joined: when the meeting point goes, take over its endpoint or join anew."""
        lost_since: float | None = None
        warned = False
        while not self._closed.wait(_CHECK_S):
            if not self.joined:
                continue
            if self.connections() > 0:
                lost_since = None
                continue
            now = time.monotonic()
            lost_since = lost_since or now
            if now - lost_since < TAKEOVER_GRACE_S:
                continue
            if self._closed.wait(random.uniform(0.0, TAKEOVER_JITTER_S)):
                return
            try:
                self._reopen()
                lost_since, warned = None, False
            except Exception as err:  # nobody listens and we cannot either: try again
                if not warned:  # once per outage: it is retried every second or so
                    warned = True
                    log.warning("Zenoh: cannot take over %s yet (retrying): %s",
                                ", ".join(self.settings.listen), error_text(err))

    def _reopen(self) -> None:
        with self._lock:
            old, self._session = self._session, None
            self._publishers.clear()
            self._declared.clear()
        if old is not None:
            try:
                old.close()
            except Exception:
                log.debug("closing the old session failed", exc_info=True)
        session = self._open()
        with self._lock:
            if self._closed.is_set():
                session.close()
                return
            self._session = session
            for declare in self._declare:
                try:
                    declare(session)
                except Exception:
                    log.exception("declaring again on the new session failed")
        if not self.joined:
            log.info("Zenoh: the meeting point went away: took over %s",
                     ", ".join(self.settings.listen))

    def _add(self, declare: Callable[[Any], Any]) -> None:
        with self._lock:
            self._declare.append(declare)
            if self._session is not None:
                declare(self._session)

    # -- operations -----------------------------------------------------------------------

    def put(self, key_expr: str, payload: bytes) -> None:
        """Put; while a lost meeting point is being replaced the payload reaches nobody anyway
        and is dropped."""
        with self._lock:
            if self._session is not None:
                self._session.put(key_expr, payload)

    def publisher(self, key_expr: str) -> Callable[[bytes], None]:
        def declare(session: Any) -> None:
            pub = session.declare_publisher(key_expr)
            self._declared.append(pub)
            self._publishers[key_expr] = pub

        self._add(declare)

        def put(payload: bytes) -> None:
            with self._lock:
                pub = self._publishers.get(key_expr)
                if pub is not None:
                    pub.put(payload)

        return put

    def queryable(self, key_expr: str, answer: Callable[[], Iterable[bytes]]) -> None:
        """Answer every query on ``key_expr`` with the payloads ``answer()`` returns."""
        self.answer(key_expr, lambda _key, _params: [Reply(key_expr, p) for p in answer()])

    def answer(self, key_expr: str,
               answer: Callable[[str, Mapping[str, str | None]], Iterable[Reply]]) -> None:
        """Answer every query on ``key_expr`` (which may hold wildcards) with the replies
        ``answer(query_key, parameters)`` returns; an ``error`` reply is sent as Zenoh's
        ``reply_err``. Runs on a Zenoh thread."""

        def handler(query: Any) -> None:
            try:
                params = dict(query.parameters)
                for reply in answer(str(query.key_expr), params):
                    if reply.error:
                        query.reply_err(reply.payload)
                    else:
                        query.reply(reply.key, reply.payload, attachment=reply.attachment)
            except Exception as err:  # a failing reply must not kill Zenoh's thread
                # nor leave the querier waiting for its timeout: it is told, in one line
                log.error("queryable %s failed: %s: %s", key_expr, type(err).__name__, err)
                log.debug("queryable %s failed", key_expr, exc_info=True)
                with contextlib.suppress(Exception):  # the query may be gone already
                    query.reply_err(f"failed: {type(err).__name__}".encode())
            finally:
                # the query ends here, even if a traceback kept in a log record still holds
                # it (the querier would otherwise wait for its timeout)
                with contextlib.suppress(Exception):
                    query.drop()

        self._add(lambda s: self._declared.append(s.declare_queryable(key_expr, handler)))

    def liveliness_token(self, key_expr: str) -> Callable[[], None]:
        """Declare a token (present while this session lives, declared again after a
        takeover); returns ``withdraw()``, which undeclares it for good (a solver's claim)."""
        current: list[Any] = []

        def declare(s: Any) -> None:
            token = s.liveliness().declare_token(key_expr)
            current[:] = [token]
            self._declared.append(token)

        self._add(declare)

        def withdraw() -> None:
            with self._lock:
                if declare in self._declare:
                    self._declare.remove(declare)
                tokens, current[:] = list(current), []
                for t in tokens:
                    if t in self._declared:
                        self._declared.remove(t)
            for t in tokens:
                try:
                    t.undeclare()
                except Exception:  # already gone with the session
                    log.debug("undeclaring %s failed", key_expr, exc_info=True)

        return withdraw

    def liveliness_get(self, selector: str, timeout_s: float = 2.0) -> list[str]:
        """The keys of the liveliness tokens alive now that match ``selector``."""
        session = self._session
        if session is None:
            return []
        out = []
        for reply in session.liveliness().get(selector, timeout=timeout_s):
            ok = reply.ok
            if ok is not None:
                out.append(str(ok.key_expr))
        return out

    def subscribe(self, key_expr: str, callback: Callable[[str, bytes], None]) -> None:
        """``callback(key, payload)`` runs on a Zenoh thread: hand data over thread-safely."""

        def handler(sample: Any) -> None:
            try:
                callback(str(sample.key_expr), sample.payload.to_bytes())
            except Exception:
                log.exception("subscriber callback for %s failed", key_expr)

        self._add(lambda s: self._declared.append(s.declare_subscriber(key_expr, handler)))

    def subscribe_liveliness(self, key_expr: str, callback: Callable[[str, bool], None]) -> None:
        """``callback(key, alive)`` when a liveliness token appears or disappears."""

        def handler(sample: Any) -> None:
            alive = str(sample.kind).upper().endswith("PUT")
            callback(str(sample.key_expr), alive)

        self._add(lambda s: self._declared.append(
            s.liveliness().declare_subscriber(key_expr, handler, history=True)))

    def get(self, selector: str, timeout_s: float = 2.0) -> list[tuple[str, bytes]]:
        """Query: every successful reply as (key, payload), in order and unconsolidated (a
        queryable may answer several times on one key, as ``q/timemarks`` does)."""
        session = self._session
        if session is None:
            return []
        out = []
        replies = session.get(
            selector, timeout=timeout_s,
            consolidation=zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE),
        )
        for reply in replies:
            ok = reply.ok
            if ok is not None:
                out.append((str(ok.key_expr), ok.payload.to_bytes()))
        return out

    def ask(self, key_expr: str, parameters: Mapping[str, str],
            timeout_s: float = 10.0) -> Callable[[], list[Reply]]:
        """Send a query now and return a function that waits for its replies (every reply,
        errors included, unconsolidated): several queries can be in flight at once."""
        session = self._session
        if session is None:
            return list
        handler = session.get(
            zenoh.Selector(key_expr, zenoh.Parameters(dict(parameters))), timeout=timeout_s,
            consolidation=zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE),
        )

        def replies() -> list[Reply]:
            out = []
            for reply in handler:  # ends when the query is finished (answered or timed out)
                ok = reply.ok
                if ok is not None:
                    att = ok.attachment
                    out.append(Reply(str(ok.key_expr), ok.payload.to_bytes(),
                                     att.to_bytes() if att is not None else None))
                elif reply.err is not None:
                    out.append(Reply(key_expr, reply.err.payload.to_bytes(), error=True))
            return out

        return replies

    def connections(self) -> int:
        """How many Zenoh peers and routers this session is connected to right now."""
        session = self._session
        if session is None:
            return 0
        info = session.info
        return len(list(info.peers_zid())) + len(list(info.routers_zid()))

    def close(self) -> None:
        self._closed.set()
        if self._watcher is not None:
            self._watcher.join(timeout=5)
        with self._lock:
            session, self._session = self._session, None
            declared = list(self._declared)
            self._declared.clear()
            self._publishers.clear()
        for d in reversed(declared):
            try:
                d.undeclare()
            except Exception:  # already gone with the session
                log.debug("undeclare failed", exc_info=True)
        if session is not None:
            try:
                session.close()
            except Exception:
                log.debug("session close failed", exc_info=True)


def open_bus(settings: ZenohSettings) -> Bus:
    """Open a session; raises :class:`~groundstation.errors.GroundstationError` on failure."""
    from groundstation.errors import GroundstationError

    try:
        return Bus(settings)
    except Exception as err:  # zenoh raises its own ZError
        raise GroundstationError(f"cannot open Zenoh session ({settings.mode}, listen "
                                 f"{list(settings.listen)}, connect {list(settings.connect)}): "
                                 f"{error_text(err)}") from err
