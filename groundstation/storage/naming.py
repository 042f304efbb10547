"""Recording names: files ``<station>_<YYYYmmddTHHMMSSZ>[_<n>].mcap`` with their ``.ubx``
sidecars, and session ids ``<station>_<YYYYmmddTHHMMSSZ>-<token>``.

A file name is unique in its directory (created exclusively, the next ``_<n>`` if taken). A
session id must be unique everywhere it travels (the bus, the views, the solver): two daemons
with the same station name started in the same second, on one machine or two, would otherwise
share one. The random token after a ``-`` makes it so; ``-`` sorts before the digits and ``_``,
so every part of a session, named ``<station>_<its start second>[_<n>]``, still sorts at or
after its session id (the reader's part-following relies on it, ``storage/reading.py``).
"""

from __future__ import annotations

import datetime as dt
import re
import secrets
from collections.abc import Iterator
from pathlib import Path

MAX_SAME_SECOND = 10_000
SESSION_TOKEN_BYTES = 3
"""24 random bits: two sessions of one station started in the same second share an id with a
probability of 1 in 16.7 million."""

_SESSION_TIME = re.compile(r"_(\d{8}T\d{6}Z)(?:-[0-9a-f]+)?$")


def session_file_stem(station: str, start_ns: int) -> str:
    """``<station>_<YYYYmmddTHHMMSSZ>`` for a UTC start time given as UNIX ns."""
    when = dt.datetime.fromtimestamp(start_ns / 1e9, tz=dt.UTC)
    return f"{station}_{when:%Y%m%dT%H%M%SZ}"


def new_session_id(station: str, start_ns: int) -> str:
    """A fresh session id: ``<station>_<YYYYmmddTHHMMSSZ>-<6 hex digits>`` (module docstring)."""
    return f"{session_file_stem(station, start_ns)}-{secrets.token_hex(SESSION_TOKEN_BYTES)}"


def session_start_ns(session_id: str) -> int | None:
    """The UTC start second (UNIX ns) a session id or file stem names, or None."""
    m = _SESSION_TIME.search(session_id)
    if m is None:
        return None
    when = dt.datetime.strptime(m.group(1), "%Y%m%dT%H%M%SZ").replace(tzinfo=dt.UTC)
    return int(when.timestamp()) * 1_000_000_000


def candidate_pairs(out_dir: Path, stem: str) -> Iterator[tuple[Path, Path]]:
    """The (MCAP, sidecar) names to try for a file started at ``stem``'s second, in order: the
    stem itself, then ``<stem>_1``, ``<stem>_2`` ... (several parts can start within a second
    after a rotation or a write failure; a file is never overwritten).

    Raises:
        FileExistsError: after :data:`MAX_SAME_SECOND` names (never in practice).
    """
    for n in range(MAX_SAME_SECOND):
        name = stem if n == 0 else f"{stem}_{n}"
        yield out_dir / f"{name}.mcap", out_dir / f"{name}.ubx"
    raise FileExistsError(f"no free file name for {stem} in {out_dir}")
