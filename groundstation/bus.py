"""The Zenoh bus: the one module that imports zenoh. Sessions, keys, JSON payloads.

A session is opened from :class:`~groundstation.config.ZenohSettings` (the one Zenoh settings
type) and listens exactly where it says: an empty ``listen`` list opens no listener (Zenoh's own
default would be every interface, ``tcp/[::]:0``).

Key space (DESIGN.md): ``groundstation/<station>/{status,timemark,event,epoch,ubx,session,
q/timemarks,q/status,alive,solution}``. Payloads are UTF-8 JSON objects carrying ``schema``
(:data:`~groundstation.records.STATUS_SCHEMA_VERSION`) and ``type``; ``docs/zenoh.md`` lists
every key and field.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from groundstation import jsonio
from groundstation.config import ZenohSettings
from groundstation.records import STATUS_SCHEMA_VERSION

log = logging.getLogger("groundstation.zenoh")

KEY_ROOT = "groundstation"


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


def _config(settings: ZenohSettings) -> Any:
    conf = zenoh.Config()
    conf.insert_json5("mode", jsonio.dumps(settings.mode).decode())
    conf.insert_json5("scouting/multicast/enabled", "true" if settings.scouting else "false")
    # Always set, even empty: left out, Zenoh listens on tcp/[::]:0 (every interface).
    conf.insert_json5("listen/endpoints", jsonio.dumps(list(settings.listen)).decode())
    conf.insert_json5("connect/endpoints", jsonio.dumps(list(settings.connect)).decode())
    return conf


class Bus:
    """An open Zenoh session with the few operations groundstation uses."""

    def __init__(self, settings: ZenohSettings) -> None:
        self.settings = settings
        self._session: Any = zenoh.open(_config(settings))
        self._declared: list[Any] = []

    def put(self, key_expr: str, payload: bytes) -> None:
        self._session.put(key_expr, payload)

    def publisher(self, key_expr: str) -> Callable[[bytes], None]:
        pub = self._session.declare_publisher(key_expr)
        self._declared.append(pub)
        put: Callable[[bytes], None] = pub.put
        return put

    def queryable(self, key_expr: str, answer: Callable[[], Iterable[bytes]]) -> None:
        """Answer every query on ``key_expr`` with the payloads ``answer()`` returns."""

        def handler(query: Any) -> None:
            try:
                for payload in answer():
                    query.reply(key_expr, payload)
            except Exception:  # a failing reply must not kill Zenoh's thread
                log.exception("queryable %s failed", key_expr)

        self._declared.append(self._session.declare_queryable(key_expr, handler))

    def liveliness_token(self, key_expr: str) -> None:
        self._declared.append(self._session.liveliness().declare_token(key_expr))

    def subscribe(self, key_expr: str, callback: Callable[[str, bytes], None]) -> None:
        """``callback(key, payload)`` runs on a Zenoh thread: hand data over thread-safely."""

        def handler(sample: Any) -> None:
            try:
                callback(str(sample.key_expr), sample.payload.to_bytes())
            except Exception:
                log.exception("subscriber callback for %s failed", key_expr)

        self._declared.append(self._session.declare_subscriber(key_expr, handler))

    def subscribe_liveliness(self, key_expr: str, callback: Callable[[str, bool], None]) -> None:
        """``callback(key, alive)`` when a liveliness token appears or disappears."""

        def handler(sample: Any) -> None:
            alive = str(sample.kind).upper().endswith("PUT")
            callback(str(sample.key_expr), alive)

        sub = self._session.liveliness().declare_subscriber(key_expr, handler, history=True)
        self._declared.append(sub)

    def get(self, selector: str, timeout_s: float = 2.0) -> list[tuple[str, bytes]]:
        """Query: every successful reply as (key, payload), in order and unconsolidated (a
        queryable may answer several times on one key, as ``q/timemarks`` does)."""
        out = []
        replies = self._session.get(
            selector, timeout=timeout_s,
            consolidation=zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE),
        )
        for reply in replies:
            ok = reply.ok
            if ok is not None:
                out.append((str(ok.key_expr), ok.payload.to_bytes()))
        return out

    def connections(self) -> int:
        """How many Zenoh peers and routers this session is connected to right now."""
        info = self._session.info
        return len(list(info.peers_zid())) + len(list(info.routers_zid()))

    def close(self) -> None:
        for d in reversed(self._declared):
            try:
                d.undeclare()
            except Exception:  # already gone with the session
                log.debug("undeclare failed", exc_info=True)
        self._declared.clear()
        try:
            self._session.close()
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
                                 f"{err}") from err
