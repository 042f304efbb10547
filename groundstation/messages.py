"""The bus payloads as the views and the solver accept them: parsed and range-checked (sans-I/O).

Every reader of the bus (the dashboard, ``watch``, the solver service) turns a payload into a
message here before using it. A payload that is not a JSON object, is too large or too deep,
or holds a value outside its range raises :class:`BadMessage`; the reader counts it and drops
it, and goes on (a crafted time mark of ``1e25`` ns must not stop a view).

The rules, by field name (``docs/zenoh.md`` keeps units in the names):

- ``type`` is one of :data:`KINDS` and must be the kind the key says (``.../status`` carries a
  ``status``); ``station``, ``session_id``, ``kind``, ``message``, ``state`` are strings;
- times: ``t_host_ns``, ``*_t_gps_ns``, ``start_ns``, ``end_ns`` are integers in
  ``[0, MAX_TIME_NS]``; other ``*_ns`` integers within ``±MAX_TIME_NS``;
- durations and other ``*_s`` are finite numbers within ``±MAX_SECONDS``, ``*interval_s`` in
  ``(0, 3600]``; ``*_fraction`` in ``[0, 1]``;
- counters (:data:`COUNTERS`) are integers in ``[0, 2**53]`` (exact in the page's JavaScript);
- a ``session``'s ``recordings[]`` (the finished files the daemon serves) each have a plain
  recording file ``name``, a byte ``size``, a ``sha256`` and ``chunk_bytes``
  (:func:`groundstation.storage.transfer.check_entry`);
- a ``session``'s ``files`` are strings and its ``first_epoch_t_gps_ns`` is not after its
  ``last_epoch_t_gps_ns`` (the span a solver pairs rover and base by);
- the tables a view reads (``link``, ``marks``, ``recording``, ``data`` ...) are objects and
  the lists (``sats``, ``alerts``, ``files`` ...) are lists; ``null`` is allowed for any value.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from groundstation import jsonio
from groundstation.storage import transfer

KINDS = frozenset({"status", "event", "timemark", "session", "solution", "epoch", "rtk"})
MAX_PAYLOAD_BYTES = 1 << 20
MAX_DEPTH = 8
MAX_NODES = 50_000
MAX_STRING = 4096
MAX_TIME_NS = 1 << 62
"""About year 2126 in GPS or UNIX ns; also a time the page's JavaScript can draw."""
MAX_SECONDS = 1e10
MAX_COUNT = 1 << 53
COUNTERS = frozenset({
    "index", "count", "epochs", "dropouts", "missing_epochs", "bytes", "bytes_in", "frames",
    "tracked", "ppk_ready", "received", "last_count", "part", "marks", "schema",
    "below_mask", "unidentified",
})
TABLES = {"link", "recording", "data", "current_dropout"}
LISTS = {"sats", "alerts", "files", "recent_dropouts", "notes", "recordings"}
STRINGS = {"type", "station", "session_id", "kind", "message"}
RTK_QUALITIES = frozenset({"fix", "float", "dgps", "single", "none"})


class BadMessage(ValueError):
    """A payload that breaks the rules (module docstring); the text says which."""


def parse(payload: bytes, expected: str | None = None) -> dict[str, Any]:
    """A payload as a checked message.

    Args:
        payload: the bytes from the bus.
        expected: the kind the key names (``status`` for ``.../status``), if any.

    Raises:
        BadMessage: what is wrong, in one line.
    """
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise BadMessage(f"payload of {len(payload)} bytes (at most {MAX_PAYLOAD_BYTES})")
    try:
        msg = jsonio.loads(payload)
    except ValueError as err:
        raise BadMessage(f"not JSON: {err}") from err
    return check(msg, expected)


def check(msg: Any, expected: str | None = None) -> dict[str, Any]:
    """``msg`` (decoded JSON) if it follows the rules.

    Raises:
        BadMessage: what is wrong, in one line.
    """
    if not isinstance(msg, dict):
        raise BadMessage("not a JSON object")
    kind = msg.get("type")
    if kind not in KINDS:
        raise BadMessage(f"unknown type {kind!r}")
    if expected is not None and kind != expected:
        raise BadMessage(f"a {kind!r} message where a {expected!r} was expected")
    if kind == "rtk":  # flat, its own fields (``sats`` is a count here, not the status's list)
        _check_rtk(msg)
        return msg
    nodes = [0]
    _walk(msg, "", 0, nodes)
    if kind == "event" and not isinstance(msg.get("kind"), str):
        raise BadMessage("event without kind")
    if kind == "session":
        files = msg.get("files") or []
        if not all(isinstance(f, str) for f in files):
            raise BadMessage("session files must be strings")
        for entry in msg.get("recordings") or []:  # the finished files served over the bus
            try:
                transfer.check_entry(entry)
            except transfer.BadRequest as err:
                raise BadMessage(str(err)) from err
        first, last = msg.get("first_epoch_t_gps_ns"), msg.get("last_epoch_t_gps_ns")
        if first is not None and last is not None and first > last:
            raise BadMessage(f"session span: first epoch {first} after last {last}")
    return msg


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_rtk(msg: dict[str, Any]) -> None:
    """A live position (``groundstation/<rover>/rtk``, docs/zenoh.md)."""
    for name in ("t_gps_ns", "rx_host_ns"):
        t = msg.get(name)
        if (name == "t_gps_ns" or t is not None) and (
                not isinstance(t, int) or isinstance(t, bool) or not 0 <= t <= MAX_TIME_NS):
            raise BadMessage(f"{name}: expected a time in ns, got {t!r}")
    if msg.get("quality") not in RTK_QUALITIES:
        raise BadMessage(f"quality: expected one of {sorted(RTK_QUALITIES)}, "
                         f"got {msg.get('quality')!r}")
    sats = msg.get("sats")
    if not isinstance(sats, int) or isinstance(sats, bool) or not 0 <= sats <= 255:
        raise BadMessage(f"sats: expected a count, got {sats!r}")
    if not _finite(msg.get("ratio")) or not abs(msg["ratio"]) <= MAX_SECONDS:
        raise BadMessage(f"ratio: expected a number, got {msg.get('ratio')!r}")
    age = msg.get("age_s")
    if age is not None and not (_finite(age) and abs(age) <= MAX_SECONDS):
        raise BadMessage(f"age_s: expected seconds, got {age!r}")
    for name in ("ecef_m", "sd_enu_m"):
        v = msg.get(name)
        if v is not None and not (isinstance(v, list) and len(v) == 3 and all(
                _finite(x) and abs(x) < 1e8 for x in v)):
            raise BadMessage(f"{name}: expected three numbers in metres, got {v!r}")
    for name in ("station", "why", "alert"):
        v = msg.get(name)
        if v is not None and not (isinstance(v, str) and len(v) <= MAX_STRING):
            raise BadMessage(f"{name}: expected a string")


def _walk(value: Any, name: str, depth: int, nodes: list[int]) -> None:
    nodes[0] += 1
    if nodes[0] > MAX_NODES:
        raise BadMessage(f"more than {MAX_NODES} values")
    if depth > MAX_DEPTH:
        raise BadMessage(f"nested deeper than {MAX_DEPTH}")
    if value is None:
        return
    if isinstance(value, Mapping):
        if name in LISTS or name in STRINGS:
            raise BadMessage(f"{name}: expected a {'list' if name in LISTS else 'string'}")
        for k, v in value.items():
            _walk(v, str(k), depth + 1, nodes)
        return
    if isinstance(value, list):
        if name in TABLES or name in STRINGS:
            raise BadMessage(f"{name}: expected {'an object' if name in TABLES else 'a string'}")
        for v in value:
            _walk(v, "", depth + 1, nodes)
        return
    if name in TABLES or name in LISTS:
        raise BadMessage(f"{name}: expected {'an object' if name in TABLES else 'a list'}, "
                         f"got {type(value).__name__}")
    if isinstance(value, str):
        if len(value) > MAX_STRING:
            raise BadMessage(f"{name or 'a string'}: longer than {MAX_STRING} characters")
        return
    if name in STRINGS:
        raise BadMessage(f"{name}: expected a string, got {value!r}")
    if isinstance(value, bool):
        return
    if isinstance(value, (int, float)):
        _number(name, value)
        return
    raise BadMessage(f"{name}: unexpected value {value!r}")  # pragma: no cover (JSON types)


def _number(name: str, value: float) -> None:
    if name.endswith("_ns") or name in COUNTERS:
        if not isinstance(value, int):
            raise BadMessage(f"{name}: expected an integer, got {value!r}")
        if name in COUNTERS:
            lo, hi = 0, MAX_COUNT
        elif name in ("t_host_ns", "start_ns", "end_ns") or name.endswith("t_gps_ns"):
            lo, hi = 0, MAX_TIME_NS
        else:
            lo, hi = -MAX_TIME_NS, MAX_TIME_NS
        if not lo <= value <= hi:
            raise BadMessage(f"{name}: {value} outside [{lo}, {hi}]")
        return
    if not math.isfinite(value):
        raise BadMessage(f"{name}: not a finite number")
    if name.endswith("_fraction") and not 0.0 <= value <= 1.0:
        raise BadMessage(f"{name}: {value} outside [0, 1]")
    if name.endswith("interval_s") and not 0.0 < value <= 3600.0:
        raise BadMessage(f"{name}: {value} outside (0, 3600] s")
    if name.endswith("_s") and abs(value) > MAX_SECONDS:
        raise BadMessage(f"{name}: {value} outside ±{MAX_SECONDS:g} s")
