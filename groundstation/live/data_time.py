"""The data's own clock: times for a stream that holds no reception times (a ``.ubx`` file).

A ``.ubx`` recording keeps the receiver's bytes but not when they arrived. A source of such a
stream yields its chunks stamped :data:`UNTIMED`; the pipeline frames and decodes them (one
pass) and times them here from what they decoded to: a chunk takes the UTC of the latest
measurement epoch (RXM-RAW / RXM-RAWX) decoded so far, never going back. A receiver sends an
epoch's messages right after its measurement time, so this is close to when the bytes arrived
live; the monitor's windows run on it and ``--speed`` paces it
(:class:`~groundstation.pacing.Pacer`). The decoder has judged every epoch first
(:mod:`groundstation.rules.plausible`, without host times: the frames have none): a frame that
passed its checksum by chance with a time a week ahead is not decoded, so it does not move the
clock a week ahead.

Chunks before the first epoch take that epoch's time (they are held, up to
:data:`DATA_TIME_WAIT_BYTES`); a stream with no epoch by then is timed from there on as a
115 200-baud link (or the file's configured rate) would have delivered it, from the moment
reading started.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

from groundstation.gpstime import gps_to_unix_ns
from groundstation.pacing import link_time_ns
from groundstation.records import Item, RawEpoch

UNTIMED = 0
"""The time a source gives a chunk it has no reception time for: the pipeline times it."""

DATA_TIME_WAIT_BYTES = 256 * 1024
"""How far into a stream without reception times its first epoch time is looked for; a stream
with none by then is timed as a link would have delivered it."""

Timed = tuple[bytes, list[Item], int]
"""A chunk, what its frames decoded to (restamped with its time) and its time (UNIX ns)."""

T = TypeVar("T", bound=Sequence[Item])


class DataClock:
    """Times chunks of an :data:`UNTIMED` stream from the epochs they decoded to.

    Args:
        start_ns: UNIX ns when reading started (the start of link times).
        link_bytes_per_s: the link rate for a stream without epochs.
    """

    def __init__(self, start_ns: int, link_bytes_per_s: float) -> None:
        self._start_ns = start_ns
        self._rate = link_bytes_per_s
        self.last_ns: int | None = None
        """UTC (UNIX ns) of the latest epoch so far (``None`` before the first one)."""
        self._held: list[tuple[bytes, list[Item]]] = []
        self._held_bytes = 0
        self._by_link = False  # no epoch in the first DATA_TIME_WAIT_BYTES
        self._link_offset = 0

    def stamp(self, chunk: bytes, items: list[Item]) -> list[Timed]:
        """Time one chunk with what its frames decoded to; returns the chunks now timed, in
        order (none while chunks before the first epoch are held, several when it comes)."""
        if not self._by_link:
            last = self.last_ns
            for item in items:
                if type(item) is RawEpoch and item.gps_week > 0:  # decoded: plausible
                    t = gps_to_unix_ns(item.t_gps_ns)
                    if last is None or t > last:
                        last = t
            self.last_ns = last
            if last is not None:
                held, self._held = self._held, []
                return [*((c, restamped(i, last), last) for c, i in held),
                        (chunk, restamped(items, last), last)]
            self._held_bytes += len(chunk)
            self._held.append((chunk, items))
            if self._held_bytes <= DATA_TIME_WAIT_BYTES:
                return []
            self._by_link = True
            return self.flush()
        return [self._by_link_time(chunk, items)]

    def flush(self) -> list[Timed]:
        """The chunks still held (a stream that ended before its first epoch): link times."""
        held, self._held = self._held, []
        return [self._by_link_time(c, i) for c, i in held]

    def now_ns(self) -> int:
        """The time of what comes next without a chunk (frames recovered at the end)."""
        if self.last_ns is not None:
            return self.last_ns
        return link_time_ns(self._start_ns, self._link_offset, self._rate)

    def _by_link_time(self, chunk: bytes, items: list[Item]) -> Timed:
        t = link_time_ns(self._start_ns, self._link_offset, self._rate)
        self._link_offset += len(chunk)
        return chunk, restamped(items, t), t


def restamped(items: T, t_ns: int) -> T:
    """``items`` with their ``t_host_ns`` set to ``t_ns``, in place.

    The records were just made by the pipeline's decoder for this chunk and nobody holds them
    yet, so their time is set in place (a new frozen record per record cost 3 % of a file's
    ingest).
    """
    for item in items:
        if hasattr(item, "t_host_ns"):
            object.__setattr__(item, "t_host_ns", t_ns)
    return items
