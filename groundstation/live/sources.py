"""Byte sources yielding ``(chunk, t_host_ns)``: serial device, TCP client and .ubx file.

A device source never ends because its device went away: it reports the loss as an event,
reconnects with jittered exponential backoff and, once back, reports the outage with its start,
end and duration. A serial device that vanishes (EIO, ENODEV, end of file on the tty, the device
node removed) is noticed within ``stall_check_s``.

A serial port is opened exclusively (``flock``, through pyserial's ``exclusive=True``), so two
daemons never read the same radio (each would get a random half of the bytes). A port another
process holds when the daemon starts is refused at once (:meth:`SerialSource.claim` raises
:class:`~groundstation.errors.SourceError`, the command exits with status 1) before any
recording file is created; if another process grabs the port while the daemon is waiting for
an unplugged device, the daemon reports it and keeps retrying, so the session is not lost.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import gzip
import logging
import os
import random
import time
from collections.abc import AsyncIterator, Callable
from typing import IO, Protocol

import serial

from groundstation.config import (
    FileSourceSettings,
    SerialSourceSettings,
    SourceSettings,
    TcpSourceSettings,
)
from groundstation.errors import InputError, SourceError
from groundstation.records import Event

EventSink = Callable[[Event], None]


class Source(Protocol):
    """Anything that yields ``(chunk, t_host_ns)``.

    ``can_wait`` says whether the source may be paused when a never-dropping sink falls
    behind (a file can wait; a radio cannot, its bytes would be lost). A source may also
    offer ``claim()``, which the pipeline calls before it creates any file: it takes what the
    source needs exclusively and raises :class:`~groundstation.errors.SourceError` when that
    is impossible (a serial port held by another daemon).
    """

    @property
    def name(self) -> str: ...

    @property
    def can_wait(self) -> bool: ...

    def chunks(self) -> AsyncIterator[tuple[bytes, int]]: ...


class DeviceVanished(Exception):
    """The device went away; the source reconnects."""


class PortInUse(Exception):
    """Another process holds the serial port (its exclusive lock)."""


def lock_holder(path: str) -> int | None:
    """The pid holding a ``flock`` on ``path`` (from ``/proc/locks``), if it can be told."""
    try:
        st = os.stat(path)
        with open("/proc/locks", encoding="ascii") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    want = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in lines:
        parts = line.split()
        # "1: FLOCK  ADVISORY  WRITE 4242 00:1a:3 0 EOF" (blocked waiters carry a "->")
        if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == want:
            with contextlib.suppress(ValueError):
                return int(parts[4])
    return None


def backoff_delay_s(attempt: int, min_s: float, max_s: float, rand: Callable[[], float]) -> float:
    """Exponential backoff with "equal jitter": half fixed, half random, capped at ``max_s``."""
    base = min(max_s, min_s * (2.0 ** min(attempt, 30)))
    return base / 2 + base / 2 * rand()


class _Reconnecting:
    """Outage bookkeeping shared by the serial and TCP sources."""

    def __init__(
        self, name: str, logger: logging.Logger, on_event: EventSink,
        clock: Callable[[], int], rand: Callable[[], float],
    ) -> None:
        self.name = name
        self._log = logger
        self._on_event = on_event
        self._clock = clock
        self._rand = rand
        self.connected = False
        self.outages = 0
        self.connects = 0
        self._outage_start_ns: int | None = None
        self._outage_reason = ""
        self._attempts = 0

    def lost(self, reason: str) -> None:
        now = self._clock()
        self.connected = False
        if self._outage_start_ns is None:
            self._outage_start_ns = now
            self._outage_reason = reason
            self._attempts = 0
            self._log.warning("%s: lost: %s", self.name, reason)
            self._on_event(Event(
                "source.lost", now, f"{self.name}: {reason}", "warning",
                {"source": self.name, "reason": reason, "start_ns": now},
            ))

    def up(self) -> None:
        now = self._clock()
        self.connected = True
        self.connects += 1
        start = self._outage_start_ns
        if start is not None:
            self.outages += 1
            duration_s = (now - start) / 1e9
            self._log.warning("%s: back after %.3f s (%d attempts)", self.name, duration_s,
                              self._attempts)
            self._on_event(Event(
                "source.outage", now,
                f"{self.name}: outage of {duration_s:.3f} s ({self._outage_reason})", "warning",
                {"source": self.name, "start_ns": start, "end_ns": now,
                 "duration_s": duration_s, "reason": self._outage_reason,
                 "attempts": self._attempts},
            ))
            self._outage_start_ns = None
        else:
            self._log.info("%s: connected", self.name)
            self._on_event(Event("source.connected", now, f"{self.name}: connected", "info",
                                 {"source": self.name}))

    async def wait_before_retry(self, min_s: float, max_s: float) -> None:
        delay = backoff_delay_s(self._attempts, min_s, max_s, self._rand)
        self._attempts += 1
        await asyncio.sleep(delay)


COALESCE_S = 0.01
"""After a short read, let the port gather bytes this long before reading again: at 115 200
baud a USB adapter or a pty delivers a few dozen bytes every few milliseconds, and one read
(and one pass through the pipeline) per 20 ms instead of per delivery is what keeps the
daemon's CPU near 3 % of a core; 20 ms is far below anything the monitor or a subscriber
notices, and the kernel's tty buffer holds it even at 921 600 baud."""

class SerialSource:
    """A serial port (8N1) read without blocking the event loop (``loop.add_reader``).

    Args:
        settings: port, baud, read size, backoff and stall-check interval.
        on_event: receives ``source.connected``, ``source.lost`` and ``source.outage``.
        clock: UNIX ns clock for ``t_host_ns`` and events.
        rand: uniform [0, 1) for the backoff jitter.
    """

    can_wait = False

    def __init__(
        self,
        settings: SerialSourceSettings,
        on_event: EventSink,
        *,
        clock: Callable[[], int] = time.time_ns,
        rand: Callable[[], float] = random.random,
    ) -> None:
        self.settings = settings
        self.name = f"serial:{settings.port}"
        self._clock = clock
        self._log = logging.getLogger("groundstation.serial")
        self.state = _Reconnecting(self.name, self._log, on_event, clock, rand)
        self._claimed: serial.Serial | None = None

    def _open(self) -> serial.Serial:
        s = self.settings
        try:
            port = serial.Serial(
                s.port, s.baud, bytesize=serial.EIGHTBITS, parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE, timeout=0, xonxoff=False, rtscts=False,
                exclusive=True,
            )
        except serial.SerialException as err:
            if err.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                pid = lock_holder(s.port)
                by = f"process {pid}" if pid is not None else "another process"
                raise PortInUse(f"{s.port} is in use by {by} (it holds the port's exclusive "
                                "lock: is another groundstation daemon running on it?)") from err
            raise
        os.set_blocking(port.fileno(), False)
        return port

    def claim(self) -> None:
        """Open the port now if it is there, exclusively, and keep it for :meth:`chunks`.

        A missing device is not an error (the source waits for it to be plugged in).

        Raises:
            SourceError: another process holds the port.
        """
        if self._claimed is not None or not os.path.exists(self.settings.port):
            return
        try:
            self._claimed = self._open()
        except PortInUse as err:
            raise SourceError(f"refusing to start: {err}") from err
        except (serial.SerialException, OSError, ValueError) as err:
            self._log.debug("claim of %s: %s (retried by the source)", self.settings.port, err)

    async def _read(self, fd: int) -> bytes:
        """One read as soon as the fd is readable; raises DeviceVanished on loss."""
        loop = asyncio.get_running_loop()
        s = self.settings
        try:  # after the coalescing pause bytes are usually waiting: no readiness round trip
            data = os.read(fd, s.read_size_bytes)
        except BlockingIOError:
            pass
        except OSError as err:
            raise DeviceVanished(f"{os.strerror(err.errno or 0)} (errno {err.errno})") from err
        else:
            if data:
                return data  # (end of file is reported by the path below)
        while True:
            fut: asyncio.Future[bytes] = loop.create_future()

            def readable(fut: asyncio.Future[bytes] = fut) -> None:
                if fut.done():
                    return
                try:
                    fut.set_result(os.read(fd, s.read_size_bytes))
                except BlockingIOError:
                    return  # woken with nothing to read: wait for the next readiness
                except OSError as err:
                    fut.set_exception(err)

            loop.add_reader(fd, readable)
            try:
                async with asyncio.timeout(s.stall_check_s):
                    data = await fut
            except TimeoutError:
                # Quiet line: fine, unless the device node is gone (USB unplugged).
                if not os.path.exists(s.port):
                    raise DeviceVanished(f"{s.port} no longer exists") from None
                continue
            except OSError as err:
                raise DeviceVanished(f"{os.strerror(err.errno or 0)} (errno {err.errno})") \
                    from err
            finally:
                loop.remove_reader(fd)
            if not data:  # a tty whose other end hung up reads as end of file
                raise DeviceVanished("end of file on the device (hung up)")
            return data

    async def chunks(self) -> AsyncIterator[tuple[bytes, int]]:
        s = self.settings
        while True:
            try:
                port, self._claimed = self._claimed or self._open(), None
            except PortInUse as err:
                if not self.state.connects:
                    raise SourceError(f"refusing to start: {err}") from err
                self.state.lost(str(err))  # grabbed while our device was away: keep trying
                await self.state.wait_before_retry(s.reconnect_min_s, s.reconnect_max_s)
                continue
            except (serial.SerialException, OSError, ValueError) as err:
                self.state.lost(f"cannot open: {err}")
                await self.state.wait_before_retry(s.reconnect_min_s, s.reconnect_max_s)
                continue
            self.state.up()
            try:
                fd = port.fileno()
                while True:
                    data = await self._read(fd)
                    yield data, self._clock()
                    if len(data) < s.read_size_bytes:
                        await asyncio.sleep(COALESCE_S)
            except DeviceVanished as err:
                self.state.lost(str(err))
            finally:
                with contextlib.suppress(Exception):
                    port.close()
            await self.state.wait_before_retry(s.reconnect_min_s, s.reconnect_max_s)


class TcpSource:
    """A TCP client (RTKLIB ``str2str`` or u-center's server), reconnecting."""

    can_wait = False

    def __init__(
        self,
        settings: TcpSourceSettings,
        on_event: EventSink,
        *,
        clock: Callable[[], int] = time.time_ns,
        rand: Callable[[], float] = random.random,
    ) -> None:
        self.settings = settings
        self.name = f"tcp:{settings.host}:{settings.port}"
        self._clock = clock
        self.state = _Reconnecting(self.name, logging.getLogger("groundstation.tcp"),
                                   on_event, clock, rand)

    async def chunks(self) -> AsyncIterator[tuple[bytes, int]]:
        s = self.settings
        while True:
            try:
                async with asyncio.timeout(s.connect_timeout_s):
                    reader, writer = await asyncio.open_connection(s.host, s.port)
            except (OSError, TimeoutError) as err:
                self.state.lost(f"cannot connect: {err or type(err).__name__}")
                await self.state.wait_before_retry(s.reconnect_min_s, s.reconnect_max_s)
                continue
            self.state.up()
            try:
                while True:
                    try:
                        data = await reader.read(s.read_size_bytes)
                    except OSError as err:
                        self.state.lost(f"connection error: {err}")
                        break
                    if not data:
                        self.state.lost("connection closed by the server")
                        break
                    yield data, self._clock()
            finally:
                writer.close()
                with contextlib.suppress(Exception):
                    await writer.wait_closed()
            await self.state.wait_before_retry(s.reconnect_min_s, s.reconnect_max_s)


class FileSource:
    """A ``.ubx`` or ``.ubx.gz`` file, paced at ``rate_bytes_per_s`` or as fast as possible.

    Raises:
        InputError: when the file cannot be opened.
    """

    can_wait = True

    def __init__(
        self,
        settings: FileSourceSettings,
        on_event: EventSink | None = None,
        *,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.settings = settings
        self.name = f"file:{settings.path}"
        self._clock = clock
        self.bytes_read = 0

    def _open(self) -> IO[bytes]:
        path = self.settings.path
        try:
            if path.suffix == ".gz":
                return gzip.open(path, "rb")  # type: ignore[return-value]
            return path.open("rb")
        except OSError as err:
            raise InputError(f"cannot open {path}: {err}") from err

    async def chunks(self) -> AsyncIterator[tuple[bytes, int]]:
        s = self.settings
        rate = s.rate_bytes_per_s
        with self._open() as f:
            t0 = time.monotonic()
            while True:
                try:
                    data = f.read(s.read_size_bytes)
                except (OSError, EOFError) as err:
                    raise InputError(f"reading {s.path}: {err}") from err
                if not data:
                    return
                if rate > 0:
                    due = t0 + (self.bytes_read + len(data)) / rate
                    delay = due - time.monotonic()
                    if delay > 0:
                        await asyncio.sleep(delay)
                else:
                    await asyncio.sleep(0)  # let the sinks run between chunks
                self.bytes_read += len(data)
                yield data, self._clock()


def make_source(
    settings: SourceSettings, on_event: EventSink, *, clock: Callable[[], int] = time.time_ns
) -> Source:
    """The source for a configured source kind."""
    if isinstance(settings, SerialSourceSettings):
        return SerialSource(settings, on_event, clock=clock)
    if isinstance(settings, TcpSourceSettings):
        return TcpSource(settings, on_event, clock=clock)
    return FileSource(settings, on_event, clock=clock)
