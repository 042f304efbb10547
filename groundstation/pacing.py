"""Pacing: when a timed chunk is due, at ``speed`` times the pace its times say.

The one rule behind every paced stream: a file or MCAP source in the live pipeline (``run
--file``, ``replay``), the simulator served on a pty or TCP port, and the demo's pty feeder.
The first chunk goes out at once; each later chunk is due ``(t - t_first) / speed`` after it,
on the monotonic clock, so a late chunk is caught up on rather than shifting every later one.
``speed=None`` means as fast as possible.

:class:`Pacer` is the sans-I/O rule; :func:`paced` drives it with blocking sleeps (threads),
the async sources ``await asyncio.sleep(pacer.delay_s(t))``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

from groundstation.gpstime import NS_PER_S

LINK_BYTES_PER_S = 11_520
"""A 115 200-baud 8N1 link: the pace of a file that holds no reception times."""

T = TypeVar("T")


class Pacer:
    """How long to wait before the chunk stamped ``t_ns`` is due.

    Args:
        speed: times real time (2.0: twice as fast); ``None``: never wait.
        clock: monotonic seconds (injected for tests).
    """

    def __init__(self, speed: float | None, clock: Callable[[], float] = time.monotonic) -> None:
        if speed is not None and speed <= 0:
            raise ValueError(f"speed must be positive, not {speed}")
        self.speed = speed
        self._clock = clock
        self._t0_ns: int | None = None
        self._wall0 = 0.0

    def delay_s(self, t_ns: int) -> float:
        """Seconds to wait before sending the chunk stamped ``t_ns`` (0 when it is due)."""
        if self.speed is None:
            return 0.0
        if self._t0_ns is None:
            self._t0_ns, self._wall0 = t_ns, self._clock()
            return 0.0
        due = self._wall0 + (t_ns - self._t0_ns) / NS_PER_S / self.speed
        return max(due - self._clock(), 0.0)


def link_time_ns(start_ns: int, bytes_before: int, bytes_per_s: float) -> int:
    """When a link of ``bytes_per_s`` would have delivered a chunk that follows
    ``bytes_before`` bytes, starting at ``start_ns``."""
    return start_ns + int(bytes_before * NS_PER_S // bytes_per_s)


def paced(
    chunks: Iterable[tuple[int, T]],
    speed: float | None,
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[tuple[int, T]]:
    """Yield ``(t_ns, chunk)`` no earlier than :class:`Pacer` allows (blocking sleeps)."""
    pacer = Pacer(speed, clock)
    for t_ns, chunk in chunks:
        wait = pacer.delay_s(t_ns)
        if wait > 0:
            sleep(wait)
        yield t_ns, chunk
