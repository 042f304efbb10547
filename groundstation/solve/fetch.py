"""Fetching a station's recording over Zenoh, for a solver that cannot read it where it is.

A ``session`` message lists, per finished file, its ``name``, ``size``, ``sha256`` and
``chunk_bytes`` (``recordings[]``); the daemon answers chunk queries on
``groundstation/<station>/q/recording/<session_id>`` (:mod:`groundstation.live.serve`; wire
rules: :mod:`groundstation.storage.transfer`). :func:`remote_for` decides whether a recording
named by the session is fetched (configuration ``fetch``: ``auto`` when the path is not a
readable file inside the recording roots, ``always``, ``never``); :class:`Fetcher` fetches it:

- into ``<out_root>/<station>/<name>.part``, chunk by chunk in order, :data:`WINDOW` queries in
  flight; a chunk is appended only once its CRC, offset and length match;
- a query without a reply (a broken link, a router restarting, the daemon gone) is asked again
  after a growing pause, resuming at the ``.part`` file's size; so does a later fetch of the
  same file (a solver restarted), since the ``.part`` is kept;
- when the announced size is reached, the whole file's SHA-256 must equal the announced one,
  else the ``.part`` is discarded and fetched once more from the start; only a verified file is
  renamed to ``<name>`` and solved;
- a refusal by the daemon (an unknown file or session) fails the fetch at once, with its text;
  so does an announced size that would leave less than 100 MB free on the solver's disk.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from groundstation.bus import Bus, Reply, key
from groundstation.errors import GroundstationError
from groundstation.storage import transfer

log = logging.getLogger("groundstation.fetch")

WINDOW = 8
"""Chunk queries in flight at once (8 x 256 KiB: the link stays busy across a router hop)."""
QUERY_TIMEOUT_S = 10.0
STALL_S = 120.0
"""Give up when no chunk arrived for this long (the ``.part`` is kept for the next try)."""
RETRY_MIN_S, RETRY_MAX_S = 0.2, 5.0
ATTEMPTS = 2
"""Whole-file attempts: a SHA-256 mismatch discards the ``.part`` and fetches once more."""
FREE_MARGIN_BYTES = 100_000_000
"""Left free on the solver's disk: a station announcing a huge file cannot fill it."""


@dataclass(frozen=True, slots=True)
class Remote:
    """A recording to fetch: where it is served, what it must be, where it goes."""

    station: str
    session_id: str
    name: str
    size: int
    sha256: str
    chunk_bytes: int
    dest: Path

    @property
    def key_expr(self) -> str:
        return key(self.station, f"q/recording/{self.session_id}")


def _readable_inside(confined: Path | None) -> bool:
    return confined is not None and confined.is_file() and os.access(confined, os.R_OK)


def remote_for(station: str, session: Mapping[str, Any], given: Path, out_root: Path,
               confined: Path | None, mode: str = "auto") -> Remote | None:
    """The served copy of the recording ``given`` to fetch, or None (solve it in place, or
    refuse it as before).

    Args:
        station: the (checked) station name.
        session: the (checked) ``session`` message.
        given: the recording path the message names.
        out_root: the station's output root: the copy goes to ``out_root/<station>/<name>``.
        confined: ``given`` resolved inside the recording roots, None when outside them.
        mode: ``auto`` (fetch when not a readable file inside the roots), ``always``,
            ``never``.
    """
    if mode == "never" or (mode == "auto" and _readable_inside(confined)):
        return None
    sid = str(session.get("session_id") or "")
    if not transfer.SESSION_ID.fullmatch(sid):
        return None
    for entry in session.get("recordings") or []:
        if isinstance(entry, dict) and entry.get("name") == given.name:
            e = transfer.check_entry(entry)  # checked with the message already; cheap
            return Remote(station, sid, e["name"], e["size"], e["sha256"], e["chunk_bytes"],
                          out_root / station / e["name"])
    return None


class Fetcher:
    """Fetches served recordings over one bus (see the module docstring).

    Args:
        bus: the solver's Zenoh session.
        window: chunk queries in flight.
        query_timeout_s: how long one query waits for its reply.
        stall_s: give up after this long without a chunk.
        sleep: pause between retries (a test passes a faster one).

    Attributes:
        retries: queries asked again (no reply, a damaged chunk).
        bad_chunks: replies refused by their CRC, offset or length.
        discarded: whole ``.part`` files thrown away for a SHA-256 mismatch.
        resumed_at: the ``.part`` size the last fetch started from.
    """

    def __init__(self, bus: Bus, *, window: int = WINDOW,
                 query_timeout_s: float = QUERY_TIMEOUT_S, stall_s: float = STALL_S,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.bus = bus
        self.window = window
        self.query_timeout_s = query_timeout_s
        self.stall_s = stall_s
        self._sleep = sleep
        self.retries = 0
        self.bad_chunks = 0
        self.discarded = 0
        self.resumed_at = 0

    def fetch(self, remote: Remote) -> Path:
        """Fetch (or find already fetched) ``remote``; returns its verified path.

        Raises:
            GroundstationError: refused by the daemon, no chunk for ``stall_s``, or the
                SHA-256 still wrong after a fresh fetch; what was received stays in the
                ``.part`` unless it was proven wrong.
        """
        dest = remote.dest
        if dest.exists():
            if dest.is_file() and transfer.sha256_file(dest) == remote.sha256:
                log.info("%s already fetched", dest)
                return dest
            raise GroundstationError(f"{dest} exists with other content: not overwritten")
        dest.parent.mkdir(parents=True, exist_ok=True)
        part = dest.with_name(dest.name + ".part")
        have = part.stat().st_size if part.exists() else 0
        free = shutil.disk_usage(dest.parent).free
        if remote.size - have > free - FREE_MARGIN_BYTES:  # an announced size is not trusted
            raise GroundstationError(f"{remote.name}: {remote.size} bytes announced, "
                                     f"{free} free in {dest.parent}: not fetched")
        log.info("fetching %s (%d bytes) from station %s over Zenoh into %s", remote.name,
                 remote.size, remote.station, dest.parent)
        for attempt in range(1, ATTEMPTS + 1):
            self._fill(remote, part)
            digest = transfer.sha256_file(part)
            if digest == remote.sha256:
                os.replace(part, dest)
                log.info("fetched %s (%d bytes, SHA-256 verified)", dest, remote.size)
                return dest
            self.discarded += 1
            part.unlink()
            log.warning("%s: SHA-256 mismatch after %d bytes: discarded (attempt %d of %d)",
                        part, remote.size, attempt, ATTEMPTS)
        raise GroundstationError(f"{remote.name}: SHA-256 differs from the announced one "
                                 f"after {ATTEMPTS} fetches")

    def _fill(self, remote: Remote, part: Path) -> None:
        """Append chunks to ``part`` until it holds ``remote.size`` bytes."""
        with part.open("ab") as out:
            pos = out.tell()
            if pos > remote.size:  # not ours to trust: longer than the file
                out.truncate(0)
                pos = 0
            self.resumed_at = pos
            if pos:
                log.info("%s: resuming at %d of %d bytes", part, pos, remote.size)
            pending: deque[tuple[transfer.Request, Callable[[], list[Reply]]]] = deque()
            ahead = pos
            last_progress = time.monotonic()
            pause = RETRY_MIN_S
            while pos < remote.size:
                while len(pending) < self.window and ahead < remote.size:
                    req = transfer.Request(remote.name, ahead,
                                           min(remote.chunk_bytes, remote.size - ahead))
                    pending.append((req, self.bus.ask(remote.key_expr, req.parameters(),
                                                      self.query_timeout_s)))
                    ahead += req.length
                req, replies = pending.popleft()
                data = self._chunk(remote, req, replies())
                if data is None:  # start over from here after a pause
                    pending.clear()
                    ahead = pos
                    self.retries += 1
                    if time.monotonic() - last_progress > self.stall_s:
                        raise GroundstationError(
                            f"{remote.name}: no chunk from station {remote.station} for "
                            f"{self.stall_s:g} s; {pos} of {remote.size} bytes kept in {part} "
                            "(the next fetch resumes there)")
                    self._sleep(pause)
                    pause = min(RETRY_MAX_S, pause * 2)
                    continue
                out.write(data)
                pos += len(data)
                last_progress = time.monotonic()
                pause = RETRY_MIN_S
            out.flush()
            with contextlib.suppress(OSError):
                os.fsync(out.fileno())

    def _chunk(self, remote: Remote, req: transfer.Request,
               replies: list[Reply]) -> bytes | None:
        """The chunk's bytes, None when it must be asked again."""
        for reply in replies:
            if reply.error:
                raise GroundstationError(
                    f"{remote.name}: station {remote.station} refused the fetch: "
                    f"{reply.payload[:300].decode(errors='replace')}")
        ok = [r for r in replies if not r.error]
        if not ok:
            log.debug("%s: no reply for the chunk at %d", remote.name, req.offset)
            return None
        try:
            transfer.check_chunk(req, ok[0].payload, ok[0].attachment)
        except transfer.BadRequest as err:
            self.bad_chunks += 1
            log.warning("%s: %s: asked again", remote.name, err)
            return None
        if len(ok[0].payload) != req.length:
            self.bad_chunks += 1
            log.warning("%s: a chunk of %d bytes where %d were asked: asked again",
                        remote.name, len(ok[0].payload), req.length)
            return None
        return ok[0].payload
