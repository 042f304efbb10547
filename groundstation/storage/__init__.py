"""Recordings on disk: MCAP writing and tolerant reading (``mcapio``), the recording session
(``session``, with ``naming``, ``rotation``, ``topics``, ``publish_time``, ``location``,
``backlog``) and the JSON schemas (``schemas``)."""

from groundstation.storage.mcapio import (
    McapMessage,
    ReadReport,
    SummaryInfo,
    iter_messages,
    iter_raw_chunks,
    read_metadata,
    read_summary,
)

__all__ = [
    "McapMessage",
    "ReadReport",
    "SummaryInfo",
    "iter_messages",
    "iter_raw_chunks",
    "read_metadata",
    "read_summary",
]
