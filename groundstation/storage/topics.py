"""The MCAP topic registry: which channel each record type is recorded on, and its JSON body.

Raw chunks go to ``/ubx/raw`` byte for byte; each record type below goes to its JSON channel
with a schema derived from the dataclass. Types not listed are not recorded as JSON (frames and
undecodable frames are already in ``/ubx/raw``). The table is fixed here, in storage, so that
what a recording holds does not depend on which modules happened to be imported.
"""

from __future__ import annotations

from typing import Any

from groundstation.records import (
    Ephemeris,
    Event,
    NavSolution,
    PipelineStatus,
    RawChunk,
    RawEpoch,
    Status,
    Subframe,
    SvInfo,
    TimeMark,
)
from groundstation.storage.mcapio import RAW_TOPIC, ChannelSpec, json_channel
from groundstation.storage.schemas import dataclass_schema, union_schema

RAW_CHANNEL = ChannelSpec(RAW_TOPIC, "ubx")

_NAV_DATA = json_channel("/gnss/ephemeris", union_schema("NavData", (Subframe, Ephemeris)))

ROUTES: dict[type, ChannelSpec] = {
    RawEpoch: json_channel("/gnss/epoch", dataclass_schema(RawEpoch)),
    TimeMark: json_channel("/gnss/timemark", dataclass_schema(TimeMark)),
    Subframe: _NAV_DATA,
    Ephemeris: _NAV_DATA,
    NavSolution: json_channel("/gnss/nav", dataclass_schema(NavSolution)),
    SvInfo: json_channel("/gnss/svinfo", dataclass_schema(SvInfo)),
    Event: json_channel("/groundstation/event", dataclass_schema(Event)),
    Status: json_channel("/groundstation/status", dataclass_schema(Status)),
    PipelineStatus: json_channel("/groundstation/pipeline", dataclass_schema(PipelineStatus)),
}
"""Record type -> the JSON channel it is recorded on."""


def register_record_topic(cls: type, topic: str, schema: dict[str, Any] | None = None) -> None:
    """Record instances of ``cls`` (a dataclass) on ``topic`` as well (an extension's own
    record); the schema is derived from the dataclass unless given."""
    ROUTES[cls] = json_channel(topic, schema if schema is not None else dataclass_schema(cls))


def recorded_types() -> frozenset[type]:
    """Every item type a recording takes: raw chunks and the routed records."""
    return frozenset((RawChunk, *ROUTES))
