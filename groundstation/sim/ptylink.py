"""A pseudo-terminal standing in for the radio's USB serial port, and the one way to feed it.

The daemon opens :attr:`PtyLink.path` with pyserial exactly as it opens ``/dev/ttyUSB0``;
what is written into the master side arrives there. Used by ``groundstation demo``,
``groundstation simulate --pty`` and the integration tests (which also pull the "cable" out and
plug it back through a symlink). Timed chunks are written paced by :mod:`groundstation.pacing`,
in the calling thread (:meth:`PtyLink.feed`) or in a background one (:meth:`PtyLink.start_feed`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
import tty
from collections.abc import Iterable
from pathlib import Path

from groundstation.pacing import paced

log = logging.getLogger("groundstation.pty")


class PtyLink:
    """A pty pair in raw mode (no echo, no line discipline: bytes pass unchanged).

    Args:
        link: if given, a symlink to the slave side that :meth:`unplug` removes and
            :meth:`plug` puts back (to a new pty pair), like a USB cable pulled and plugged in;
            :attr:`path` is then the link.
    """

    def __init__(self, link: Path | None = None) -> None:
        self.link = link
        self.master = -1
        self.slave = -1
        self.path = ""
        """What a serial reader opens (the link, or the slave's device name)."""
        self.bytes_written = 0
        self.chunks_written = 0
        """Timed chunks :meth:`feed` has written whole (a cut run reports what was sent)."""
        self.last_t_ns: int | None = None
        """The time of the last chunk :meth:`feed` wrote whole, ``None`` before the first."""
        self.cut_short = False
        """A feed ended with chunks left: :meth:`stop` was called or its ``for_s`` ran out."""
        self.done = threading.Event()
        """Set when a feed has ended (all written, stopped, or the pty closed)."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.plug()

    def plug(self) -> None:
        """Open a new pty pair (and point the link at it)."""
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = str(self.link) if self.link is not None else os.ttyname(self.slave)
        if self.link is not None:
            tmp = self.link.with_suffix(".new")
            tmp.unlink(missing_ok=True)
            os.symlink(os.ttyname(self.slave), tmp)
            os.replace(tmp, self.link)  # atomically: a reader never sees no link while plugging

    def unplug(self) -> None:
        """Remove the link and close the pair: the reader sees its device vanish."""
        if self.link is not None:
            self.link.unlink(missing_ok=True)
        self._close_fds()

    def write(self, data: bytes, piece: int = 1024) -> None:
        """Write all of ``data`` into the master side, ``piece`` bytes at a time."""
        for i in range(0, len(data), piece):
            view = memoryview(data)[i : i + piece]
            while view:
                n = os.write(self.master, view)
                view = view[n:]
            self.bytes_written += min(piece, len(data) - i)

    def feed(self, chunks: Iterable[tuple[int, bytes]], speed: float | None,
             for_s: float = 0.0) -> int:
        """Write timed chunks ``(t_ns, data)`` paced at ``speed`` (``None``: at once), until
        they end, :meth:`stop` is called or ``for_s`` seconds (``> 0``) have passed since the
        feed began. Returns the bytes written.

        The time limit is kept here, by the thread that writes, like a radio that goes quiet:
        an event loop kept busy cannot let more of the flight through than the limit allows.

        Raises:
            OSError: the pty was closed under the writer.
        """
        start, began = self.bytes_written, time.monotonic()
        self.cut_short = False
        for t_ns, chunk in paced(chunks, speed):
            if self._stop.is_set() or 0 < for_s <= time.monotonic() - began:
                self.cut_short = True
                break
            self.write(chunk, piece=len(chunk) or 1)
            self.chunks_written += 1
            self.last_t_ns = t_ns
        return self.bytes_written - start

    def start_feed(self, chunks: Iterable[tuple[int, bytes]], speed: float | None,
                   for_s: float = 0.0) -> None:
        """:meth:`feed` in a background thread; :attr:`done` is set when it ends."""
        self.done.clear()

        def run() -> None:
            try:
                self.feed(chunks, speed, for_s)
            except OSError as err:
                log.warning("pty writer stopped: %s", err)
            finally:
                self.done.set()

        self._thread = threading.Thread(target=run, name="pty-feeder", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Ask a feed to stop after the chunk it is writing."""
        self._stop.set()

    def _close_fds(self) -> None:
        for fd in (self.master, self.slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self.slave = -1

    def close(self) -> None:
        """Stop any feed, remove the link, if any, and close the pair.

        The link goes first: the kernel gives a closed pty's number to the next pty opened,
        and a reader still reopening the link (a daemon stopped after its pty) would take
        another program's pty.
        """
        self._stop.set()
        self.unplug()
