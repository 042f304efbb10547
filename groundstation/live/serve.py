"""The daemon's finished recording files, served over Zenoh in chunks.

The publisher hands this server each MCAP file of the session once it is closed (a rotated
part when the next one opens, the last part when the recorder has finished); the server hashes
it (SHA-256, announced with ``name``, ``size`` and ``chunk_bytes`` in the ``session`` message's
``recordings[]``) and from then on answers chunk queries on
``groundstation/<station>/q/recording/<session_id>`` (the wire rules:
:mod:`groundstation.storage.transfer`). A file still being written is never served: it is not
known here until it is closed. Only the MCAP files are served: each holds every raw byte on
``/ubx/raw`` (the ``.ubx`` sidecar is the local crash copy of the same bytes).

A query is trusted for nothing: the file is looked up by exact name among this session's
served files (a name such as ``../x`` is refused by its form and could match nothing anyway),
the offset and length are integers in range (at most :data:`~groundstation.storage.transfer.
MAX_LENGTH` bytes a reply), and a file whose size changed since it was hashed is refused.
Refusals are answered with a one-line error, counted and logged sparingly.
"""

from __future__ import annotations

import bisect
import logging
import os
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from groundstation.bus import Bus, Reply, key
from groundstation.storage import transfer

log = logging.getLogger("groundstation.serve")

MAX_RANGES = 100_000
"""Separate byte ranges of one file noted as sent (:class:`SentRanges`)."""


@dataclass(frozen=True, slots=True)
class ServedFile:
    """A closed recording file and what the ``session`` message says about it."""

    name: str
    path: Path
    size: int
    sha256: str
    chunk_bytes: int

    def entry(self) -> dict[str, Any]:
        """Its ``recordings[]`` entry."""
        return {"name": self.name, "size": self.size, "sha256": self.sha256,
                "chunk_bytes": self.chunk_bytes}


class RecordingServer:
    """Serves one station's finished recording files of its current session.

    Args:
        station: the station name (``groundstation/<station>/q/recording/...``).
        chunk_bytes: the chunk size announced to fetchers.
    """

    def __init__(self, station: str, *, chunk_bytes: int = transfer.CHUNK_BYTES) -> None:
        self.station = station
        self.chunk_bytes = chunk_bytes
        self.session_id = ""
        self._files: dict[str, ServedFile] = {}
        self._sent: dict[str, SentRanges] = {}  # what of each file has been sent
        self._lock = threading.Lock()
        self.queries = 0
        self.refused = 0
        self.sent_bytes = 0

    @property
    def key_expr(self) -> str:
        """Every session of this station (the session id is checked per query)."""
        return key(self.station, "q/recording/*")

    def bind(self, bus: Bus) -> None:
        """Declare the queryable on ``bus`` (again after the publisher reopens its session)."""
        bus.answer(self.key_expr, self.answer)

    def add(self, path: Path, session_id: str) -> ServedFile | None:
        """Serve a closed file (hashed here: call it off the event loop). None when it is not
        an MCAP recording name or cannot be read (said in the log)."""
        name = path.name
        with self._lock:
            if name in self._files:
                return self._files[name]
        if not transfer.FILE_NAME.fullmatch(name) or not transfer.SESSION_ID.fullmatch(
                session_id):
            log.warning("not serving %s: not a recording name or session id", path)
            return None
        try:
            size = path.stat().st_size
            digest = transfer.sha256_file(path)
            if path.stat().st_size != size:
                raise OSError(f"{path} changed while it was hashed")
        except OSError as err:
            log.warning("not serving %s: %s", path, err)
            return None
        served = ServedFile(name, path.absolute(), size, digest, self.chunk_bytes)
        with self._lock:
            self.session_id = session_id
            self._files.setdefault(name, served)
            self._sent.setdefault(name, SentRanges())
        log.info("serving %s (%d bytes) on %s", name, size,
                 key(self.station, f"q/recording/{session_id}"))
        return served

    def entries(self) -> list[dict[str, Any]]:
        """The ``recordings[]`` of the ``session`` message, in the order served."""
        with self._lock:
            return [f.entry() for f in self._files.values()]

    def sent_in_full(self) -> bool:
        """Every served file has been sent whole at least once (to anyone)."""
        with self._lock:
            return bool(self._files) and all(
                self._sent[n].covers(f.size) for n, f in self._files.items())

    def _refuse(self, query_key: str, why: str) -> list[Reply]:
        with self._lock:
            self.refused += 1
            n = self.refused
        if n <= 10 or n % 100 == 0:  # a flood must not flood the log too
            log.warning("recording query refused (%d so far): %s", n, why)
        return [Reply(query_key, f"refused: {why}".encode(), error=True)]

    def answer(self, query_key: str, params: Mapping[str, str | None]) -> list[Reply]:
        """One chunk query (on a Zenoh thread): the bytes with their attachment, or a
        refusal."""
        with self._lock:
            self.queries += 1
            session_id = self.session_id
        asked = query_key.rsplit("/", 1)[-1]
        if not session_id or asked != session_id:
            return self._refuse(query_key, f"no finished file of session {asked[:80]!r} here")
        try:
            req = transfer.parse_request(params)
        except transfer.BadRequest as err:
            return self._refuse(query_key, str(err))
        with self._lock:
            served = self._files.get(req.file)
        if served is None:
            return self._refuse(query_key, f"{req.file!r} is not a finished file of "
                                           f"session {session_id}")
        if req.offset > served.size:
            return self._refuse(query_key, f"offset {req.offset} beyond the file's "
                                           f"{served.size} bytes")
        try:
            with served.path.open("rb") as f:
                if os.fstat(f.fileno()).st_size != served.size:
                    return self._refuse(query_key, f"{req.file} changed since it was announced")
                f.seek(req.offset)
                data = f.read(min(req.length, served.size - req.offset))
        except OSError as err:
            return self._refuse(query_key, f"{req.file}: cannot read it ({err.strerror})")
        with self._lock:
            self.sent_bytes += len(data)
            self._sent[req.file].add(req.offset, req.offset + len(data))
        return [Reply(query_key, data,
                      transfer.chunk_attachment(req.file, req.offset, data, served.size))]


class SentRanges:
    """The byte ranges of a file sent so far, merged: sorted, disjoint ``[start, end)``.

    Each :meth:`add` finds its place by binary search and touches only the ranges it merges
    with: ``n`` queries cost ``O(n log n)`` comparisons, plus the list insertion (a C memmove).
    Re-sorting every range per query, as before, cost ``O(n² log n)``: 20 000 one-byte queries
    at every other byte took 22 s of the daemon's CPU. At most :data:`MAX_RANGES` separate
    ranges are kept (a peer asking for every other byte must not grow the daemon without
    bound); a range beyond that is not noted (``untracked``), so the file is not taken as sent
    in full on its account: the daemon then serves until ``serve_after_s``, the safe side.
    """

    __slots__ = ("starts", "ends", "untracked")

    def __init__(self) -> None:
        self.starts: list[int] = []
        self.ends: list[int] = []  # sorted too: the ranges are disjoint
        self.untracked = 0

    def add(self, start: int, end: int) -> None:
        """Add ``[start, end)``, merged with every range it overlaps or touches."""
        starts, ends = self.starts, self.ends
        i = bisect.bisect_left(ends, start)  # the first range ending at or after start
        j = bisect.bisect_right(starts, end)  # past the last range starting at or before end
        if i < j:
            start, end = min(start, starts[i]), max(end, ends[j - 1])
        elif len(starts) >= MAX_RANGES:
            self.untracked += 1
            return
        starts[i:j] = [start]
        ends[i:j] = [end]

    def covers(self, size: int) -> bool:
        """Whether ``[0, size)`` has been sent whole."""
        return size == 0 or (len(self.starts) == 1 and self.starts[0] == 0
                             and self.ends[0] >= size)

    def __len__(self) -> int:
        return len(self.starts)
