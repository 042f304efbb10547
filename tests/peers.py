"""Real peers for integration tests: a pty pair that can be unplugged, the daemon as a
real process with its stderr collected, a CLI process in its own working directory
(:class:`CliProc`, with :func:`cli_env`), the messages a bus delivers (:class:`Received`),
and :func:`wait_until`, the one way a test waits for something to happen (a condition with a
timeout, never a fixed sleep)."""

from __future__ import annotations

import itertools
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from groundstation.bus import Bus, decode
from groundstation.live.fanout import Inbox, InboxClosed
from groundstation.records import Event, Status
from groundstation.serialport import lock_holder
from groundstation.sim.ptylink import PtyLink

REPO = Path(__file__).resolve().parents[1]

T = TypeVar("T")


def wait_until(
    cond: Callable[[], T], timeout_s: float = 10.0, what: str = "condition",
    poll_s: float = 0.02,
) -> T:
    """Return ``cond()``'s value as soon as it is true; fail naming ``what`` after ``timeout_s``.

    Polls every ``poll_s``: the things tests wait for (a file's size, a message on the bus, a
    line on stderr) have no notification to block on, and the poll keeps the wait short
    where a fixed sleep would have to assume the slowest machine.
    """
    deadline = time.monotonic() + timeout_s
    while not (got := cond()):
        if time.monotonic() >= deadline:
            raise AssertionError(f"{what} not met within {timeout_s:g} s")
        time.sleep(poll_s)
    return got


PORTS_PER_WORKER = 400
"""Ports each test worker (pytest-xdist ``gwN``) takes its ports from, in turn."""
_port_turn = itertools.count()


def _port_range() -> tuple[int, int] | None:
    """This worker's ports, ``[first, end)``: below the kernel's ephemeral range, where no
    outgoing connection (a Zenoh client, an HTTP request) is given one by chance between the
    test choosing it and a peer listening on it, and apart from every other worker's. None
    when the ephemeral range leaves no room below it."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range", encoding="ascii") as f:
            ephemeral_low = int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    first = 20_000 + index * PORTS_PER_WORKER
    end = first + PORTS_PER_WORKER
    return (first, end) if end <= ephemeral_low else None


def free_port() -> int:
    """A TCP port nobody listens on right now (for a Zenoh endpoint, a web server), this test
    worker's own: taken in turn from its range (:func:`_port_range`), skipping any port in use
    (by another program on the machine too), so a port comes back to a worker only after all
    its others; the kernel's choice where no range fits."""
    span = _port_range()
    if span is not None:
        first, end = span
        for _ in range(end - first):
            port = first + next(_port_turn) % (end - first)
            with socket.socket() as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    continue
            return port
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        chosen: int = s.getsockname()[1]
        return chosen


def cli_env(**settings: str) -> dict[str, str]:
    """The environment of a CLI process a test starts: this one's without any
    ``GROUNDSTATION_*`` setting (the test names every setting it means), the repository on
    ``PYTHONPATH`` (the process runs in its own directory), then ``settings``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("GROUNDSTATION_")}
    env["PYTHONPATH"] = str(REPO)
    env.update(settings)
    return env


def interrupted_cli(argv: list[str], cwd: Path | None = None,
                    ready: Callable[[], object] | None = None, ready_s: float = 60.0,
                    after_s: float = 0.0) -> tuple[int, str, str]:
    """Run ``groundstation <argv>``, wait until ``ready()`` (at most ``ready_s``) and ``after_s``
    more, send SIGINT (a user's Ctrl-C); (exit status, stdout, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "groundstation.cli", *argv], cwd=cwd,
                            env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + ready_s
        while ready is not None and not ready() and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(after_s)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out, err


class CliProc:
    """``python -m groundstation.cli *argv`` in its own working directory ``cwd`` (made if
    missing), its stdout and stderr in ``stdout.txt`` and ``stderr.txt`` there.

    Files rather than pipes: a long-running process never blocks on a full pipe, and what it
    said stays readable after a failure. ``env`` adds settings to :func:`cli_env`;
    ``wait_s`` is how long :meth:`wait_for` waits unless told otherwise.
    """

    def __init__(self, cwd: Path, *argv: str, env: Mapping[str, str] | None = None,
                 wait_s: float = 60.0) -> None:
        cwd.mkdir(parents=True, exist_ok=True)
        self.cwd = cwd
        self.wait_s = wait_s
        self.out_path = cwd / "stdout.txt"
        self.err_path = cwd / "stderr.txt"
        with self.out_path.open("w") as out, self.err_path.open("w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "groundstation.cli", *argv], cwd=cwd,
                env=cli_env(**(env or {})), stdout=out, stderr=err,
            )

    def stderr(self) -> str:
        """All the process wrote on stderr so far."""
        return self.err_path.read_text(errors="replace")

    def wait_for(self, text: str, timeout_s: float | None = None) -> None:
        """Return once ``text`` is on stderr; fail with its stderr if the process exits first
        or ``timeout_s`` (default ``wait_s``) passes."""
        try:
            wait_until(lambda: text in self.stderr() or self.proc.poll() is not None,
                       self.wait_s if timeout_s is None else timeout_s,
                       f"{text!r} in {self.cwd.name}'s stderr", poll_s=0.1)
        except AssertionError as e:
            raise AssertionError(f"{e}:\n{self.stderr()}") from None
        assert text in self.stderr(), f"{self.cwd.name} exited early:\n{self.stderr()}"

    def stop(self) -> None:
        """SIGTERM and wait (20 s, then SIGKILL); nothing if it has exited already."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)


def named_elsewhere(device: str) -> bool:
    """Whether another process holds ``device`` (a pty slave) locked or names it on its
    command line: a daemon of someone else's started on ``/dev/pts/N`` whose pty has closed
    reopens the number when the kernel hands it to the next pty (this test's)."""
    if lock_holder(device) not in (None, os.getpid()):
        return True
    needle = device.encode()
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                if needle in f.read().split(b"\0"):
                    return True
        except OSError:
            continue
    return False


class Pty(PtyLink):
    """A pty pair reachable through a symlink that can be pulled and plugged back.

    A pty whose device another process names or holds (:func:`named_elsewhere`) is passed
    over for the next one: the test's daemon must be the only reader of its pty.
    """

    link: Path

    def __init__(self, link: Path) -> None:
        super().__init__(link)

    def plug(self) -> None:
        passed: list[tuple[int, int]] = []
        try:
            for _ in range(20):
                super().plug()
                if not named_elsewhere(os.ttyname(self.slave)):
                    return
                passed.append((self.master, self.slave))  # held: the next pty is another
        finally:
            for fd in (fd for pair in passed if pair != (self.master, self.slave)
                       for fd in pair):
                os.close(fd)


class Daemon:
    """`python -m groundstation.cli run ...` with its stderr collected line by line (and its
    stdout whole)."""

    def __init__(self, *args: str, command: str = "run") -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "groundstation.cli", command, *args],
            cwd=REPO, env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        self.lines: list[tuple[float, str]] = []
        self._out: list[str] = []
        # Each pipe has one reader, its own thread: ``communicate`` would read stderr too and
        # take lines the pump had not read yet (a daemon that ended at once lost its one line).
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()
        self._out_thread = threading.Thread(target=self._pump_out, daemon=True)
        self._out_thread.start()

    def _pump(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append((time.monotonic(), line))

    def _pump_out(self) -> None:
        assert self.proc.stdout is not None
        self._out.append(self.proc.stdout.read())

    def wait_for(self, text: str, timeout_s: float = 60.0, after: float = 0.0) -> float:
        """Monotonic time at which a stderr line containing ``text`` appeared (at most
        ``timeout_s``: generous, for a process starting on a busy machine; the time a
        behaviour must take is checked by the tests, not by this wait)."""
        deadline = time.monotonic() + timeout_s
        while True:
            ended = self.proc.poll() is not None
            if ended:  # its last lines may still be in the pipe: read to the end first
                self._thread.join(timeout=5)
            for t, line in list(self.lines):
                if t >= after and text in line:
                    return t
            if ended or time.monotonic() >= deadline:
                break
            time.sleep(0.02)
        raise AssertionError(f"no {text!r} within {timeout_s} s; stderr:\n" + self.stderr)

    @property
    def stderr(self) -> str:
        return "".join(line for _, line in self.lines)

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 15.0) -> tuple[int, str]:
        """Send ``sig`` (nothing if it has ended), wait for the end and for both pipes to be
        read to their end: the exit status and stdout."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        self.proc.wait(timeout=timeout_s)
        self._thread.join(timeout=5)
        self._out_thread.join(timeout=5)
        return self.proc.returncode, "".join(self._out)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


def _every(_message: dict[str, Any]) -> bool:
    return True


class Received:
    """Every message a bus delivers on ``key_expr``, parsed by ``parse``, with its arrival time
    (monotonic), in order; read from the test's thread while the bus's thread adds."""

    def __init__(self, bus: Bus, key_expr: str,
                 parse: Callable[[bytes], dict[str, Any]] = decode) -> None:
        self._parse = parse
        self._lock = threading.Lock()
        self._items: list[tuple[float, dict[str, Any]]] = []
        bus.subscribe(key_expr, self._on)

    def _on(self, _key: str, payload: bytes) -> None:
        with self._lock:
            self._items.append((time.monotonic(), self._parse(payload)))

    def timed(self, which: Callable[[dict[str, Any]], object] = _every,
              ) -> list[tuple[float, dict[str, Any]]]:
        """The messages ``which`` accepts (default: all), each with its arrival time."""
        with self._lock:
            items = list(self._items)
        return [(t, m) for t, m in items if which(m)]

    def all(self, which: Callable[[dict[str, Any]], object] = _every) -> list[dict[str, Any]]:
        """The messages ``which`` accepts (default: all)."""
        return [m for _, m in self.timed(which)]


class ItemCollector:
    """A pipeline sink that keeps every item of the types it accepts, in order (never drops:
    register it with ``Overflow.NEVER_DROP``). ``ItemCollector(RawChunk, RawEpoch)``, or a
    subclass naming its ``accepts``."""

    name = "items"
    accepts: frozenset[type] = frozenset()

    def __init__(self, *types: type) -> None:
        if types:
            self.accepts = frozenset(types)
        self.items: list[Any] = []

    async def consume(self, inbox: Inbox, publish: object) -> None:
        kinds = tuple(self.accepts)
        while True:
            try:
                items = await inbox.get_all()
            except InboxClosed:
                return
            self.items.extend(i for i in items if isinstance(i, kinds))


class EventCollector(ItemCollector):
    """Every Event published."""

    name = "events"
    accepts: frozenset[type] = frozenset({Event})
    items: list[Event]


class StatusEventCollector(ItemCollector):
    """Every Event and Status published, in order."""

    name = "everything"
    accepts: frozenset[type] = frozenset({Event, Status})
    items: list[Event | Status]


class Screen:
    """What a program draws on a terminal (the master side of its pty), read as it comes by a
    thread, so a test can wait for something to be shown while the program runs on."""

    def __init__(self, master: int) -> None:
        self._master = master
        self._data = bytearray()
        self._lock = threading.Lock()
        self._stopping = False
        self._thread = threading.Thread(target=self._read, name="screen", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stopping:  # polled: the fd is closed only once this thread has ended
            ready, _, _ = select.select([self._master], [], [], 0.2)
            if not ready:
                continue
            try:
                data = os.read(self._master, 65536)
            except OSError:  # EIO: the program closed the terminal
                return
            if not data:
                return
            with self._lock:
                self._data += data

    def text(self) -> str:
        """Everything drawn so far."""
        with self._lock:
            return self._data.decode(errors="replace")

    def ended(self, timeout_s: float) -> bool:
        """Wait until the last writer has closed the terminal (at most ``timeout_s``)."""
        self._thread.join(timeout=timeout_s)
        return not self._thread.is_alive()

    def stop(self) -> None:
        """Stop reading (the master side stays open)."""
        self._stopping = True
        self._thread.join()

    def close(self) -> None:
        """Read what is left once the program has ended (at most 5 s), stop, close the master
        side."""
        self.ended(5)
        self.stop()
        os.close(self._master)


def read_terminal(master: int, timeout_s: float) -> str:
    """Everything the terminal shows until its last writer closes it (at most ``timeout_s``;
    the caller closes ``master``)."""
    screen = Screen(master)
    screen.ended(timeout_s)
    screen.stop()
    return screen.text()
