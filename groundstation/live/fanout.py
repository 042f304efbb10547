"""Fanout: hands every pipeline item to each registered sink through its own bounded inbox.

Publishing never waits: :meth:`Fanout.publish` is synchronous, so the source is never blocked by
a slow sink. What happens when an inbox is full is the sink's stated policy:

- ``Overflow.DROP_OLDEST`` (monitor, publisher): the oldest item is dropped and counted; the
  first drop, and then at most one every ``drop_event_interval_ns``, raises a ``fanout.dropped``
  event.
- ``Overflow.NEVER_DROP`` (recorder): the item is kept anyway (the bound is a high-water mark);
  crossing it is counted and raises ``<sink>.behind``; draining below half of it raises
  ``<sink>.caught_up``.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import time
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from groundstation import events as kinds
from groundstation.records import Event

log = logging.getLogger("groundstation.fanout")


@dataclass(frozen=True, slots=True)
class RawChunk:
    """Bytes exactly as the source delivered them, with the host receive time."""

    data: bytes
    t_host_ns: int


Item = Any
"""What flows through the fanout: :class:`RawChunk`, decoded records, :class:`Event`, status."""


class Overflow(enum.Enum):
    """What a full inbox does with one more item."""

    DROP_OLDEST = "drop_oldest"
    NEVER_DROP = "never_drop"


class InboxClosed(Exception):
    """The inbox is closed and empty: the sink should finish."""


class Inbox:
    """A sink's bounded queue with an overflow policy (see the module docstring).

    Args:
        name: the sink's name (for events and logs).
        maxsize: the bound.
        overflow: the policy beyond the bound.
        on_event: where this inbox reports drops and falling behind.
        clock: UNIX ns clock.
    """

    def __init__(
        self,
        name: str,
        maxsize: int,
        overflow: Overflow,
        on_event: Callable[[Event], None],
        *,
        clock: Callable[[], int] = time.time_ns,
        drop_event_interval_ns: int = 10_000_000_000,
    ) -> None:
        self.name = name
        self.maxsize = maxsize
        self.overflow = overflow
        self._items: deque[Item] = deque()
        self._ready = asyncio.Event()
        self._closed = False
        self._on_event = on_event
        self._clock = clock
        self._drop_interval_ns = drop_event_interval_ns
        self._last_drop_event_ns: int | None = None
        self.dropped = 0
        self.over_limit = 0
        self.high_water = 0
        self.behind = False
        self.delivered = 0

    def __len__(self) -> int:
        return len(self._items)

    def put(self, item: Item) -> None:
        """Enqueue without waiting, applying the overflow policy."""
        if self._closed:
            return
        event: Event | None = None
        if len(self._items) >= self.maxsize:
            if self.overflow is Overflow.DROP_OLDEST:
                self._items.popleft()
                self.dropped += 1
                now = self._clock()
                if (self._last_drop_event_ns is None
                        or now - self._last_drop_event_ns >= self._drop_interval_ns):
                    self._last_drop_event_ns = now
                    event = Event(
                        kinds.FANOUT_DROPPED, now,
                        f"sink {self.name} is slow: {self.dropped} item(s) dropped so far",
                        "warning", {"sink": self.name, "dropped": self.dropped},
                    )
            else:
                self.over_limit += 1
                if not self.behind:
                    self.behind = True
                    log.warning("sink %s fell behind (%d items queued)", self.name, len(self))
                    event = Event(
                        kinds.behind(self.name), self._clock(),
                        f"{self.name} is falling behind: {len(self)} items queued "
                        "(nothing is dropped)", "error",
                        {"sink": self.name, "queued": len(self), "limit": self.maxsize},
                    )
        self._items.append(item)
        self.high_water = max(self.high_water, len(self._items))
        self._ready.set()
        if event is not None:  # after the item: the event goes through the fanout (and here)
            self._on_event(event)

    def close(self) -> None:
        """No more items; the sink drains what is queued, then :meth:`get` raises."""
        self._closed = True
        self._ready.set()

    async def get(self, timeout_s: float | None = None) -> Item | None:
        """The next item; ``None`` if ``timeout_s`` passed first.

        Raises:
            InboxClosed: when closed and drained.
        """
        while not self._items:
            if self._closed:
                raise InboxClosed(self.name)
            self._ready.clear()
            if timeout_s is None:
                await self._ready.wait()
            else:
                try:
                    async with asyncio.timeout(timeout_s):
                        await self._ready.wait()
                except TimeoutError:
                    return None
        item = self._items.popleft()
        self.delivered += 1
        if self.behind and len(self._items) <= self.maxsize // 2:
            self.behind = False
            log.info("sink %s caught up", self.name)
            self._on_event(Event(
                kinds.caught_up(self.name), self._clock(), f"{self.name} caught up", "info",
                {"sink": self.name, "over_limit": self.over_limit},
            ))
        return item


@runtime_checkable
class Sink(Protocol):
    """A consumer of pipeline items (recorder, monitor, Zenoh publisher ...).

    ``consume`` runs as its own task: it takes items with ``await inbox.get(...)`` until
    :class:`InboxClosed`, then finishes its work (close files, flush) and returns. Items a
    sink produces itself (a monitor's status and events) go back through ``publish``, which
    the pipeline hands to it before ``consume`` starts.
    """

    @property
    def name(self) -> str: ...

    async def consume(self, inbox: Inbox, publish: Callable[[Item], None]) -> None: ...


@dataclass(frozen=True, slots=True)
class SinkSpec:
    """A sink with its queue bound and overflow policy."""

    sink: Sink
    maxsize: int
    overflow: Overflow


@dataclass(frozen=True, slots=True)
class InboxStats:
    name: str
    queued: int
    delivered: int
    dropped: int
    over_limit: int
    high_water: int


class Fanout:
    """Copies each published item into every sink's inbox, in registration order."""

    def __init__(self, *, clock: Callable[[], int] = time.time_ns) -> None:
        self._clock = clock
        self.inboxes: list[Inbox] = []
        self.published = 0

    def add_inbox(self, name: str, maxsize: int, overflow: Overflow) -> Inbox:
        inbox = Inbox(name, maxsize, overflow, self.publish, clock=self._clock)
        self.inboxes.append(inbox)
        return inbox

    def publish(self, item: Item) -> None:
        """Hand ``item`` to every sink whose inbox is open; never waits."""
        self.published += 1
        for inbox in self.inboxes:
            inbox.put(item)

    def close(self, names: Collection[str] | None = None) -> None:
        """No more items for the named sinks (all when ``None``): they drain and finish."""
        for inbox in self.inboxes:
            if names is None or inbox.name in names:
                inbox.close()

    @property
    def stats(self) -> tuple[InboxStats, ...]:
        return tuple(
            InboxStats(i.name, len(i), i.delivered, i.dropped, i.over_limit, i.high_water)
            for i in self.inboxes
        )
