"""Recording file names: ``<station>_<YYYYmmddTHHMMSSZ>[_<n>].mcap`` with its ``.ubx`` sidecar."""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterator
from pathlib import Path

MAX_SAME_SECOND = 10_000


def session_file_stem(station: str, start_ns: int) -> str:
    """``<station>_<YYYYmmddTHHMMSSZ>`` for a UTC start time given as UNIX ns."""
    when = dt.datetime.fromtimestamp(start_ns / 1e9, tz=dt.UTC)
    return f"{station}_{when:%Y%m%dT%H%M%SZ}"


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
