"""JSON Schemas of the recorded JSON channels: derived from the records, plus foxglove.LocationFix.

Schemas are generated from the dataclass type hints, so a field added to a record shows up in
the recording's schema without anyone editing a second copy.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from functools import cache
from typing import Any, Literal, Union, get_args, get_origin

JSON_SCHEMA_DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _type_schema(tp: Any) -> dict[str, Any]:
    origin = get_origin(tp)
    if tp is Any:
        return {}
    if tp is bool:
        return {"type": "boolean"}
    if tp is int:
        return {"type": "integer"}
    if tp is float:
        return {"type": "number"}
    if tp is str:
        return {"type": "string"}
    if tp in (bytes, bytearray):
        return {"type": "string", "contentEncoding": "base64"}
    if tp is type(None):
        return {"type": "null"}
    if origin is Literal:
        return {"enum": list(get_args(tp))}
    if origin in (Union, types.UnionType):
        return {"anyOf": [_type_schema(a) for a in get_args(tp)]}
    if origin in (tuple, list):
        args = get_args(tp)
        if origin is tuple and args and (len(args) != 2 or args[1] is not Ellipsis):
            return {
                "type": "array",
                "prefixItems": [_type_schema(a) for a in args],
                "minItems": len(args),
                "maxItems": len(args),
            }
        return {"type": "array", "items": _type_schema(args[0]) if args else {}}
    if origin is dict or tp is dict:
        return {"type": "object"}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return dataclass_schema(tp, top_level=False)
    return {}


@cache
def dataclass_schema(cls: type, *, top_level: bool = True) -> dict[str, Any]:
    """A JSON Schema for the JSON form of a record (as :mod:`groundstation.jsonio` writes it).

    Top-level schemas also allow the ``type`` field the recorder adds (the record class name).
    """
    hints = typing.get_type_hints(cls)
    props = {f.name: _type_schema(hints[f.name]) for f in dataclasses.fields(cls)}
    schema: dict[str, Any] = {"title": cls.__name__, "type": "object", "properties": props}
    if cls.__doc__:
        schema["description"] = " ".join(cls.__doc__.split("\n\n")[0].split())
    if top_level:
        props["type"] = {"const": cls.__name__}
        schema = {"$schema": JSON_SCHEMA_DRAFT, **schema}
    return schema


def union_schema(title: str, classes: tuple[type, ...]) -> dict[str, Any]:
    """One schema for a channel that carries several record types, told apart by ``type``."""
    return {
        "$schema": JSON_SCHEMA_DRAFT,
        "title": title,
        "oneOf": [
            {k: v for k, v in dataclass_schema(c).items() if k != "$schema"} for c in classes
        ],
    }


LOCATION_FIX_SCHEMA: dict[str, Any] = {
    "title": "foxglove.LocationFix",
    "description": "A navigation satellite fix for any Global Navigation Satellite System",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
            "description": "Timestamp of the message",
        },
        "frame_id": {
            "type": "string",
            "description": "Frame for the sensor. Latitude and longitude readings are at the "
            "origin of the frame.",
        },
        "latitude": {"type": "number", "description": "Latitude in degrees"},
        "longitude": {"type": "number", "description": "Longitude in degrees"},
        "altitude": {"type": "number", "description": "Altitude in meters"},
        "position_covariance": {
            "type": "array",
            "items": {"type": "number"},
            "minItems": 9,
            "maxItems": 9,
            "description": "Position covariance (m^2) defined relative to a tangential plane "
            "through the reported position. The components are East, North, and Up (ENU), in "
            "row-major order.",
        },
        "position_covariance_type": {
            "title": "foxglove.PositionCovarianceType",
            "description": "If `position_covariance` is available, `position_covariance_type` "
            "must be set to indicate the type of covariance.",
            "oneOf": [
                {"title": "UNKNOWN", "const": 0},
                {"title": "APPROXIMATED", "const": 1},
                {"title": "DIAGONAL_KNOWN", "const": 2},
                {"title": "KNOWN", "const": 3},
            ],
        },
    },
}
"""The ``foxglove.LocationFix`` JSON schema, so Foxglove/Lichtblick map panels work."""
