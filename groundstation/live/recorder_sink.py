"""The recorder sink: drains its inbox into a :class:`SessionRecorder`, flushing on a timer.

Never drops (its inbox's policy is ``NEVER_DROP``); closes the chunk and flushes MCAP and sidecar
at least every ``flush_interval_s``, even when no data arrives, and writes the MCAP summary
when the inbox is closed and drained. It accepts the raw chunks and every record type of the
topic registry (``storage/topics.py``). When writing fails (a full disk) the session recorder
holds the data and retries (``storage/session.py``); this sink records and publishes what it
reports (``recorder.write_failed``, ``recorder.dropped``, ``recorder.recovered``,
``recorder.vanished``) and announces the file the recording resumes in.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from groundstation.live.fanout import Inbox, InboxClosed, Publish
from groundstation.records import Item, RawChunk
from groundstation.storage.session import SessionRecorder
from groundstation.storage.topics import recorded_types

log = logging.getLogger("groundstation.recorder")

LINGER_S = 0.1
"""How long the sink waits for more items once one has arrived (then until the next item, at
most twice this: ``fanout.LINGER_LATE``): at 115 200 baud the serial source hands over its
reads every 100 ms (a mark at once), and writing them in bursts costs a fraction of a wake-up
each. Durability is the flush
interval's business (0.5 s by default), which this is well below."""


class RecorderSink:
    """A :class:`~groundstation.live.fanout.Sink` that records everything it receives.

    Args:
        recorder: the session recorder (opened by :meth:`open` or by ``consume``).
        flush_interval_s: the longest time between flushes.
        on_file: called with the path of each new file (first one and rotations).
        clock: UNIX ns clock for items that carry no host time.
    """

    name = "recorder"

    def __init__(
        self,
        recorder: SessionRecorder,
        flush_interval_s: float,
        on_file: Callable[[Path], None] | None = None,
        *,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self._clock = clock
        self.recorder = recorder
        self.flush_interval_s = flush_interval_s
        self._on_file = on_file
        self._opened = False
        self._files_seen = 0

    @property
    def accepts(self) -> frozenset[type]:
        return recorded_types()

    def open(self) -> Path:
        """Create the first file now (so its path is known before data flows)."""
        if not self._opened:
            self.recorder.open()
            self._opened = True
            self._notify_files()
        path = self.recorder.current_file
        assert path is not None
        return path

    def _notify_files(self) -> None:
        if self.recorder.failing:
            return  # a part opened while recovering is announced once it holds the backlog
        files = self.recorder.created_files  # lost ones too: the indices stay put
        if self._on_file is not None:
            for path in files[self._files_seen:]:
                self._on_file(path)
        self._files_seen = len(files)

    def write(self, item: Item) -> None:
        """Record one item (synchronously)."""
        if type(item) is RawChunk:
            self.recorder.write_raw(item.data, item.t_host_ns)
            if self.recorder.file_count != self._files_seen:
                self._notify_files()
        else:
            # log_time is the host time the record's bytes arrived (events: when they happened).
            t = getattr(item, "t_host_ns", 0)
            self.recorder.write_record(item, t if isinstance(t, int) and t > 0 else self._clock())

    def _write_burst(self, items: list[Item]) -> None:
        """:meth:`write` for each item, the loop in the session recorder (one call a burst)."""
        recorder, i, n = self.recorder, 0, len(items)
        while i < n:
            i = recorder.write_items(items, i, self._clock, self._files_seen)
            if type(items[i - 1]) is RawChunk and recorder.file_count != self._files_seen:
                self._notify_files()  # where write() announces a new file

    async def consume(self, inbox: Inbox, publish: Publish) -> None:
        self.open()
        try:
            while True:
                try:
                    items = await inbox.get_all(timeout_s=self.flush_interval_s,
                                                linger_s=LINGER_S)
                except InboxClosed:
                    break
                self._write_burst(items)
                self.recorder.maybe_flush()
                for event in self.recorder.take_notices():
                    self.write(event)  # our own news never comes back through the fanout
                    publish(event)
                if self.recorder.file_count != self._files_seen:
                    self._notify_files()  # a new part after a recovered write failure
        finally:
            self.recorder.close()
