"""The latest solution message of each recording, answered on ``groundstation/<station>/
q/solution`` for a view or a worker that joins late (``docs/zenoh.md``).

Held in memory by the solver service: every ``solution`` it publishes replaces the previous
one of the same recording (station, session, file name); the oldest recordings are forgotten
beyond :data:`MAX_RECORDINGS`.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import PurePath
from typing import Any

from groundstation.bus import Reply, intersects, key

MAX_RECORDINGS = 10_000


class LatestSolutions:
    """The last solution payload per recording; :meth:`answer` is the queryable's handler."""

    def __init__(self, max_recordings: int = MAX_RECORDINGS) -> None:
        self._latest: OrderedDict[tuple[str, str, str], bytes] = OrderedDict()
        self._lock = threading.Lock()
        self.max_recordings = max_recordings

    def keep(self, station: str, body: Mapping[str, Any], payload: bytes) -> None:
        """Remember ``payload`` (the encoded ``body``) as the station's latest for its
        recording."""
        flight = body.get("flight")
        ident = (station, str(body.get("session_id") or ""),
                 PurePath(str(flight)).name if flight else "")
        with self._lock:
            self._latest.pop(ident, None)
            self._latest[ident] = payload
            while len(self._latest) > self.max_recordings:
                self._latest.popitem(last=False)

    def answer(self, query_key: str, _params: Mapping[str, str | None]) -> list[Reply]:
        """One reply per recording of every station the query's key names, oldest first."""
        with self._lock:
            items = list(self._latest.items())
        out = []
        for (station, _sid, _name), payload in items:
            k = key(station, "q/solution")
            if intersects(k, query_key):
                out.append(Reply(k, payload))
        return out
