"""Recordings on disk: MCAP writing and tolerant reading (``mcapio``), the recording session
(``session``, with ``naming``, ``rotation``, ``topics``, ``publish_time``, ``location``,
``backlog``) and the JSON schemas (``schemas``).

The names below come from ``mcapio``, imported on first use: importing any
``groundstation.storage`` module must not load the ``mcap`` library (0.05-0.1 s), which
``rinex`` and ``inspect`` of a ``.ubx`` never need.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("groundstation.storage.mcapio"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
