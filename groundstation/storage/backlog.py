"""What a recording holds in memory while writing fails (a full disk): bounded, raw bytes first.

Decoded records can be derived again from the raw bytes, so they go first: when the bound is
reached, the held records are dropped and further records are not kept; raw chunks are kept
until they alone fill the bound, then new chunks are dropped (the hole is at the end of what is
held, the earlier bytes stay contiguous). Drops are counted and reported by ``recorder.dropped``
events with the counts and the host-time span of the lost raw bytes (the first at once, then at
most every 10 s). The state machine that uses it is :class:`~groundstation.storage.session.
SessionRecorder` (module docstring there).
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from groundstation.records import Event
from groundstation.storage.mcapio import ChannelSpec
from groundstation.storage.topics import RAW_CHANNEL

log = logging.getLogger("groundstation.recorder")

Msg = tuple[ChannelSpec, bytes, int, int]
"""A message on its way to the MCAP: channel, data, log time, publish time."""

DROP_EVENT_INTERVAL_NS = 10_000_000_000
HELD_OVERHEAD_BYTES = 150
"""Memory a held message costs besides its data (tuple, bytes header, times, deque slot), so
that the bound limits the memory actually used."""


def cost(msg: Msg) -> int:
    """The memory ``msg`` takes while held."""
    return len(msg[1]) + HELD_OVERHEAD_BYTES


def size_text(n: float) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e6 else f"{n / 1e3:.0f} kB"


class Backlog:
    """Messages waiting for the disk, in order, within ``max_bytes``.

    Args:
        max_bytes: the bound on the memory held.
        clock: UNIX ns clock (for the drop events).
        notices: where ``recorder.dropped`` events are appended.
    """

    def __init__(self, max_bytes: int, clock: Callable[[], int], notices: list[Event]) -> None:
        self.max_bytes = max_bytes
        self._clock = clock
        self._notices = notices
        self.items: deque[Msg] = deque()
        self.bytes = 0
        self.records_off = False
        self.dropped_chunks = 0
        self.dropped_bytes = 0
        self.dropped_records = 0
        self._drop_span: tuple[int, int] | None = None
        self._last_drop_event_ns: int | None = None

    def __bool__(self) -> bool:
        return bool(self.items)

    def push_front(self, msgs: Iterable[Msg]) -> None:
        """Put ``msgs`` (in order) before everything held (the pending messages of an abandoned
        file go back first)."""
        for msg in reversed(list(msgs)):
            self.items.appendleft(msg)
            self.bytes += cost(msg)

    def pop(self) -> Msg:
        msg = self.items.popleft()
        self.bytes -= cost(msg)
        return msg

    def hold(self, msg: Msg) -> None:
        """Keep ``msg`` if the bound allows (records give way to raw bytes)."""
        size = cost(msg)
        raw = msg[0] is RAW_CHANNEL
        if not raw and (self.records_off or self.bytes + size > self.max_bytes):
            self.records_off = True
            self.dropped_records += 1
            self.report_drops()
            return
        if raw and self.bytes + size > self.max_bytes:
            if not self.records_off:  # records can be derived again from the raw bytes
                self.records_off = True
                kept: deque[Msg] = deque()
                for m in self.items:
                    if m[0] is RAW_CHANNEL:
                        kept.append(m)
                    else:
                        self.dropped_records += 1
                        self.bytes -= cost(m)
                self.items = kept
            if self.bytes + size > self.max_bytes:
                self.dropped_chunks += 1
                self.dropped_bytes += len(msg[1])
                t = msg[2]
                span = self._drop_span
                self._drop_span = (t, t) if span is None else (min(span[0], t), max(span[1], t))
                self.report_drops()
                return
        self.items.append(msg)
        self.bytes += size

    def drop_counts(self) -> dict[str, Any]:
        span = self._drop_span
        return {
            "dropped_raw_chunks": self.dropped_chunks,
            "dropped_raw_bytes": self.dropped_bytes,
            "dropped_records": self.dropped_records,
            "dropped_raw_first_ns": span[0] if span else None,
            "dropped_raw_last_ns": span[1] if span else None,
        }

    @property
    def dropped_any(self) -> bool:
        return bool(self.dropped_chunks or self.dropped_records)

    def report_drops(self, *, force: bool = False) -> None:
        now = self._clock()
        last = self._last_drop_event_ns
        if not force and last is not None and now - last < DROP_EVENT_INTERVAL_NS:
            return
        self._last_drop_event_ns = now
        msg = (f"recording backlog full ({size_text(self.max_bytes)} held): dropped "
               f"{self.dropped_bytes} raw bytes in {self.dropped_chunks} chunks and "
               f"{self.dropped_records} decoded records so far")
        log.error("%s", msg)
        self._notices.append(Event("recorder.dropped", now, msg, "error", self.drop_counts()))
