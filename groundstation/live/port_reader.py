"""A serial port read by a thread of its own, handing the event loop batches of reads.

Why a thread: at 115 200 baud a tty delivers a few dozen bytes every few milliseconds. Read on
the event loop, each read is a pass through the whole loop (epoll, timers, the tasks it wakes),
and at ~94 passes a second those passes, not the work they carry, were most of the daemon's CPU
(``benchmarks/RESULTS.md``, "Daemon CPU at 115 200 baud"). A thread that sleeps
:data:`COALESCE_S` between reads costs far less per wake-up, and it wakes the loop only:

- at once when the bytes it holds complete a TIM-TM2 frame (a camera mark: the subscribers'
  latency limit is issue 5's p99 < 20 ms), or
- when the oldest bytes it holds are :data:`BATCH_S` old, whether more bytes came meanwhile or
  the line went quiet (the recorder and the monitor take bursts of 100 ms anyway), or
- when the device fails (the error is handed over with the bytes read before it).

Each read keeps its own host time; the loop side gets the reads as they were, in order. Nothing
is framed here (the framer stays on the loop, one decode path): a mark is recognised by its
header bytes ``B5 62 0D 03`` and length alone, and a false match only costs an early wake-up.
"""

from __future__ import annotations

import asyncio
import os
import select
import threading
import time
from collections.abc import Callable

from groundstation.ubx import layouts as L

COALESCE_S = 0.01
"""After a short read, let the port gather bytes this long before reading again (one read per
10 ms instead of one per tty delivery); a mark's bytes wait at most this long in the kernel."""

BATCH_S = 0.1
"""Without a mark, the loop is woken once the oldest bytes held are this old."""

_MARK_HEADER = bytes((0xB5, 0x62, *L.TIM_TM2.key))
_MARK_FRAME_LEN = L.TIM_TM2.head.size + 8  # sync(2) + class, id, length(4) + checksum(2)

Chunk = tuple[bytes, int]


class DeviceVanished(Exception):
    """The device failed or vanished (the message says how); the source reconnects."""


class MarkWatch:
    """Says when the bytes read so far complete a TIM-TM2 frame, however they were cut.

    Only the header and the fixed length are looked at (no checksum): a false match costs an
    early wake-up, a missed one up to :data:`BATCH_S` of a mark's latency."""

    def __init__(self) -> None:
        self._offset = 0  # bytes seen so far
        self._tail = b""  # the last bytes seen, for a header cut between two reads
        self._mark_end = -1  # stream offset at which a mark's frame is complete (-1: none)

    def feed(self, data: bytes) -> bool:
        """Add a read; True when a mark's frame is complete with it."""
        seen = self._tail + data
        at = seen.rfind(_MARK_HEADER)
        if at >= 0:
            self._mark_end = self._offset - len(self._tail) + at + _MARK_FRAME_LEN
        self._offset += len(data)
        self._tail = seen[-(len(_MARK_HEADER) - 1):]
        if 0 <= self._mark_end <= self._offset:
            self._mark_end = -1
            return True
        return False


class PortReader:
    """Reads an open, non-blocking serial fd in a daemon thread (see the module docstring).

    Args:
        fd: the port's file descriptor (non-blocking); it stays the caller's to close, after
            :meth:`stop`.
        read_size: the largest single read.
        clock: UNIX ns clock for each read's host time.
        idle_check: called every ``stall_check_s`` of silence and every ``repoint_check_s``
            while bytes flow; raises :class:`DeviceVanished` when the device is gone or the path
            now names another one.
        stall_check_s: longest wait for bytes before ``idle_check``.
        repoint_check_s: while bytes flow, the interval of ``idle_check``.
    """

    def __init__(
        self,
        fd: int,
        *,
        read_size: int,
        clock: Callable[[], int],
        idle_check: Callable[[], None],
        stall_check_s: float,
        repoint_check_s: float,
    ) -> None:
        self._fd = fd
        self._read_size = read_size
        self._clock = clock
        self._idle_check = idle_check
        self._stall_s = stall_check_s
        self._repoint_s = repoint_check_s
        self._lock = threading.Lock()
        self._held: list[Chunk] = []
        self._held_since = 0.0  # monotonic time of the oldest read held (0: none)
        self._error: DeviceVanished | None = None
        self._woken = False  # a wake-up of the loop is on its way
        self._stop_r, self._stop_w = os.pipe()
        self._stopping = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready: asyncio.Event | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start reading; batches are announced to the running event loop."""
        self._loop = asyncio.get_running_loop()
        self._ready = asyncio.Event()
        self._thread = threading.Thread(target=self._run, name="serial-reader", daemon=True)
        self._thread.start()

    def stop(self) -> list[Chunk]:
        """Stop the thread and return the reads not yet taken (with what the port held).

        Blocks the caller for at most one pause (:data:`COALESCE_S`): the thread is woken at
        once when it waits for bytes."""
        self._stopping = True
        os.write(self._stop_w, b"x")
        if self._thread is not None:
            self._thread.join()
        os.close(self._stop_r)
        os.close(self._stop_w)
        with self._lock:
            held, self._held = self._held, []
        return held

    async def batch(self) -> list[Chunk]:
        """The reads held, oldest first, once the thread says they are due.

        Raises:
            DeviceVanished: the device failed; the reads before the failure were returned by the
                calls before this one.
        """
        assert self._ready is not None
        while True:
            if self._error is None:  # after a failure, nothing more will be announced
                await self._ready.wait()
                self._ready.clear()
            with self._lock:
                held, self._held = self._held, []
                self._held_since = 0.0
                self._woken = False
                error = self._error
            if held:
                return held
            if error is not None:
                raise error

    # -- the thread ----------------------------------------------------------------------------

    def _wake(self) -> None:
        """On the loop: the thread has something."""
        assert self._ready is not None
        self._ready.set()

    def _announce(self) -> None:
        """Wake the loop once for everything held now (the lock is held by the caller)."""
        if not self._woken and self._loop is not None:
            self._woken = True
            try:
                self._loop.call_soon_threadsafe(self._wake)
            except RuntimeError:
                self._stopping = True  # the loop is closed: nobody is waiting any more

    def _fail(self, err: DeviceVanished) -> None:
        with self._lock:
            self._error = err
            self._announce()

    def _read(self, fd: int) -> bytes:
        """What is waiting, without blocking (empty: nothing; pyserial's port returns at once
        with VMIN 0, so an empty read means end of file only after select said readable)."""
        try:
            return os.read(fd, self._read_size)
        except BlockingIOError:
            return b""
        except OSError as err:
            raise DeviceVanished(f"{os.strerror(err.errno or 0)} (errno {err.errno})") from err

    def _run(self) -> None:
        fd = self._fd
        marks = MarkWatch()
        next_check = time.monotonic() + self._repoint_s
        quiet_since = time.monotonic()  # when the last bytes came
        try:
            while not self._stopping:
                data = self._read(fd)  # after the pause, bytes are usually waiting
                if not data:
                    # A pause in the flow: wait for bytes, but no longer than until what is
                    # held is due (then it is handed over) or the stall check.
                    now = time.monotonic()
                    with self._lock:
                        due = (self._held_since + BATCH_S if self._held and not self._woken
                               else None)
                    wait = self._stall_s if due is None else max(0.0, min(due - now,
                                                                           self._stall_s))
                    ready, _, _ = select.select([fd, self._stop_r], [], [], wait)
                    if self._stop_r in ready:
                        break
                    if not ready:
                        now = time.monotonic()
                        if due is not None and now >= due:
                            with self._lock:
                                self._announce()
                        if now - quiet_since >= self._stall_s:
                            quiet_since = now
                            next_check = now + self._repoint_s
                            self._idle_check()  # a quiet line: is the device still there?
                        continue
                    data = self._read(fd)
                    if not data:  # readable yet empty: the other end of the tty hung up
                        raise DeviceVanished("end of file on the device (hung up)")
                t = self._clock()
                now = quiet_since = time.monotonic()
                mark = marks.feed(data)
                with self._lock:
                    if not self._held:
                        self._held_since = now
                    self._held.append((data, t))
                    if mark or now - self._held_since >= BATCH_S:
                        self._announce()
                if now >= next_check:
                    next_check = now + self._repoint_s
                    self._idle_check()
                if len(data) < self._read_size:
                    time.sleep(COALESCE_S)
            # Stopping: what the port holds now was received before the stop; keep it.
            while data := self._read(fd):
                with self._lock:
                    self._held.append((data, self._clock()))
        except DeviceVanished as err:
            self._fail(err)
        except Exception as err:  # never die silently: the loop side reconnects
            self._fail(DeviceVanished(f"serial reader failed: {err!r}"))
