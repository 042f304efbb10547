"""Fanout: routes each pipeline item, by its type, to the sinks that accept it, each through its
own bounded inbox.

Every item is a record (:data:`~groundstation.records.Item`). A sink declares the item types it
accepts (:attr:`Sink.accepts`) and gets only those; what a sink publishes itself goes to the
other sinks, never back to it (the ``publish`` a sink is handed carries its name as the item's
origin). Routes are worked out once per (type, origin) and cached.

Publishing never waits: :meth:`Fanout.publish` is synchronous, so the source is never blocked by
a slow sink. What happens when an inbox is full is the sink's stated policy:

- ``Overflow.DROP_OLDEST`` (monitor, publisher): the oldest item is dropped and counted; the
  first drop, and then at most one every ``drop_event_interval_ns``, raises a ``fanout.dropped``
  event.
- ``Overflow.NEVER_DROP`` (recorder): the item is kept anyway (the bound is a high-water mark);
  crossing it is counted and raises ``<sink>.behind``; draining below half of it raises
  ``<sink>.caught_up``.

The events an inbox raises come from the fanout itself (no sink's origin), so they reach every
sink that accepts events, the one concerned included.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import time
from collections import deque
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from groundstation import events as kinds
from groundstation.records import Event, Item, RawChunk

log = logging.getLogger("groundstation.fanout")


__all__ = [
    "Fanout", "Inbox", "InboxClosed", "InboxStats", "Item", "Overflow", "Publish", "RawChunk",
    "Sink", "SinkSpec",
]

LINGER_LATE = 2.0
"""A lingering sink whose linger is over waits for the next item up to this multiple of its
linger in all (see :meth:`Inbox.get_all`)."""

Publish = Callable[[Item], None]
"""How a sink hands what it produces (events, status) to the other sinks."""


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
        accepts: the item types this inbox takes (subclasses included).
        clock: UNIX ns clock.
    """

    def __init__(
        self,
        name: str,
        maxsize: int,
        overflow: Overflow,
        on_event: Callable[[Event], None],
        *,
        accepts: Iterable[type] = (),
        clock: Callable[[], int] = time.time_ns,
        drop_event_interval_ns: int = 10_000_000_000,
    ) -> None:
        self.name = name
        self.maxsize = maxsize
        self.overflow = overflow
        self.accepts: frozenset[type] = frozenset(accepts)
        self._items: deque[Item] = deque()
        self._ready = asyncio.Event()
        self._batch = max(1, maxsize // 4)  # a lingering sink stops waiting at this many
        self._batch_ready = asyncio.Event()
        self._due = 0.0  # while lingering: the monotonic time the linger is over (0: not)
        self._flowing = False  # get_all(linger_s) took items last time
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

    def takes(self, cls: type) -> bool:
        """Whether items of type ``cls`` are routed here."""
        return any(issubclass(cls, t) for t in self.accepts)

    def put(self, item: Item) -> None:
        """Enqueue without waiting, applying the overflow policy."""
        if self._closed:
            return
        items = self._items
        if len(items) < self.maxsize:  # the common case, kept short: it runs per item per sink
            items.append(item)
            n = len(items)
            if n > self.high_water:
                self.high_water = n
            if n >= self._batch or (self._due and time.monotonic() >= self._due):
                self._batch_ready.set()  # the sink runs in this pass of the loop, not on a timer
            self._ready.set()
            return
        event: Event | None = None
        if self.overflow is Overflow.DROP_OLDEST:
            items.popleft()
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
        items.append(item)
        self.high_water = max(self.high_water, len(items))
        self._ready.set()
        self._batch_ready.set()
        if event is not None:  # after the item: the event goes through the fanout (and here)
            self._on_event(event)

    def close(self) -> None:
        """No more items; the sink drains what is queued, then :meth:`get` raises."""
        self._closed = True
        self._ready.set()
        self._batch_ready.set()

    async def _wait(self, timeout_s: float | None) -> bool:
        """Wait until an item is queued; False if ``timeout_s`` passed first.

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
                    return False
        return True

    def _taken(self) -> None:
        if self.behind and len(self._items) <= self.maxsize // 2:
            self.behind = False
            log.info("sink %s caught up", self.name)
            self._on_event(Event(
                kinds.caught_up(self.name), self._clock(), f"{self.name} caught up", "info",
                {"sink": self.name, "over_limit": self.over_limit},
            ))

    async def get(self, timeout_s: float | None = None) -> Item | None:
        """The next item; ``None`` if ``timeout_s`` passed first.

        Raises:
            InboxClosed: when closed and drained.
        """
        if not await self._wait(timeout_s):
            return None
        item = self._items.popleft()
        self.delivered += 1
        self._taken()
        return item

    async def get_all(self, timeout_s: float | None = None, *, linger_s: float = 0.0
                      ) -> list[Item]:
        """Everything queued, oldest first, once there is something; ``[]`` if ``timeout_s``
        passed first. One wake-up per burst instead of one per item: at 115 200 baud a sink
        otherwise wakes for every 64-byte chunk and every record.

        Args:
            timeout_s: the longest wait for a first item.
            linger_s: once there is an item, wait this long for more, then until the next
                item arrives (at most ``LINGER_LATE`` x ``linger_s`` in all), so that the sink
                wakes together with its producer; a quarter of the bound, or the inbox
                closing, ends the wait early, so a flood is not slowed.
                While items keep coming, the next call lingers straight away instead of
                first waiting for one item: one wake-up per ``linger_s`` in steady flow. A
                sink that can take its items a little late (the recorder, the monitor) wakes
                a few dozen times a second instead of once per chunk.

        Raises:
            InboxClosed: when closed and drained.
        """
        if linger_s > 0 and self._flowing and not self._closed:
            await self._linger(linger_s)  # the last call took items: more are on their way
            if not self._items:
                self._flowing = False
                return []  # the flow stopped: the sink gets its tick, then waits afresh
        else:
            if not await self._wait(timeout_s):
                return []
            if linger_s > 0 and not self._closed:
                await self._linger(linger_s)
        self._flowing = linger_s > 0
        items = list(self._items)
        self._items.clear()
        self.delivered += len(items)
        self._taken()
        return items

    async def _linger(self, linger_s: float) -> None:
        """Wait until the first item put once ``linger_s`` has passed (or a quarter of the
        bound, or the close); at most ``LINGER_LATE`` x ``linger_s`` when nothing comes.

        Ending on a put rather than on a timer of its own saves the wake-ups: the sink runs
        right after its producer's pass through the loop instead of waking the process once
        more between two reads (at 115 200 baud: 94 instead of 136 wake-ups a second, and a
        wake-up of an idle process costs more CPU than the work a burst brings)."""
        if len(self._items) >= self._batch:
            return
        self._batch_ready.clear()
        self._due = time.monotonic() + linger_s  # asyncio's loop clock is time.monotonic
        try:
            async with asyncio.timeout(linger_s * LINGER_LATE):
                await self._batch_ready.wait()
        except TimeoutError:
            pass  # the flow paused: take what came meanwhile
        finally:
            self._due = 0.0


@runtime_checkable
class Sink(Protocol):
    """A consumer of pipeline items (recorder, monitor, Zenoh publisher ...).

    ``accepts`` names the item types the sink takes (read once, when the pipeline starts);
    nothing else is routed to it. ``consume`` runs as its own task: it takes items with ``await
    inbox.get_all(...)`` (or ``get``) until :class:`InboxClosed`, then finishes its work (close
    files, flush) and returns. Items a sink produces itself (a monitor's status and events) go
    to the other sinks through ``publish``, which the pipeline hands to it; they never come back
    to it.
    """

    @property
    def name(self) -> str: ...

    @property
    def accepts(self) -> frozenset[type]: ...

    async def consume(self, inbox: Inbox, publish: Publish) -> None: ...


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
    """Routes each published item to the inboxes that accept its type, in registration order,
    leaving out the inbox of the sink that published it."""

    def __init__(self, *, clock: Callable[[], int] = time.time_ns) -> None:
        self._clock = clock
        self.inboxes: list[Inbox] = []
        self.published = 0
        self._routes: dict[tuple[type, str | None], tuple[Inbox, ...]] = {}

    def add_inbox(
        self, name: str, maxsize: int, overflow: Overflow, accepts: Iterable[type]
    ) -> Inbox:
        """A new inbox for the sink ``name``, taking the item types ``accepts``."""
        if any(i.name == name for i in self.inboxes):
            raise ValueError(f"an inbox named {name!r} exists already")
        inbox = Inbox(name, maxsize, overflow, self._from_fanout, accepts=accepts,
                      clock=self._clock)
        self.inboxes.append(inbox)
        self._routes.clear()
        return inbox

    def _from_fanout(self, event: Event) -> None:
        self.publish(event)

    def _route(self, cls: type, origin: str | None) -> tuple[Inbox, ...]:
        route = self._routes[(cls, origin)] = tuple(
            i for i in self.inboxes if i.name != origin and i.takes(cls)
        )
        return route

    def publish(self, item: Item, origin: str | None = None) -> None:
        """Hand ``item`` to every open inbox that accepts its type, except ``origin``'s; never
        waits."""
        self.published += 1
        key = (type(item), origin)
        route = self._routes.get(key)
        if route is None:
            route = self._route(key[0], origin)
        for inbox in route:
            inbox.put(item)

    def publisher(self, origin: str) -> Publish:
        """``publish`` for the sink named ``origin``: what it produces never comes back to it."""

        def publish(item: Item) -> None:
            self.publish(item, origin)

        return publish

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
