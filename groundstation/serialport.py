"""The one module that imports pyserial: opening a receiver's UART and the blocking link to it.

Every port is opened the same way: 8N1, no flow control, exclusively (pyserial's ``flock``), so
two processes never read the same radio (each would get a random half of the bytes). A port
held by another process raises :class:`PortInUse` naming the holder. Two users: the daemon's
:class:`~groundstation.live.sources.SerialSource` (non-blocking, read by its own thread) and
``groundstation configure`` through :class:`SerialLink` (blocking reads with a short timeout).
pyserial's own exception is an :class:`OSError`, so callers catch that and never import serial.
"""

from __future__ import annotations

import contextlib
import errno
import os
from typing import TypeAlias

import serial

from groundstation.errors import SourceError
from groundstation.ubx.configure import READ_SLICE_S

Port: TypeAlias = serial.Serial
"""An open port (``fileno()``, ``read``, ``write``, ``close`` ...)."""


class PortInUse(OSError):
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


def is_terminal(path: str) -> bool:
    """Whether the character device ``path`` has a terminal interface (a serial port, a pty):
    ``/dev/null`` or ``/dev/zero`` do not, and a serial reader on them would retry for ever.

    Opened without becoming the controlling terminal and without waiting for a carrier, and
    closed at once (no lock taken). A device that cannot be opened at all counts as a
    terminal here: the caller's own open says why.
    """
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return True
    try:
        return os.isatty(fd)
    finally:
        os.close(fd)


def open_port(path: str, baud: int, *, timeout_s: float | None,
              write_timeout_s: float | None = None) -> Port:
    """Open ``path`` at ``baud``, 8N1, no flow control, exclusively.

    Args:
        path: the device, e.g. ``/dev/ttyUSB0``.
        baud: the rate.
        timeout_s: read timeout (0: never block; ``None``: block).
        write_timeout_s: write timeout (``None``: block).

    Raises:
        PortInUse: another process holds the port's lock.
        OSError: any other failure (missing device, permission, a rate the device refuses;
            pyserial's ``SerialException`` is one).
    """
    try:
        return serial.Serial(
            path, baud, bytesize=serial.EIGHTBITS, parity=serial.PARITY_NONE,
            stopbits=serial.STOPBITS_ONE, timeout=timeout_s, write_timeout=write_timeout_s,
            xonxoff=False, rtscts=False, exclusive=True,
        )
    except serial.SerialException as err:
        if err.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
            pid = lock_holder(path)
            by = f"process {pid}" if pid is not None else "another process"
            raise PortInUse(f"{path} is in use by {by} (it holds the port's exclusive "
                            "lock: is another groundstation daemon running on it?)") from err
        raise
    except ValueError as err:  # pyserial's answer to a rate or setting the driver refuses
        raise OSError(f"{path}: {err}") from err


class SerialLink:
    """A blocking serial link for ``groundstation configure`` (the ``Link`` of
    :func:`groundstation.ubx.configure.send_messages`).

    Args:
        port: device path, e.g. ``/dev/wi232`` or ``/dev/ttyUSB0``.
        baud: the rate the receiver's port is running at now.
        read_slice_s: longest single blocking read (the caller checks its deadline between).

    Raises:
        SourceError: the port cannot be opened (missing, permission, or locked by another
            process such as a running daemon).
    """

    def __init__(self, port: str, baud: int, *, read_slice_s: float = READ_SLICE_S) -> None:
        self.port = port
        self._baud = baud
        self._slice_s = read_slice_s
        self._serial = self._open(baud)

    @property
    def baud(self) -> int:
        return self._baud

    def _open(self, baud: int) -> Port:
        try:
            return open_port(self.port, baud, timeout_s=self._slice_s, write_timeout_s=5.0)
        except OSError as err:
            raise SourceError(f"cannot open {self.port} at {baud} baud: {err}") from err

    def write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
            self._serial.flush()  # tcdrain: the bytes are on the wire before the clock starts
        except OSError as err:
            raise SourceError(f"cannot write to {self.port}: {err}") from err

    def read(self, max_wait_s: float) -> bytes:
        # The port's own timeout (read_slice_s) bounds the blocking read; callers loop.
        del max_wait_s
        try:
            data = bytes(self._serial.read(1))
            if data and self._serial.in_waiting:
                data += bytes(self._serial.read(self._serial.in_waiting))
        except OSError as err:
            raise SourceError(f"cannot read from {self.port}: {err}") from err
        return data

    def discard_input(self) -> None:
        self._serial.reset_input_buffer()

    def reopen(self, baud: int) -> None:
        self._serial.close()
        self._serial = self._open(baud)
        self._baud = baud

    def close(self) -> None:
        """Close the port (idempotent)."""
        self._serial.close()
