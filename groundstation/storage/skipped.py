"""What a reader could not read in a damaged recording and skipped: one record, said the same way
by every tool (the log's warning line, ``inspect``'s output and ``--json``).

Kept apart from :mod:`~groundstation.storage.mcapio` so that ``inspect`` of a ``.ubx`` can name
the type without loading the ``mcap`` library.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any


def _utc(t_ns: int) -> str:
    try:
        when = dt.datetime.fromtimestamp(t_ns / 1e9, dt.UTC)
    except (OverflowError, OSError, ValueError):
        return f"{t_ns} ns"
    return when.strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


@dataclass(frozen=True, slots=True)
class Skipped:
    """A stretch of a recording file that could not be read, and what it cost.

    The times are the recording's log times (host time of reception, UNIX ns). When the file's
    summary names the lost chunks, ``lost_first_ns`` .. ``lost_last_ns`` is their span;
    otherwise only the messages read on either side bound it (``read_before_ns``, the last one
    read before the damage, and ``read_after_ns``, the first one after).
    """

    file: str
    start_byte: int
    end_byte: int
    """Exclusive; the file's size when nothing after the damage could be read."""
    reason: str
    chunks: int | None = None
    """Chunks lost, from the file's summary; ``None`` when the file has none to say."""
    lost_first_ns: int | None = None
    lost_last_ns: int | None = None
    read_before_ns: int | None = None
    read_after_ns: int | None = None
    to_end: bool = False
    """Nothing after the damage could be read."""

    @property
    def bytes(self) -> int:
        return self.end_byte - self.start_byte

    def time_span(self) -> str:
        """The time lost, as precisely as the file allows."""
        if self.lost_first_ns is not None and self.lost_last_ns is not None:
            return (f"messages logged {_utc(self.lost_first_ns)} .. {_utc(self.lost_last_ns)} "
                    "lost")
        before = _utc(self.read_before_ns) if self.read_before_ns is not None else None
        after = _utc(self.read_after_ns) if self.read_after_ns is not None else None
        if before and after:
            return f"messages logged between {before} and {after} lost"
        if before:
            return f"messages logged after {before} lost"
        if after:
            return f"messages logged before {after} lost"
        return "no message could be read around it"

    @property
    def nothing_read(self) -> bool:
        """No message could be read before the damage nor after it: the file is unreadable as
        a recording, which the tool's error says (:meth:`brief`), not a warning of its own."""
        return self.to_end and self.read_before_ns is None and self.lost_first_ns is None

    def brief(self) -> str:
        """Where and why, in a few words, for a tool's error line."""
        end = "the end of the file" if self.to_end else f"{self.end_byte:,}"
        return f"bytes {self.start_byte:,} .. {end} unreadable: {self.reason}"

    def describe(self) -> str:
        """One line: where, why, what was lost and where reading went on."""
        end = "the end of the file" if self.to_end else f"{self.end_byte:,}"
        chunks = "" if self.chunks is None else (
            f", {self.chunks} chunk{'s' if self.chunks != 1 else ''}")
        goes_on = "nothing after it could be read" if self.to_end else "read on after it"
        return (f"{self.file}: bytes {self.start_byte:,} .. {end} unreadable ({self.reason}): "
                f"{self.bytes:,} bytes{chunks} skipped, {self.time_span()}; {goes_on}")

    def as_json(self) -> dict[str, Any]:
        return {
            "file": self.file, "start_byte": self.start_byte, "end_byte": self.end_byte,
            "bytes": self.bytes, "reason": self.reason, "chunks": self.chunks,
            "lost_first_ns": self.lost_first_ns, "lost_last_ns": self.lost_last_ns,
            "read_before_ns": self.read_before_ns, "read_after_ns": self.read_after_ns,
            "to_end": self.to_end, "description": self.describe(),
        }
