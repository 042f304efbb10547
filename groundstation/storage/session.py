"""A recording session: MCAP files plus their ``.ubx`` sidecars, and the state machine that
survives a disk that fills up.

Sans-asyncio: the live recorder sink (``live/recorder_sink.py``) feeds it; tests and tools can
drive it directly. Raw chunks go to ``/ubx/raw`` byte for byte (``log_time`` = host receive time)
and to the sidecar; decoded records go to the JSON channels of the topic registry
(``storage/topics.py``), with ``publish_time`` from ``storage/publish_time.py``. File names come
from ``storage/naming.py``, when to start the next file from ``storage/rotation.py``, the
LocationFix messages from ``storage/location.py``, and what is held while writing fails from
``storage/backlog.py``.

The write path: while no rotation is due, a message goes straight into the MCAP chunk in
progress (a record's JSON is encoded there, :meth:`~groundstation.storage.mcapio.McapFileWriter.
add_typed`). Whether one is due is two comparisons per message against the current file's
:meth:`~groundstation.storage.rotation.RotationPolicy.limits`, worked out again for each new
file, at each flush and when a chunk is closed, so a file ends exactly where the per-message
rule ends it. Otherwise (or while writing fails) the full path below is taken. The recorder
sink hands over a whole burst (:meth:`SessionRecorder.write_items`).

Write failures (ENOSPC, EDQUOT, EIO ... any ``OSError``) never escape. The design:

- Every message handed to the MCAP writer since its last successful flush is *pending*: the
  writer can give it back (:meth:`~groundstation.storage.mcapio.McapFileWriter.unsettled`,
  read from the uncompressed chunks it holds until then, at most one flush interval), and the
  sizes of the MCAP and the sidecar after that flush are known-good boundaries (files are
  written unbuffered and never short, :class:`~groundstation.storage.mcapio.ExactFile`).
- When a write fails, the current pair is *abandoned*: the MCAP is cut back to its last good
  chunk boundary and closed without a summary (a torn chunk is never left behind, and nothing in
  it is duplicated later), the sidecar is cut back to the same point in the byte stream. The
  pending messages go back to the front of an in-memory *backlog*, which takes everything that
  arrives from then on, in order. A ``recorder.write_failed`` event says so.
- The backlog is bounded (``backlog_bytes_max``); what gives way first, and how drops are
  reported, is :class:`~groundstation.storage.backlog.Backlog`'s.
- Every ``retry_interval_ns`` a new pair is opened (the next part, as for a rotation, its
  metadata naming the previous file and the failure) and the backlog is written into it in
  slices of about 1 MB, one slice per call of :meth:`SessionRecorder.maybe_flush` (the live
  sink calls it after every item), each slice flushed, so a large backlog never stalls the
  event loop and the serial reader; what arrives meanwhile queues behind the backlog. If a
  slice fails, the part is abandoned like any other at its last good chunk boundary (or
  deleted if it holds no message yet) and the rest waits for the next retry. When the backlog
  is empty, ``recorder.recovered`` reports what was written and what was lost. The
  concatenation of the parts' ``/ubx/raw`` (and of the sidecars) is then again every byte
  received, in order, except for the counted drops; each sidecar still holds exactly its MCAP
  part's raw bytes.
- A recording that cannot even be started (the first file) raises ``OSError`` from
  :meth:`SessionRecorder.open`: the daemon refuses to start with that message.

Files that vanish (the out dir deleted, a file unlinked, renamed away or replaced) raise no
error on write: the descriptors still work, into an inode nobody can reach. So at every flush,
after the chunk is written and before the pending messages are let go, and before a rotation,
the current pair's paths are checked against the inodes created (a ``stat`` per file, twice a
second at the default flush interval, never per message). When they differ, a
``recorder.vanished`` event names the files lost (every file of the session no longer at its
path), the directory is created again and the session continues in a new part, starting with
the pending messages: everything received since the last check, so nothing after the deletion
is lost. If the directory cannot be created, the write-failure machine above takes over
(``recorder.write_failed``, data held in memory, retried). The summary (:attr:`stats`) names
only files that exist, and the lost ones apart.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from groundstation import __version__, jsonio
from groundstation import events as kinds
from groundstation.records import Event, NavSolution, RawChunk
from groundstation.storage.backlog import Backlog, Msg, cost, size_text
from groundstation.storage.location import LOCATION_CHANNEL, location_fix
from groundstation.storage.mcapio import ExactFile, McapFileWriter, WritableFile
from groundstation.storage.naming import candidate_pairs, new_session_id, session_file_stem
from groundstation.storage.publish_time import PublishClock
from groundstation.storage.rotation import RotationPolicy
from groundstation.storage.topics import RAW_CHANNEL, ROUTES

log = logging.getLogger("groundstation.recorder")

SAME_FIX_EPOCH_NS = 5_000_000
"""Two receiver solutions this close are one epoch's (NAV-SOL's TOW carries its sub-millisecond
``fTOW``, NAV-POSLLH's does not; u-blox navigation rates are at most 20-25 Hz, 40 ms apart)."""


@dataclass(frozen=True, slots=True)
class RecorderStats:
    """Counters of a recording session.

    ``raw_chunks``/``raw_bytes``/``records`` count what was received; what a write failure made
    it drop is in the ``dropped_*`` counters and ``held_bytes`` is the memory taken by what waits
    (data plus a per-message overhead). ``files`` and ``sidecars`` exist (as far as the
    recorder knows); ``lost_files`` were deleted under it (module docstring).
    """

    session_id: str
    files: tuple[Path, ...]
    sidecars: tuple[Path, ...]
    raw_chunks: int
    raw_bytes: int
    records: int
    events: int
    flushes: int
    write_failures: int = 0
    held_bytes: int = 0
    dropped_raw_chunks: int = 0
    dropped_raw_bytes: int = 0
    dropped_records: int = 0
    lost_files: tuple[Path, ...] = ()


FileOpener = Callable[[Path], WritableFile]


DRAIN_SLICE_BYTES = 1_000_000


class SessionRecorder:
    """Writes one session: MCAP files (rotated) plus a ``.ubx`` sidecar for each.

    Args:
        out_dir: directory for the files (created if missing).
        station: station name; files are ``<station>_<YYYYmmddTHHMMSSZ>.mcap``.
        receiver: receiver description for the metadata record.
        configuration: the resolved settings, recorded as metadata.
        chunk_size_bytes: MCAP chunk size target.
        compression: MCAP chunk compression.
        flush_interval_ns: close the chunk and flush both files at least this often.
        rotate_size_bytes: start a new file beyond this MCAP size (0 = never).
        rotate_duration_ns: start a new file after this long (0 = never).
        sidecar: write the ``.ubx`` sidecar.
        clock: wall clock in UNIX ns (injected for tests).
        backlog_bytes_max: what may be held in memory while writing fails.
        retry_interval_ns: how often writing is tried again after a failure.
        open_file: creates each file exclusively (the storage layer's fault hook for tests).
        max_chunks_per_file: start a new file after about this many MCAP chunks (why:
            :class:`~groundstation.storage.rotation.RotationPolicy`).
    """

    def __init__(
        self,
        out_dir: Path,
        station: str,
        *,
        receiver: str = "",
        configuration: dict[str, Any] | None = None,
        chunk_size_bytes: int = 64 * 1024,
        compression: str = "zstd",
        flush_interval_ns: int = 500_000_000,
        rotate_size_bytes: int = 0,
        rotate_duration_ns: int = 0,
        sidecar: bool = True,
        clock: Callable[[], int] = time.time_ns,
        backlog_bytes_max: int = 64_000_000,
        retry_interval_ns: int = 2_000_000_000,
        open_file: FileOpener = ExactFile,
        max_chunks_per_file: int = 43_200,
    ) -> None:
        self.out_dir = out_dir
        self.station = station
        self.receiver = receiver
        self.configuration = configuration or {}
        self.chunk_size_bytes = chunk_size_bytes
        self.compression = compression
        self.flush_interval_ns = flush_interval_ns
        self.rotation = RotationPolicy(rotate_size_bytes, rotate_duration_ns, chunk_size_bytes,
                                       max_chunks_per_file)
        self.sidecar = sidecar
        self._clock = clock
        self.backlog_bytes_max = backlog_bytes_max
        self.retry_interval_ns = retry_interval_ns
        self._open = open_file
        self._file_chunks = 0  # chunks closed by our flushes in the current file
        self._msgs_at_flush = 0
        self.session_id = ""
        self._mcap: McapFileWriter | None = None
        self._ubx: WritableFile | None = None
        self._files: list[Path] = []
        self._sidecars: list[Path] = []
        self._file_start_ns = 0
        self._last_flush_ns = 0
        self._latest_ns = 0  # the latest time the clock gave (a step back is told by it)
        self.clock_steps_back = 0
        """Times the clock stepped back (NTP, an operator): intervals went on across them."""
        # RotationPolicy.limits of the current file (module docstring: the write path)
        self._due_now = True
        self._data_limit = self._time_limit = 0
        self._publish_clock = PublishClock()
        self._raw_chunks = 0
        self._raw_bytes = 0
        self._records = 0
        self._fix_publish_ns: int | None = None  # the epoch of the last LocationFix written
        self._events = 0
        self._flushes = 0
        self._closed = False
        # write-failure handling (module docstring)
        self._mcap_good = 0
        self._side_good = 0
        self._failure: OSError | None = None
        self._failures = 0
        self._notices: list[Event] = []
        self._backlog = Backlog(backlog_bytes_max, clock, self._notices)
        self._next_retry_ns = 0
        self._pair_empty_size = 0  # MCAP size of the current pair before any message
        self._drained_bytes = 0
        # vanished files (module docstring)
        self._idents: list[tuple[Path, tuple[int, int]]] = []  # the current pair's inodes
        self._lost: dict[Path, None] = {}  # ordered set

    # -- the clock ------------------------------------------------------------------------------

    def _now(self) -> int:
        """The wall clock (file names, event times). Intervals (rotation by duration, the flush
        and retry intervals) are measured on its forward progress only: when it steps back,
        their starting points move back with it, so a step of an hour neither postpones the
        next flush nor the next part by an hour."""
        now = self._clock()
        if now < self._latest_ns:
            self._stepped_back(self._latest_ns - now)
        self._latest_ns = now
        return now

    def _stepped_back(self, step_ns: int) -> None:
        self.clock_steps_back += 1
        self._file_start_ns -= step_ns
        self._last_flush_ns -= step_ns
        if self._next_retry_ns:
            self._next_retry_ns -= step_ns
        self._set_limits()
        if step_ns >= 1_000_000_000:  # not the jitter of a clock being slewed
            log.info("the clock stepped back %.3f s: rotation, flush and retry intervals go "
                     "on from where they were", step_ns / 1e9)

    # -- lifecycle ------------------------------------------------------------------------------

    def open(self) -> Path:
        """Start the session: create the first file. Returns its path.

        Raises:
            OSError: if the first file cannot be created (nothing is recorded yet).
        """
        now = self._now()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.session_id = new_session_id(self.station, now)
        return self._open_file(now)

    def _open_file(self, now_ns: int, after_failure: str = "") -> Path:
        """Create the next MCAP + sidecar pair; on an ``OSError`` nothing is left behind."""
        stem = session_file_stem(self.station, now_ns)
        created: list[WritableFile] = []
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)  # again after it was deleted
            for path, side in candidate_pairs(self.out_dir, stem):
                if (side.exists() and self.sidecar) or path in self._lost:
                    continue  # a lost part's name stays its own (the summary names it lost)
                try:
                    mcap_file = self._open(path)
                except FileExistsError:
                    continue
                created.append(mcap_file)
                break
            # Unbuffered: every received byte is in the OS's hands at once, so a killed
            # daemon's sidecar holds everything it received (the MCAP loses at most one flush
            # interval).
            ubx = self._open(side) if self.sidecar else None
            if ubx is not None:
                created.append(ubx)
            mcap = McapFileWriter(
                path, chunk_size_bytes=self.chunk_size_bytes, compression=self.compression,
                library=f"groundstation {__version__}", file=mcap_file, keep_unsettled=True,
            )
            previous = self._files[-1].name if self._files else ""
            mcap.add_metadata(
                "groundstation",
                {
                    "station": self.station,
                    "receiver": self.receiver,
                    "software_version": __version__,
                    "session_id": self.session_id,
                    "part": str(len(self._files) + 1),
                    "started_utc_ns": str(now_ns),
                    "previous_file": previous,
                    "after_write_failure": after_failure,
                    "sidecar": side.name if self.sidecar else "",
                },
            )
            mcap.add_metadata("configuration", {"json": jsonio.dumps(self.configuration).decode()})
            mcap.flush()
            idents = [(f.path, _ident(f.path)) for f in created]
        except OSError:
            for f in created:
                with contextlib.suppress(OSError):
                    f.close()
                with contextlib.suppress(OSError):
                    f.path.unlink()  # our own file of a moment ago, holding nothing
            raise
        self._mcap, self._ubx = mcap, ubx
        self._idents = idents
        self._files.append(path)
        if self.sidecar:
            self._sidecars.append(side)
        self._file_start_ns = now_ns
        self._last_flush_ns = now_ns
        self._mcap_good = self._pair_empty_size = mcap.size_bytes
        self._side_good = 0
        self._file_chunks = self._msgs_at_flush = 0
        self._set_limits()
        if not after_failure:  # a recovery says so once it has succeeded
            log.info("recording to %s", path)
        return path

    def _set_limits(self) -> None:
        """Work out the current file's rotation limits again (after its size, its closed
        chunks or the file itself changed)."""
        mcap = self._mcap
        if mcap is not None:
            self._due_now, self._data_limit, self._time_limit = self.rotation.limits(
                size_bytes=mcap.size_bytes, closed_chunks=self._file_chunks,
                started_ns=self._file_start_ns)

    def _rotate_due(self, now_ns: int) -> bool:
        mcap = self._mcap
        if mcap is None:
            return False
        return self.rotation.due(size_bytes=mcap.size_bytes, data_bytes=mcap.data_bytes,
                                 closed_chunks=self._file_chunks,
                                 started_ns=self._file_start_ns, now_ns=now_ns)

    def _close_file(self) -> None:
        """Finish the current pair (MCAP summary). Raises ``OSError`` if that fails."""
        if self._mcap is not None:
            self._mcap.finish()
            self._mcap = None
        if self._ubx is not None:
            self._ubx.close()
            self._ubx = None

    def close(self) -> None:
        """Finish the MCAP (summary written) and close the sidecar; safe to call twice.

        After a write failure, one last attempt is made to write what is held; what still
        cannot be written is logged as lost (never raised).
        """
        if self._closed:
            return
        if self._failure is None and self._mcap is not None:
            self._pair_gone(self._now())
        if self._failure is not None:
            self._recover(self._now(), budget_bytes=None)
        if self._failure is None:
            try:
                self._close_file()
            except OSError as err:
                self._fail(err)
        self._closed = True
        self._mark_lost()  # earlier parts deleted meanwhile: not named as the recording
        if self._failure is not None:
            log.error(
                "session %s ends with its recording failing (%s): %d bytes held in memory "
                "are lost", self.session_id, self._failure, self._backlog.bytes,
            )
        log.info(
            "session %s finished: %d raw bytes, %d records, %d file(s)",
            self.session_id, self._raw_bytes, self._records, len(self._files) - len(self._lost),
        )
        if self._lost:
            log.warning("session %s: %d file(s) were deleted during the recording and are lost: "
                        "%s", self.session_id, len(self._lost),
                        ", ".join(str(p) for p in self._lost))

    # -- writing --------------------------------------------------------------------------------

    def write_raw(self, data: bytes, t_host_ns: int) -> None:
        """Record one received chunk byte for byte (MCAP ``/ubx/raw`` and the sidecar)."""
        self._raw_chunks += 1
        self._raw_bytes += len(data)
        self._write((RAW_CHANNEL, data, t_host_ns, t_host_ns))

    def write_record(self, record: Any, log_time_ns: int) -> bool:
        """Record a decoded record or event on its channel; False if its type is not routed."""
        spec = ROUTES.get(type(record))
        if spec is None:
            return False
        publish = self._publish_clock.publish_time_ns(record, log_time_ns)
        self._records += 1
        if isinstance(record, Event):
            self._events += 1
        mcap = self._mcap
        if mcap is not None and self._failure is None:
            now = self._now()
            if (now < self._time_limit and mcap.data_bytes < self._data_limit
                    and not self._due_now):  # _write's check; encoded straight into the chunk
                try:
                    if mcap.add_typed(spec, record, log_time_ns, publish):
                        self._set_limits()
                except OSError as err:
                    self._fail(err)
            else:
                self._write_at((spec, jsonio.dumps_typed(record), log_time_ns, publish), now)
        else:
            self._write((spec, jsonio.dumps_typed(record), log_time_ns, publish))
        if isinstance(record, NavSolution) and (
                self._fix_publish_ns is None
                or abs(publish - self._fix_publish_ns) >= SAME_FIX_EPOCH_NS):
            # One map point per epoch: a receiver sending NAV-SOL and NAV-POSLLH (the LEA-6T)
            # gave two LocationFix messages of the same instant and place.
            fix = location_fix(record, publish, self.station)
            if fix is not None:
                self._fix_publish_ns = publish
                self._write((LOCATION_CHANNEL, fix, log_time_ns, publish))
        return True

    def write_items(self, items: Sequence[Any], start: int, clock: Callable[[], int],
                    files_seen: int) -> int:
        """Record ``items[start:]`` (raw chunks and records) as :meth:`write_raw` and
        :meth:`write_record` would one by one, a record without a host time (``t_host_ns``)
        at ``clock()``; stop after a raw chunk when the session has other than
        ``files_seen`` files (so the caller can announce a new part where it would have
        item by item). Returns the index after the last item written."""
        n = len(items)
        i = start
        while i < n:
            item = items[i]
            i += 1
            if type(item) is RawChunk:
                self.write_raw(item.data, item.t_host_ns)
                if len(self._files) != files_seen:
                    return i
            else:
                # log_time is the host time the record's bytes arrived (events: when they
                # happened)
                t = getattr(item, "t_host_ns", 0)
                self.write_record(item, t if isinstance(t, int) and t > 0 else clock())
        return n

    def _write(self, msg: Msg) -> None:
        mcap = self._mcap
        if mcap is not None and self._failure is None:
            now = self._now()
            if (now < self._time_limit and mcap.data_bytes < self._data_limit
                    and not self._due_now):  # no rotation due (RotationPolicy.limits)
                spec, data, log_ns, publish_ns = msg
                try:
                    if mcap.add(spec, data, log_ns, publish_ns):
                        self._set_limits()  # the file grew by a chunk
                    if spec is RAW_CHANNEL and self._ubx is not None:
                        self._ubx.write(data)
                except OSError as err:
                    self._fail(err)  # the pending messages go to the backlog, in order
                return
            self._write_at(msg, now)
            return
        if self._closed:
            raise RuntimeError("recorder is closed")
        if self._mcap is None and self._failure is None:
            raise RuntimeError("recorder is not open")
        if self._failure is not None:
            self._backlog.hold(msg)
            return
        self._write_at(msg, self._now())

    def _write_at(self, msg: Msg, now: int) -> None:
        """:meth:`_write` when a rotation may be due at ``now``."""
        rotate = self._rotate_due(now)
        if rotate and self._pair_gone(now):
            self._write(msg)  # into the new part, or held if there is none
            return
        pending = False
        closed = self._idents
        try:
            if rotate:
                self._close_file()
                self._closed_pair_gone(closed, now)  # before the next part takes a name
                self._open_file(now)
            pending = True  # _put makes it pending before anything can fail
            self._put(msg)
        except OSError as err:
            self._fail(err)  # the pending messages go to the backlog, in order
            if not pending:  # the rotation failed
                self._backlog.hold(msg)

    def _closed_pair_gone(self, closed: list[tuple[Path, tuple[int, int]]], now: int) -> None:
        """The pair just closed by a rotation, deleted between the check before it and its
        close (the directory removed while the summary was written): the alert
        :meth:`_pair_gone` would have given. Checked before the next part is opened, which
        makes the directory again and could take the deleted part's free name (and inode),
        so that nothing would ever look lost."""
        gone = [path for path, ident in closed if not _still(path, ident)]
        if not gone:
            return
        self._say_vanished(f"{gone[0].name} was deleted or moved", self._mark_lost(),
                           f"continuing in a new part in {self.out_dir}", gone[0], now)

    def _say_vanished(self, why: str, lost: list[Path], then: str, file: Path,
                      now: int) -> None:
        """Log and publish that the recording vanished (``kinds.RECORDER_VANISHED``)."""
        names = ", ".join(p.name for p in lost) or "none"
        text = f"the recording vanished ({why}): {len(lost)} file(s) lost ({names}); {then}"
        log.error("%s", text)
        self._notices.append(Event(
            kinds.RECORDER_VANISHED, now, text, "error",
            {"error": why, "errno": errno.ENOENT, "file": str(file),
             "lost": [str(p) for p in lost], "out_dir": str(self.out_dir)},
        ))

    def _put(self, msg: Msg) -> None:
        """Into the current pair (pending until the next successful flush)."""
        assert self._mcap is not None
        spec, data, log_ns, publish_ns = msg
        if self._mcap.add(spec, data, log_ns, publish_ns):
            self._set_limits()
        if spec is RAW_CHANNEL and self._ubx is not None:
            self._ubx.write(data)

    # -- write failures -------------------------------------------------------------------------

    def _fail(self, err: OSError) -> None:
        """A write failed: abandon the current pair and hold everything not safely written."""
        now = self._now()
        first = self._failure is None
        self._failure = err
        self._failures += first
        path = self._mcap.path if self._mcap is not None else None
        pending = self._mcap.unsettled() if self._mcap is not None else []
        empty = self._mcap_good <= self._pair_empty_size and self._side_good == 0
        if self._mcap is not None and empty and len(self._files) > 1:
            # a new part that holds nothing yet: leave no empty files behind
            self._mcap.discard()
            self._files.pop()
            if self._ubx is not None:
                self._sidecars.pop()
                with contextlib.suppress(OSError):
                    self._ubx.close()
                with contextlib.suppress(OSError):
                    self._ubx.path.unlink()
            self._mcap = self._ubx = None
        if self._mcap is not None:
            self._mcap.abandon(self._mcap_good)
            self._mcap = None
        if self._ubx is not None:
            with contextlib.suppress(OSError):
                self._ubx.truncate(self._side_good)
            with contextlib.suppress(OSError):
                self._ubx.close()
            self._ubx = None
        self._backlog.push_front(pending)
        self._next_retry_ns = now + self.retry_interval_ns
        if first:
            self._report_failure(err, path or self.out_dir, now)

    def _report_failure(self, err: OSError, path: Path, now: int) -> None:
        """The ``recorder.write_failed`` event (and log line) of a failure's start."""
        reason = f"{err.strerror or err}" + (f" (errno {err.errno})" if err.errno else "")
        log.error("cannot write %s: %s; holding data in memory (up to %s), retrying "
                  "every %g s", path, reason, size_text(self.backlog_bytes_max),
                  self.retry_interval_ns / 1e9)
        self._notices.append(Event(
            "recorder.write_failed", now,
            f"cannot write the recording ({reason}): holding the data in memory (up to "
            f"{size_text(self.backlog_bytes_max)}), retrying every "
            f"{self.retry_interval_ns / 1e9:g} s", "error",
            {"error": reason, "errno": err.errno or 0, "file": str(path),
             "backlog_mb": self.backlog_bytes_max / 1e6},
        ))

    def _recover(self, now_ns: int, budget_bytes: int | None = DRAIN_SLICE_BYTES) -> None:
        """Write held data again: open a new pair if there is none, then move up to
        ``budget_bytes`` of the backlog into it and flush (slices keep the event loop, and
        so the serial reader, going while a large backlog drains). A failure abandons the
        pair at its last good chunk boundary and waits for the next retry."""
        assert self._failure is not None
        self._next_retry_ns = now_ns + self.retry_interval_ns
        if self._mcap is None:
            try:
                self._open_file(now_ns, after_failure=f"{self._failure.strerror or self._failure}")
            except OSError as err:
                log.debug("recording still failing: %s", err)
                return
            self._pair_empty_size = self._mcap_good
        mcap = self._mcap
        assert mcap is not None
        budget = budget_bytes
        try:
            while self._backlog and (budget is None or budget > 0):
                msg = self._backlog.pop()
                self._drained_bytes += len(msg[1])
                if budget is not None:
                    budget -= cost(msg)
                self._put(msg)
            mcap.flush()
        except OSError as err:
            log.debug("recording still failing: %s", err)
            self._drained_bytes -= sum(len(m[1]) for m in mcap.unsettled())
            self._fail(err)
            return
        self._mark_flushed(now_ns)
        if self._backlog:
            self._next_retry_ns = now_ns  # the next slice at the next call
            return
        held, self._drained_bytes = self._drained_bytes, 0
        backlog = self._backlog
        backlog.records_off = False
        self._failure = None
        if backlog.dropped_any:
            backlog.report_drops(force=True)
        text = (f"recording resumed in {mcap.path.name}: {held} bytes held in memory written"
                + (f"; {backlog.dropped_bytes} raw bytes and {backlog.dropped_records} records "
                   "were dropped" if backlog.dropped_bytes or backlog.dropped_records else ""))
        log.warning("%s", text)
        self._notices.append(Event(
            "recorder.recovered", now_ns, text, "warning",
            {"file": str(mcap.path), "held_bytes": held, **backlog.drop_counts()},
        ))

    # -- vanished files -------------------------------------------------------------------------

    def _vanished(self) -> str:
        """Why the current pair is no longer at its paths, or ``""`` while it is."""
        for path, ident in self._idents:
            try:
                now_there = _ident(path)
            except (FileNotFoundError, NotADirectoryError):
                gone = not self.out_dir.is_dir()
                return (f"{self.out_dir} was deleted or moved" if gone
                        else f"{path.name} was deleted or moved")
            except OSError as err:  # cannot tell (e.g. no search permission): keep writing
                log.debug("cannot check %s: %s", path, err)
                continue
            if now_there != ident:
                return f"{path.name} was replaced by another file"
        return ""

    def _pair_gone(self, now: int) -> bool:
        """Check the current pair (module docstring); if it vanished, continue in a new part
        (or hold the data if none can be created) and return True."""
        why = self._vanished()
        if not why:
            return False
        mcap, ubx = self._mcap, self._ubx
        assert mcap is not None
        pending = mcap.unsettled()
        ours = {path for path, ident in self._idents if _still(path, ident)}
        # What is still ours (a sidecar deleted beside its MCAP) is cut back to its last good
        # boundary as after a write failure, so the pending messages are not there twice.
        if mcap.path in ours:
            mcap.abandon(self._mcap_good)
        else:
            mcap.forsake()
        if ubx is not None:
            with contextlib.suppress(OSError):
                if ubx.path in ours:
                    ubx.truncate(self._side_good)
            with contextlib.suppress(OSError):
                ubx.close()
        self._mcap = self._ubx = None
        self._idents = []
        lost = self._mark_lost()
        self._backlog.push_front(pending)
        self._failure = FileNotFoundError(errno.ENOENT, why)
        try:
            self._open_file(now, after_failure=why)
            err: OSError | None = None
            then = f"continuing in a new part in {self.out_dir}"
        except OSError as e:  # the directory cannot be made again: hold and retry
            err = e
            then = f"cannot make {self.out_dir} again ({e.strerror or e}): holding the data"
        self._say_vanished(why, lost, then, mcap.path, now)
        if err is not None:  # the write-failure machine from here on
            self._failure = err
            self._failures += 1
            self._next_retry_ns = now + self.retry_interval_ns
            self._report_failure(err, self.out_dir, now)
            return True
        self._recover(now)  # the pending messages first, into the new part
        return True

    def _mark_lost(self) -> list[Path]:
        """Move the session's files that no longer exist to the lost ones; the newly lost."""
        lost = [p for p in (*self._files, *self._sidecars)
                if p not in self._lost and (self._mcap is None or p != self._mcap.path)
                and (self._ubx is None or p != self._ubx.path) and not p.exists()]
        self._lost.update(dict.fromkeys(lost))
        return lost

    def take_notices(self) -> list[Event]:
        """Events about the recording itself (write failed, dropped, recovered) since the
        last call, for the sink to publish."""
        out = list(self._notices)
        self._notices.clear()  # in place: the backlog appends to this list too
        return out

    @property
    def failing(self) -> bool:
        """Writing currently fails and data is being held in memory."""
        return self._failure is not None

    # -- flushing -------------------------------------------------------------------------------

    def flush(self) -> None:
        """Close the MCAP chunk in progress and flush MCAP and sidecar to the OS."""
        if self._failure is not None or self._mcap is None:
            return
        try:
            self._mcap.flush()
            if self._ubx is not None:
                self._ubx.flush()
        except OSError as err:
            self._fail(err)
            return
        now = self._now()
        if self._pair_gone(now):  # what was just written went nowhere: it is still pending
            return
        self._mark_flushed(now)

    def _mark_flushed(self, now_ns: int) -> None:
        assert self._mcap is not None
        if self._mcap.messages != self._msgs_at_flush:  # this flush closed a chunk
            self._file_chunks += 1
            self._msgs_at_flush = self._mcap.messages
        self._mcap_good = self._mcap.size_bytes
        self._side_good = self._ubx.tell() if self._ubx is not None else 0
        self._mcap.settle()
        self._last_flush_ns = now_ns
        self._flushes += 1
        self._set_limits()

    def maybe_flush(self) -> bool:
        """Flush if the flush interval has passed (after a failure: retry writing when the
        retry interval has passed); True if it flushed."""
        now = self._now()
        if self._failure is not None:
            if now >= self._next_retry_ns and not self._closed:
                self._recover(now)
            return False
        if now - self._last_flush_ns >= self.flush_interval_ns:
            self.flush()
            return self._failure is None
        return False

    @property
    def file_count(self) -> int:
        """How many MCAP files the session has (cheap: checked after every chunk)."""
        return len(self._files)

    @property
    def current_file(self) -> Path | None:
        return self._files[-1] if self._files else None

    @property
    def created_files(self) -> tuple[Path, ...]:
        """Every MCAP part created, in order, lost ones included (what was announced)."""
        return tuple(self._files)

    @property
    def stats(self) -> RecorderStats:
        lost = self._lost
        return RecorderStats(
            self.session_id, tuple(p for p in self._files if p not in lost),
            tuple(p for p in self._sidecars if p not in lost), self._raw_chunks,
            self._raw_bytes, self._records, self._events, self._flushes, self._failures,
            self._backlog.bytes, self._backlog.dropped_chunks, self._backlog.dropped_bytes,
            self._backlog.dropped_records, tuple(lost),
        )


def _ident(path: Path) -> tuple[int, int]:
    st = os.stat(path)
    return st.st_dev, st.st_ino


def _still(path: Path, ident: tuple[int, int]) -> bool:
    """Whether ``path`` still names the file created as ``ident``."""
    try:
        return _ident(path) == ident
    except OSError:
        return False
