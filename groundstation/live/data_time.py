"""The data's own clock: times for a stream that holds no reception times (a ``.ubx`` file).

A ``.ubx`` recording keeps the receiver's bytes but not when they arrived. A source of such a
stream yields its chunks stamped :data:`UNTIMED`, and the pipeline times them here from its own
frames (one framing pass): a chunk takes the UTC of the latest measurement epoch (RXM-RAW /
RXM-RAWX) framed so far, never going back. A receiver sends an epoch's messages right after its
measurement time, so this is close to when the bytes arrived live; the monitor's windows run on
it and ``--speed`` paces it (:class:`~groundstation.pacing.Pacer`). Only epochs whose time can
belong to the session count (:mod:`groundstation.rules.plausible`, with the same verdicts as the
decoder's: :attr:`DataClock.session` judges the same epochs in the same order, without host
times): a frame that passed its checksum by chance with a time a week ahead does not move the
clock a week ahead.

Chunks before the first epoch take that epoch's time (they are held, up to
:data:`DATA_TIME_WAIT_BYTES`); a stream with no epoch by then is timed from there on as a
115 200-baud link (or the file's configured rate) would have delivered it, from the moment
reading started.
"""

from __future__ import annotations

from groundstation.gpstime import gps_to_unix_ns
from groundstation.pacing import link_time_ns
from groundstation.records import Frame
from groundstation.rules.plausible import SessionClock
from groundstation.ubx.decode import epoch_time_gps_ns

UNTIMED = 0
"""The time a source gives a chunk it has no reception time for: the pipeline times it."""

DATA_TIME_WAIT_BYTES = 256 * 1024
"""How far into a stream without reception times its first epoch time is looked for; a stream
with none by then is timed as a link would have delivered it."""

Timed = tuple[bytes, list[Frame], int]
"""A chunk, the frames it completed (restamped with its time) and its time (UNIX ns)."""


class DataClock:
    """Times chunks of an :data:`UNTIMED` stream from the frames they complete.

    Args:
        start_ns: UNIX ns when reading started (the start of link times).
        link_bytes_per_s: the link rate for a stream without epochs.
    """

    def __init__(self, start_ns: int, link_bytes_per_s: float) -> None:
        self._start_ns = start_ns
        self._rate = link_bytes_per_s
        self.session = SessionClock(start_ns, host_times=False)
        """The plausibility rule's clock (the decoder of the same stream must have one alike:
        ``host_times`` False and this ``now_ns``)."""
        self.last_ns: int | None = None
        """UTC (UNIX ns) of the latest epoch so far (``None`` before the first one)."""
        self._held: list[tuple[bytes, list[Frame]]] = []
        self._held_bytes = 0
        self._by_link = False  # no epoch in the first DATA_TIME_WAIT_BYTES
        self._link_offset = 0

    def stamp(self, chunk: bytes, frames: list[Frame]) -> list[Timed]:
        """Time one chunk with the frames it completed; returns the chunks now timed, in
        order (none while chunks before the first epoch are held, several when it comes)."""
        if not self._by_link:
            last = self.last_ns
            for frame in frames:
                t_gps = epoch_time_gps_ns(frame)
                if t_gps is not None and self.session.epoch(t_gps, 0) is None:
                    t = gps_to_unix_ns(t_gps)
                    if last is None or t > last:
                        last = t
            self.last_ns = last
            if last is not None:
                held, self._held = self._held, []
                return [*(_at(c, f, last) for c, f in held), _at(chunk, frames, last)]
            self._held_bytes += len(chunk)
            self._held.append((chunk, frames))
            if self._held_bytes <= DATA_TIME_WAIT_BYTES:
                return []
            self._by_link = True
            return self.flush()
        return [self._by_link_time(chunk, frames)]

    def flush(self) -> list[Timed]:
        """The chunks still held (a stream that ended before its first epoch): link times."""
        held, self._held = self._held, []
        return [self._by_link_time(c, f) for c, f in held]

    def now_ns(self) -> int:
        """The time of what comes next without a chunk (frames recovered at the end)."""
        if self.last_ns is not None:
            return self.last_ns
        return link_time_ns(self._start_ns, self._link_offset, self._rate)

    def _by_link_time(self, chunk: bytes, frames: list[Frame]) -> Timed:
        t = link_time_ns(self._start_ns, self._link_offset, self._rate)
        self._link_offset += len(chunk)
        return _at(chunk, frames, t)


def _at(chunk: bytes, frames: list[Frame], t_ns: int) -> Timed:
    """The chunk and its frames with the time ``t_ns``.

    The frames were made by the pipeline's framer for this chunk and nobody holds them yet, so
    their time is set in place (a new frozen ``Frame`` per frame cost 3 % of a file's ingest).
    """
    for f in frames:
        object.__setattr__(f, "t_host_ns", t_ns)
    return chunk, frames, t_ns
