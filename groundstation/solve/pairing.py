"""Base pairing: a rover station's session solved against the base *station*'s recording.

The solver configuration may name a base station instead of a base file
(``[stations.rover] base = "station:base"``, :func:`base_station`). The solver then keeps the
recent ``session`` messages of every station (:meth:`Pairing.note`); each carries the span of
epochs its recording holds (``first_epoch_t_gps_ns``, ``last_epoch_t_gps_ns``, added by the
daemon's publisher). For a finished rover session, :meth:`Pairing.base_for` picks the base
session whose span covers the rover's, and hands back its first recording file (the recording
reader follows the session's later parts by itself). A base that is still recording is fine:
the solver waits, up to ``base_wait_s``, for the base's span to reach the rover's last epoch,
and says so when it gives up. While it waits it asks the base daemon for its session every
second (``q/session``: the files and the span recorded so far), since the daemon announces its
session only at every new file and at the end, and a solver started later never heard that;
the recording reader reads a file still being written up to its last complete chunk. A base
recording is confined to ``recording_roots`` like the rover's.

No Zenoh in here: the service feeds the messages and calls :meth:`Pairing.base_for` from its
worker thread.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from groundstation.config import check_station
from groundstation.errors import ConfigError, GroundstationError

STATION_PREFIX = "station:"
"""``base = "station:<name>"``: the base is that station's recording of the same time."""
KEEP_SESSIONS = 50
"""Session messages kept per station (the most recent ones)."""
BASE_WAIT_S = 300.0
"""Default bound on the wait for a base recording that covers the rover's last epoch."""

SPAN_SLACK_NS = 2_000_000_000
"""The daemon reports its span from its status (once a second, and once at the end), so a
span's ends may be a second or so short: a base ending within this of the rover's last epoch
covers it."""

Confine = Callable[[Path], tuple[Path | None, str]]
"""``confine(path) -> (resolved path or None, why not)`` (the service's recording roots)."""
AskSession = Callable[[str], Mapping[str, Any] | None]
"""``ask(station)``: the station's current (checked) session message, if its daemon answers."""
ASK_EVERY_S = 1.0


def base_station(value: str | None, key: str = "base", station: str | None = None) -> str | None:
    """The base station a ``base`` value names (``station:<name>``), or ``None`` for a path.

    Args:
        value: the configured ``base``.
        key: the dotted key, for the error.
        station: the station this value is configured for (a station is not its own base).

    Raises:
        ConfigError: ``station:`` followed by no valid station name, or the station itself.
    """
    if value is None:
        return None
    head, sep, name = value.partition(":")
    if not sep or head.strip().lower() not in ("station", "stations"):
        return None
    if head != "station":
        raise ConfigError(key, f"{value!r}: write station:<name> to pair with a base station")
    name = check_station(name, key)
    if station is not None and name == station:
        raise ConfigError(key, f"station {station!r} cannot be its own base")
    return name


def span_of(session: Mapping[str, Any]) -> tuple[int, int] | None:
    """A session message's ``(first, last)`` epoch time (GPS ns), if it carries both."""
    first, last = session.get("first_epoch_t_gps_ns"), session.get("last_epoch_t_gps_ns")
    if isinstance(first, int) and isinstance(last, int) and first <= last:
        return first, last
    return None


def _s(ns: int) -> float:
    return ns / 1e9


class Pairing:
    """The recent sessions of every station, and the base recording for a rover's span.

    Args:
        confine: checks a base recording's path (the service's :func:`~.service.confine`).
        wait_s: how long :meth:`base_for` waits for a base recording that covers the span.
        keep: session messages kept per station.
    """

    def __init__(self, confine: Confine, wait_s: float = BASE_WAIT_S,
                 keep: int = KEEP_SESSIONS) -> None:
        self._confine = confine
        self.wait_s = wait_s
        self._keep = keep
        self._cond = threading.Condition()
        self._sessions: dict[str, OrderedDict[str, dict[str, Any]]] = {}
        self.ask: AskSession | None = None
        """Asks a base daemon for its session while waiting (set by the service on the bus)."""

    def note(self, station: str, session: Mapping[str, Any]) -> None:
        """Keep a (checked) session message of ``station``; wakes a waiting :meth:`base_for`."""
        sid = str(session.get("session_id") or "")
        if not sid:
            return
        with self._cond:
            per = self._sessions.setdefault(station, OrderedDict())
            per.pop(sid, None)
            per[sid] = dict(session)
            while len(per) > self._keep:
                per.popitem(last=False)
            self._cond.notify_all()

    def _best(self, base: str, span: tuple[int, int]) -> tuple[dict[str, Any] | None, bool]:
        """The base session overlapping ``span`` most, and whether it covers it whole."""
        best: dict[str, Any] | None = None
        best_overlap = -1
        for msg in (self._sessions.get(base) or {}).values():
            got = span_of(msg)
            if got is None or not msg.get("files"):
                continue
            overlap = min(got[1], span[1]) - max(got[0], span[0])
            if overlap >= 0 and overlap > best_overlap:
                best, best_overlap = msg, overlap
        if best is None:
            return None, False
        got = span_of(best)
        assert got is not None
        return best, got[0] <= span[0] + SPAN_SLACK_NS and got[1] >= span[1] - SPAN_SLACK_NS

    def base_for(self, base: str, span: tuple[int, int] | None, stop: threading.Event,
                 notes: list[str]) -> Path:
        """The base station's recording for a rover session of ``span`` (GPS ns).

        Waits up to :attr:`wait_s` for a session of ``base`` that covers the span (a base
        still recording reaches the rover's last epoch later); after that, a base that covers
        part of it is used with a note, none at all is an error.

        Raises:
            GroundstationError: no recording of the base overlaps the span, or it lies
                outside the recording roots, or the rover session carries no span.
        """
        if span is None:
            raise GroundstationError(
                "the rover's session message carries no epoch span (first_epoch_t_gps_ns, "
                "last_epoch_t_gps_ns): cannot pick the base station's recording")
        deadline = time.monotonic() + self.wait_s
        waited = unknown = False
        while True:
            with self._cond:
                msg, covers = self._best(base, span)
            left = deadline - time.monotonic()
            if covers or left <= 0 or stop.is_set():
                break
            waited = True
            ask = self.ask
            current = ask(base) if ask is not None else None
            if current is not None:
                self.note(base, current)
            elif not self._sessions.get(base):  # never heard of, and no daemon answers:
                unknown = True                  # waiting would only hold the queue up
                break
            with self._cond:
                self._cond.wait(min(left, ASK_EVERY_S))
        if msg is None:
            why = (f"no session of it heard and no daemon of {base!r} answers" if unknown
                   else f"gave up after waiting {self.wait_s:g} s (base_wait_s)")
            raise GroundstationError(
                f"no recording of base station {base!r} covers the rover's epochs "
                f"(GPS {_s(span[0]):.1f}-{_s(span[1]):.1f} s): {why}")
        got = span_of(msg)
        assert got is not None
        if not covers:
            cover = max(0, min(got[1], span[1]) - max(got[0], span[0]))
            notes.append(
                f"base station {base!r} covers {_s(cover):.0f} s of the rover's "
                f"{_s(span[1] - span[0]):.0f} s (gave up waiting for more after "
                f"{self.wait_s:g} s, base_wait_s): epochs outside it are not solved")
        elif waited:
            notes.append(f"waited for base station {base!r} to record the rover's last epoch")
        first = Path(str(msg["files"][0]))
        real, why = self._confine(first)
        if real is None:
            raise GroundstationError(f"base station {base!r}: recording refused: {why}")
        notes.append(f"base: station {base!r}, session {msg.get('session_id')}, {first.name}")
        return real
