"""Recordings on disk: MCAP writing and tolerant reading, session files, JSON schemas."""

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
