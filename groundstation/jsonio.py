"""The one JSON encoder and decoder of the project (msgspec), for the bus, MCAP and the dashboard.

Records are frozen dataclasses; msgspec writes them directly, without first building a dict
(``benchmarks/bench_json.py``, on real status, epoch and time-mark payloads: 9-17x faster than
the former hand-written conversion plus ``json.dumps``, about twice as fast as orjson). The
rules every JSON payload the project writes follows, in this one place:

- NaN and infinity become ``null`` (strict JSON: browsers and Foxglove reject ``NaN``);
- bytes are base64 (msgspec's encoding; the schemas in :mod:`groundstation.storage.schemas` say so);
- tuples are arrays, paths are strings, numpy scalars are numbers, dict keys become strings,
  any other object its ``str()``.
"""

from __future__ import annotations

from pathlib import PurePath
from typing import Any

import msgspec


def _hook(value: Any) -> Any:
    """Types msgspec does not write by itself."""
    if isinstance(value, PurePath):
        return str(value)
    item = getattr(value, "item", None)  # numpy scalars and 0-d arrays
    if callable(item):
        return item()
    # Anything else (an exception in an event's data ...) as its text: a record is never
    # lost because one value has an unexpected type.
    return str(value)


_ENCODER = msgspec.json.Encoder(enc_hook=_hook)
_EMPTY = b"{}"


def dumps(value: Any, *, indent: int = 0) -> bytes:
    """``value`` (records, dicts, lists, scalars) as UTF-8 JSON; ``indent`` > 0 pretty-prints."""
    out = _ENCODER.encode(value)
    return msgspec.json.format(out, indent=indent) if indent else out


def dumps_with(head: dict[str, Any], record: Any) -> bytes:
    """One JSON object: the ``head`` fields, then the fields of ``record`` (a dataclass or dict).

    The record is written as it is and joined to the head, so no dict copy of it is made. On a
    name in both, the record's value comes last and wins, as with ``{**head, **record}``.
    """
    first = _ENCODER.encode(head)
    body = _ENCODER.encode(record)
    if not body.startswith(b"{"):
        return _ENCODER.encode({**head, "value": record})
    if body == _EMPTY:
        return first
    if first == _EMPTY:
        return body
    return first[:-1] + b"," + body[1:]


_TYPE_HEADS: dict[type, bytes] = {}
"""Per record type: ``{"type":"<name>",`` (the encoded head, open for the record's fields)."""


def _type_head(record: Any) -> bytes:
    head = _TYPE_HEADS.get(type(record))
    if head is None:
        head = _TYPE_HEADS[type(record)] = (
            _ENCODER.encode({"type": type(record).__name__})[:-1] + b",")
    return head


def dumps_typed(record: Any) -> bytes:
    """``dumps_with({"type": type(record).__name__}, record)``, the same bytes, faster: the head
    is encoded once per type and the record's fields joined to it."""
    head = _type_head(record)
    body = _ENCODER.encode(record)
    if len(body) > 2 and body[0] == 0x7B:  # a non-empty object (else dumps_with's cases)
        return head + body[1:]
    return dumps_with({"type": type(record).__name__}, record)


def append_typed(record: Any, buffer: bytearray) -> None:
    """Append :func:`dumps_typed` of ``record`` to ``buffer``, encoded in place (what the
    recorder writes for every record, straight into the MCAP chunk in progress)."""
    at = len(buffer)
    head = _TYPE_HEADS.get(type(record))
    buffer += head if head is not None else _type_head(record)
    brace = len(buffer) - 1  # the record's "{" is written over the head's ","
    try:
        _ENCODER.encode_into(record, buffer, brace)
    except BaseException:
        del buffer[at:]
        raise
    if buffer[brace] == 0x7B and len(buffer) - brace > 2:  # a non-empty object
        buffer[brace] = 0x2C
    else:
        del buffer[at:]
        buffer += dumps_with({"type": type(record).__name__}, record)


def plain(value: Any) -> Any:
    """``value`` as plain Python JSON types (what :func:`loads` of :func:`dumps` gives)."""
    return loads(dumps(value))


def loads(data: bytes | str) -> Any:
    """Parse JSON.

    Raises:
        ValueError: not valid JSON (msgspec's ``DecodeError`` is one).
    """
    return msgspec.json.decode(data)
