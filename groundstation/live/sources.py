"""Byte sources yielding ``(chunk, t_host_ns)``: serial device, TCP client and recording file.

A device source never ends because its device went away: it reports the loss as an event,
reconnects with jittered exponential backoff and, once back, reports the outage with its start,
end and duration. A serial device that vanishes (EIO, ENODEV, end of file on the tty, the device
node removed) is noticed within ``stall_check_s``. So is a device path re-pointed to another
device while the old one stays open (a udev symlink such as ``/dev/radio`` moved to a new
adapter): the path's device and inode are compared with the open descriptor's every
``stall_check_s`` (at most every :data:`REPOINT_CHECK_S` while data flows), and on a
difference the source reopens the path.

A serial port is opened exclusively (``flock``, :func:`groundstation.serialport.open_port`), so two
daemons never read the same radio (each would get a random half of the bytes). A port another
process holds when the daemon starts is refused at once (:meth:`SerialSource.claim` raises
:class:`~groundstation.errors.SourceError`, the command exits with status 1) before any
recording file is created; if another process grabs the port while the daemon is waiting for
an unplugged device, the daemon reports it and keeps retrying, so the session is not lost.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import os
import random
import stat
import time
from collections.abc import AsyncIterator, Callable
from typing import Protocol

from groundstation import events as kinds
from groundstation.config import (
    FileSourceSettings,
    SerialSourceSettings,
    SourceSettings,
    TcpSourceSettings,
)
from groundstation.errors import ConfigError, SourceError
from groundstation.live.data_time import UNTIMED, DataClock
from groundstation.live.port_reader import DeviceVanished, PortReader
from groundstation.pacing import LINK_BYTES_PER_S, Pacer, link_time_ns
from groundstation.records import Event
from groundstation.serialport import Port, PortInUse, is_terminal, open_port
from groundstation.storage.reading import Recording

EventSink = Callable[[Event], None]
REPOINT_CHECK_S = 1.0
"""While bytes flow, how often the serial source checks that its path still names the open
device (a quiet line is checked every ``stall_check_s``)."""


class Source(Protocol):
    """Anything that yields ``(chunk, t_host_ns)``.

    ``can_wait`` says whether the source may be paused when a never-dropping sink falls
    behind (a file can wait; a radio cannot, its bytes would be lost). A source may also
    offer ``claim()``, which the pipeline calls before it creates any file: it takes what the
    source needs exclusively and raises :class:`~groundstation.errors.SourceError` when that
    is impossible (a serial port held by another daemon); and ``drain()``, which the pipeline
    calls once the source stopped: the ``(chunk, t_host_ns)`` it had read but not yet yielded
    (the serial source's reader thread holds up to 100 ms of reads).
    """

    @property
    def name(self) -> str: ...

    @property
    def can_wait(self) -> bool: ...

    def chunks(self) -> AsyncIterator[tuple[bytes, int]]: ...


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
                kinds.SOURCE_LOST, now, f"{self.name}: {reason}", "warning",
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
                kinds.SOURCE_OUTAGE, now,
                f"{self.name}: outage of {duration_s:.3f} s ({self._outage_reason})", "warning",
                {"source": self.name, "start_ns": start, "end_ns": now,
                 "duration_s": duration_s, "reason": self._outage_reason,
                 "attempts": self._attempts},
            ))
            self._outage_start_ns = None
        else:
            self._log.info("%s: connected", self.name)
            self._on_event(Event(kinds.SOURCE_CONNECTED, now, f"{self.name}: connected", "info",
                                 {"source": self.name}))

    async def wait_before_retry(self, min_s: float, max_s: float) -> None:
        delay = backoff_delay_s(self._attempts, min_s, max_s, self._rand)
        self._attempts += 1
        await asyncio.sleep(delay)


class SerialSource:
    """A serial port (8N1), read by a thread of its own that hands the event loop batches of
    reads (:class:`~groundstation.live.port_reader.PortReader`: a mark at once, the rest every
    100 ms).

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
        self._claimed: Port | None = None
        self._leftover: list[tuple[bytes, int]] = []

    def _open(self) -> Port:
        port = open_port(self.settings.port, self.settings.baud, timeout_s=0)
        os.set_blocking(port.fileno(), False)
        return port

    def claim(self) -> None:
        """Open the port now if it is there, exclusively, and keep it for :meth:`chunks`.

        A missing device is not an error (the source waits for it to be plugged in).

        Raises:
            SourceError: another process holds the port.
            ConfigError: the path exists but is not a serial device: a file, a FIFO or a
                directory named by mistake, or a character device without a terminal interface
                such as ``/dev/null`` (exit status 2).
        """
        if self._claimed is not None or not os.path.exists(self.settings.port):
            return
        mode = os.stat(self.settings.port).st_mode
        if not stat.S_ISCHR(mode):
            what = ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
                    else "a regular file (use --file for a recording)" if stat.S_ISREG(mode)
                    else "not a device")
            raise ConfigError("source.port", f"{self.settings.port} is {what}, not a serial "
                                             "device")
        if not is_terminal(self.settings.port):  # /dev/null: pyserial's open would fail
            raise ConfigError("source.port", f"{self.settings.port} is a character device "
                              "without a terminal interface, not a serial port")
        try:
            self._claimed = self._open()
        except PortInUse as err:
            raise SourceError(f"refusing to start: {err}") from err
        except OSError as err:
            self._log.debug("claim of %s: %s (retried by the source)", self.settings.port, err)

    def _check_same_device(self, fd: int) -> None:
        """Raise DeviceVanished when the port's path now names another device than ``fd``
        (a missing path is left to the callers: the node-removed rule)."""
        try:
            now = os.stat(self.settings.port)
        except OSError:
            return
        held = os.fstat(fd)
        if (now.st_rdev, now.st_ino, now.st_dev) != (held.st_rdev, held.st_ino, held.st_dev):
            raise DeviceVanished(f"{self.settings.port} now names another device "
                                 f"(rdev {now.st_rdev:#x}, was {held.st_rdev:#x}): reopening")

    def _idle_check(self, fd: int) -> None:
        """On the reader thread: raise DeviceVanished when the device node is gone (USB
        unplugged) or the path now names another device."""
        if not os.path.exists(self.settings.port):
            raise DeviceVanished(f"{self.settings.port} no longer exists")
        self._check_same_device(fd)

    def drain(self) -> list[tuple[bytes, int]]:
        """The reads the thread made but the pipeline has not taken, once the source stopped
        (the pipeline ingests them before it flushes the framer)."""
        held, self._leftover = self._leftover, []
        return held

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
            except OSError as err:
                self.state.lost(f"cannot open: {err}")
                await self.state.wait_before_retry(s.reconnect_min_s, s.reconnect_max_s)
                continue
            self.state.up()
            fd = port.fileno()
            reader = PortReader(
                fd, read_size=s.read_size_bytes, clock=self._clock,
                idle_check=functools.partial(self._idle_check, fd), stall_check_s=s.stall_check_s,
                repoint_check_s=REPOINT_CHECK_S,
            )
            reader.start()
            held: list[tuple[bytes, int]] = []
            try:
                while True:
                    held = await reader.batch()
                    while held:
                        yield held.pop(0)
            except DeviceVanished as err:
                self.state.lost(str(err))
            finally:  # what was read is never lost: the pipeline takes it through drain()
                self._leftover.extend(held)
                self._leftover.extend(reader.stop())
                with contextlib.suppress(Exception):
                    port.close()
            while self._leftover:  # the device went away: what was read before still counts
                yield self._leftover.pop(0)
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
    """A recording read as if it arrived now: ``.ubx``, ``.ubx.gz`` or ``.mcap`` (finished or
    not), told apart by content, with the later parts of its session followed
    (:mod:`groundstation.storage.reading`).

    Times: an MCAP's chunks keep their recorded host times (its ``/ubx/raw`` ``log_time``), so
    the monitor reaches what the live daemon saw; a file without times (``.ubx``) yields its
    chunks :data:`~groundstation.live.data_time.UNTIMED`, and the pipeline gives them the data's
    own time with :attr:`data_clock` from its own frames (the UTC of the latest measurement
    epoch; without epochs, the times a link would have delivered the bytes at:
    ``rate_bytes_per_s``, or 115 200 baud, from the moment reading starts). The pipeline runs
    its monitor on these times, not the wall clock.

    Pacing (:class:`~groundstation.pacing.Pacer`): ``rate_bytes_per_s`` > 0 paces the bytes at
    that rate (whatever the format); otherwise ``speed`` paces the chunks' times (1: as
    recorded, N: N times faster; the pipeline paces untimed chunks once timed, with
    :meth:`untimed_delay_s`: one pacer); with neither, as fast as the sinks take it.

    Args:
        settings: path, rate and read size (the chunk size of files without recorded chunks).
        on_event: unused (a file has no outages); accepted like every source.
        clock: UNIX ns clock (the start of the synthetic link times).
        speed: pace on the chunks' times at this multiple of real time (``None``: no pacing).

    Raises:
        InputError: when the file is missing or cannot be read.
    """

    can_wait = True

    def __init__(
        self,
        settings: FileSourceSettings,
        on_event: EventSink | None = None,
        *,
        clock: Callable[[], int] = time.time_ns,
        speed: float | None = None,
    ) -> None:
        self.settings = settings
        self.name = f"file:{settings.path}"
        self._clock = clock
        self.speed = speed
        self.bytes_read = 0
        self.chunks_out = 0
        self._pacer = Pacer(speed)
        self.data_clock: DataClock | None = None
        """How the pipeline times this file's :data:`UNTIMED` chunks (set when reading starts)."""

    def claim(self) -> None:
        """Check the recording before any file is created (missing, a directory, a FIFO or a
        device such as ``/dev/zero`` is refused: one line, exit status 2).

        Raises:
            InputError: the file cannot be used.
        """
        Recording(self.settings.path)

    async def chunks(self) -> AsyncIterator[tuple[bytes, int]]:
        s = self.settings
        recording = Recording(s.path)
        rate = s.rate_bytes_per_s
        self._pacer = Pacer(1.0 if rate > 0 else self.speed)
        self.data_clock = DataClock(
            self._clock(), rate if rate > 0 else LINK_BYTES_PER_S)
        for data, t_host in recording.chunks(s.read_size_bytes):
            if rate > 0:
                delay = self._pacer.delay_s(link_time_ns(0, self.bytes_read, rate))
            else:  # an untimed chunk is paced by the pipeline once it is timed
                delay = self._pacer.delay_s(t_host) if t_host != UNTIMED else 0.0
            # sleep(0) lets the sinks run between chunks when reading as fast as possible
            await asyncio.sleep(delay)
            self.bytes_read += len(data)
            self.chunks_out += 1
            yield data, t_host

    def untimed_delay_s(self, t_ns: int) -> float:
        """How long the pipeline waits before a chunk it timed with :attr:`data_clock`."""
        return 0.0 if self.settings.rate_bytes_per_s > 0 else self._pacer.delay_s(t_ns)


def make_source(
    settings: SourceSettings, on_event: EventSink, *, clock: Callable[[], int] = time.time_ns
) -> Source:
    """The source for a configured source kind."""
    if isinstance(settings, SerialSourceSettings):
        return SerialSource(settings, on_event, clock=clock)
    if isinstance(settings, TcpSourceSettings):
        return TcpSource(settings, on_event, clock=clock)
    return FileSource(settings, on_event, clock=clock)
