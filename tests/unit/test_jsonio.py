"""The one JSON encoder: strict JSON for every record, head fields joined without a copy."""

from __future__ import annotations

import ast
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from groundstation import jsonio
from groundstation.bus import decode, encode
from groundstation.records import STATUS_SCHEMA_VERSION, Event, RawEpoch, SatObs, TimeMark

ROOT = Path(__file__).resolve().parents[2] / "groundstation"


@dataclass(frozen=True, slots=True)
class Empty:
    pass


def test_records_become_strict_json() -> None:
    sat = SatObs(0, 5, math.nan, math.inf, -100.25, 44, 7, 2, True, False, locktime_ms=3)
    epoch = RawEpoch(2300, 123_400_000_000, (sat,), "RXM-RAW", 99)
    out = jsonio.dumps(epoch)
    doc = json.loads(out)  # the stdlib parser: no NaN, no Infinity
    assert doc["sats"][0]["carrier_phase_cyc"] is None and doc["sats"][0]["pseudorange_m"] is None
    assert doc["sats"][0]["doppler_hz"] == -100.25 and doc["tow_ns"] == 123_400_000_000
    assert b"NaN" not in out and b"Infinity" not in out
    ev = Event("x.y", 1, "m", "info", {"path": Path("/a/b"), "n": np.float64(2.5),
                                        "k": np.int32(3), "t": (1, 2), "blob": b"\x01\x02"})
    data = jsonio.plain(ev)["data"]
    assert data == {"path": "/a/b", "n": 2.5, "k": 3, "t": [1, 2], "blob": "AQI="}
    assert jsonio.plain({4: None}) == {"4": None}


def test_head_fields_lead_and_the_record_wins() -> None:
    mark = TimeMark(0, 1, None, 5, False, True, 1, True, 20, 7)
    doc = jsonio.loads(jsonio.dumps_with({"schema": 9, "type": "timemark", "count": -1}, mark))
    assert list(doc)[:2] == ["schema", "type"]
    assert doc["count"] == mark.count  # as {**head, **record}
    assert jsonio.loads(jsonio.dumps_with({"type": "e"}, Empty())) == {"type": "e"}
    assert jsonio.loads(jsonio.dumps_with({}, {"a": 1})) == {"a": 1}
    assert jsonio.loads(jsonio.dumps_with({"type": "v"}, [1, 2])) == {"type": "v", "value": [1, 2]}


def test_typed_records_are_dumps_with_a_type_head() -> None:
    """``dumps_typed`` and ``append_typed`` (what the recorder writes) give the bytes of
    ``dumps_with({"type": <class name>}, record)`` for every kind of value, and an encoding
    error leaves the buffer as it was."""
    sat = SatObs(0, 5, math.nan, math.inf, -100.25, 44, 7, 2, True, False, locktime_ms=3)
    values = [RawEpoch(2300, 123_400_000_000, (sat,), "RXM-RAW", 99),
              TimeMark(0, 1, None, 5, False, True, 1, True, 20, 7), Empty(),
              Event("x.y", 1, "é", "info", {"blob": b"\x01"}), [1, 2], {"a": 1}, {}, 3.5]
    for value in values:
        expected = jsonio.dumps_with({"type": type(value).__name__}, value)
        assert jsonio.dumps_typed(value) == expected
        buf = bytearray(b"head")
        jsonio.append_typed(value, buf)
        assert buf == b"head" + expected
    loop: list[object] = []
    loop.append(loop)
    buf = bytearray(b"head")
    with pytest.raises(RecursionError):
        jsonio.append_typed({"v": loop}, buf)
    assert buf == b"head"


def test_bus_payload_round_trip() -> None:
    mark = TimeMark(0, 1, None, 5, False, True, 1, True, 20, 7)
    doc = decode(encode("timemark", mark, station="st", index=3))
    assert doc == {"schema": STATUS_SCHEMA_VERSION, "type": "timemark", "station": "st",
                   "index": 3, **jsonio.plain(mark)}


def test_one_encoder_in_the_package() -> None:
    """No module but jsonio writes JSON with the stdlib (``json.dump``/``json.dumps``)."""
    offenders = []
    for path in ROOT.rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and node.attr in ("dump", "dumps")
                    and isinstance(node.value, ast.Name) and node.value.id == "json"):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert offenders == []
