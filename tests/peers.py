"""Real peers for integration tests: a pty pair that can be unplugged, the daemon as a
real process with its stderr collected, and :func:`wait_until`, the one way a test waits for
something to happen (a condition with a timeout, never a fixed sleep)."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from groundstation.live.fanout import Inbox, InboxClosed
from groundstation.records import Event, Status
from groundstation.sim.ptylink import PtyLink

REPO = Path(__file__).resolve().parents[1]


def wait_until(
    cond: Callable[[], object], timeout_s: float = 10.0, what: str = "condition",
    poll_s: float = 0.02,
) -> None:
    """Return as soon as ``cond()`` is true; fail naming ``what`` after ``timeout_s``.

    Polls every ``poll_s``: the things tests wait for (a file's size, a message on the bus, a
    line on stderr) have no notification to block on, and the poll keeps the wait short
    where a fixed sleep would have to assume the slowest machine.
    """
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() >= deadline:
            raise AssertionError(f"{what} not met within {timeout_s:g} s")
        time.sleep(poll_s)


def free_port() -> int:
    """A TCP port nobody listens on right now (for a Zenoh endpoint)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Pty(PtyLink):
    """A pty pair reachable through a symlink that can be pulled and plugged back."""

    link: Path

    def __init__(self, link: Path) -> None:
        super().__init__(link)


class Daemon:
    """`python -m groundstation.cli run ...` with its stderr collected line by line."""

    def __init__(self, *args: str, command: str = "run") -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "groundstation.cli", command, *args],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        self.lines: list[tuple[float, str]] = []
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append((time.monotonic(), line))

    def wait_for(self, text: str, timeout_s: float = 10.0, after: float = 0.0) -> float:
        """Monotonic time at which a stderr line containing ``text`` appeared."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for t, line in list(self.lines):
                if t >= after and text in line:
                    return t
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        raise AssertionError(f"no {text!r} within {timeout_s} s; stderr:\n" + self.stderr)

    @property
    def stderr(self) -> str:
        return "".join(line for _, line in self.lines)

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 15.0) -> tuple[int, str]:
        self.proc.send_signal(sig)
        out, _ = self.proc.communicate(timeout=timeout_s)
        self._thread.join(timeout=2)
        return self.proc.returncode, out

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


class EventCollector:
    """A pipeline sink that keeps every Event published (never drops: register it with
    ``Overflow.NEVER_DROP``)."""

    name = "events"
    accepts = frozenset((Event,))

    def __init__(self) -> None:
        self.items: list[Event] = []

    async def consume(self, inbox: Inbox, publish: object) -> None:
        while True:
            try:
                items = await inbox.get_all()
            except InboxClosed:
                return
            self.items.extend(i for i in items if isinstance(i, Event))


class StatusEventCollector:
    """A pipeline sink that keeps every Event and Status published, in order (never drops:
    register it with ``Overflow.NEVER_DROP``)."""

    name = "everything"
    accepts: frozenset[type] = frozenset({Event, Status})

    def __init__(self) -> None:
        self.items: list[Event | Status] = []

    async def consume(self, inbox: Inbox, publish: object) -> None:
        while True:
            try:
                items = await inbox.get_all()
            except InboxClosed:
                return
            self.items.extend(i for i in items if isinstance(i, (Event, Status)))
