"""When a recording starts its next file: size, duration, and the MCAP chunk-index bound."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class RotationPolicy:
    """When to start a new MCAP + sidecar pair (0 disables a limit).

    Attributes:
        size_bytes: beyond this MCAP size.
        duration_ns: after this long in one file.
        chunk_size_bytes: the MCAP chunk size target (to estimate the chunks in progress).
        max_chunks_per_file: after about this many MCAP chunks. The MCAP writer keeps an index
            entry per chunk in memory until the file is finished, and a chunk is closed at every
            flush: 7200 an hour at a 0.5 s flush interval, 4.7 MB an hour as the library's
            objects, about 1.1 MB packed
            (:class:`~groundstation.storage.mcapio.PackedChunkIndexes`). Without a bound a
            daemon running for days would grow for ever; 43 200 chunks is 6 hours at 0.5 s
            (about 6.5 MB of index at most), longer than a survey session.
    """

    size_bytes: int = 0
    duration_ns: int = 0
    chunk_size_bytes: int = 64 * 1024
    max_chunks_per_file: int = 43_200

    def due(self, *, size_bytes: int, data_bytes: int, closed_chunks: int, started_ns: int,
            now_ns: int) -> bool:
        """Whether the current file (``size_bytes`` on disk, ``data_bytes`` in the chunk in
        progress, ``closed_chunks`` closed by flushes, started at ``started_ns``) is done.

        ``started_ns`` and ``now_ns`` must come from a clock that does not step back: the
        session recorder moves ``started_ns`` back with a step of its wall clock
        (:meth:`~groundstation.storage.session.SessionRecorder._now`), so a step of an hour
        does not keep a file open an hour longer."""
        if self.size_bytes and size_bytes >= self.size_bytes:
            return True
        chunks = closed_chunks + data_bytes // self.chunk_size_bytes
        if self.max_chunks_per_file and chunks >= self.max_chunks_per_file:
            return True
        return bool(self.duration_ns and now_ns - started_ns >= self.duration_ns)

    def limits(self, *, size_bytes: int, closed_chunks: int, started_ns: int
               ) -> tuple[bool, int, int]:
        """:meth:`due` solved for what changes message by message, so a writer can check it
        with two comparisons: ``(due_now, data_limit, time_limit)``. With the same file (size,
        closed chunks, start), ``due(..., data_bytes=d, now_ns=t)`` is true exactly when
        ``due_now or d >= data_limit or t >= time_limit``."""
        due_now = bool(self.size_bytes and size_bytes >= self.size_bytes)
        data_limit = time_limit = NEVER
        if self.max_chunks_per_file:
            # closed + d // chunk >= max  <=>  d >= (max - closed) * chunk  (d >= 0)
            data_limit = max(0, self.max_chunks_per_file - closed_chunks) * self.chunk_size_bytes
        if self.duration_ns:
            time_limit = started_ns + self.duration_ns
        return due_now, data_limit, time_limit


NEVER = 1 << 126
"""A limit no byte count or UNIX ns time reaches."""
