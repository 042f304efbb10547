"""The serial reader thread (``live/port_reader.py``) on a real pty: every byte in order with its
read's time, marks recognised however the bytes are cut, a quiet line handed over, the port's
last bytes kept at the stop, a hang-up reported."""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import os
import struct
import termios
import threading
import time
import tty
from collections.abc import Iterator

import pytest

from groundstation.live.port_reader import DeviceVanished, MarkWatch, PortReader
from groundstation.ubx import layouts as L


def _mark(count: int) -> bytes:
    return L.TIM_TM2.frame(flags=0x41, count=count, wnR=2300, wnF=2300, towMsR=5, towMsF=4)


def test_mark_watch_sees_a_mark_however_it_is_cut() -> None:
    before, mark, after = b"\xb5\x62\x01\x02" + bytes(40), _mark(3), b"\xb5\x62\x0d"
    stream = before + mark + after
    end = len(before) + len(mark)
    for a in range(1, len(stream)):
        for b in range(a, len(stream) + 1):
            w = MarkWatch()
            said = [w.feed(stream[:a]), w.feed(stream[a:b]), w.feed(stream[b:])]
            # exactly one read says so: the one that brings the mark's last byte
            first = 0 if a >= end else 1 if b >= end else 2
            assert said == [i == first for i in range(3)], (a, b)


def test_mark_watch_ignores_other_messages() -> None:
    w = MarkWatch()
    assert not w.feed(L.TIM_TM2.frame()[:-1] + b"\x00" * 0)  # one byte short
    w = MarkWatch()
    assert not w.feed(b"\xb5\x62\x0d\x01" + bytes(60))  # TIM-TP, not TIM-TM2


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, int]]:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(slave, False)
    yield master, slave
    for fd in (master, slave):
        with contextlib.suppress(OSError):
            os.close(fd)


def _reader(fd: int, checked: threading.Event | None = None) -> PortReader:
    def idle() -> None:
        if checked is not None:
            checked.set()

    return PortReader(fd, read_size=4096, clock=time.time_ns, idle_check=idle,
                      stall_check_s=0.05, repoint_check_s=1.0)


def test_bytes_arrive_in_order_and_a_quiet_line_is_handed_over(
    pty_pair: tuple[int, int]
) -> None:
    master, slave = pty_pair
    sent = bytes(range(256)) * 40 + _mark(1) + b"tail"
    checked = threading.Event()

    async def main() -> bytes:
        reader = _reader(slave, checked)
        reader.start()
        got = bytearray()
        times: list[int] = []
        for i in range(0, len(sent), 100):
            os.write(master, sent[i:i + 100])
            await asyncio.sleep(0.002)
        while len(got) < len(sent):  # the line is quiet now: what is held comes anyway
            for data, t in await asyncio.wait_for(reader.batch(), 5):
                got += data
                times.append(t)
        assert times == sorted(times)
        # the quiet line is checked (every stall_check_s)
        assert await asyncio.to_thread(checked.wait, 10)
        assert reader.stop() == []
        return bytes(got)

    assert asyncio.run(main()) == sent


def test_stop_keeps_what_is_held_and_what_the_port_holds(pty_pair: tuple[int, int]) -> None:
    master, slave = pty_pair

    async def main() -> bytes:
        reader = _reader(slave)
        reader.start()
        os.write(master, b"first")
        await asyncio.sleep(0.02)  # read by the thread, not yet due
        os.write(master, b"second")  # read too, or still in the port at the stop
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:  # until the pty has passed it to the slave side
            queued = struct.unpack("i", fcntl.ioctl(slave, termios.FIONREAD, b"\0" * 4))[0]
            with reader._lock:
                held = sum(len(d) for d, _ in reader._held)
            if queued + held == len(b"firstsecond"):
                break
            await asyncio.sleep(0.001)
        return b"".join(d for d, _ in reader.stop())

    assert asyncio.run(main()) == b"firstsecond"


def test_hang_up_is_reported_after_the_bytes_before_it(pty_pair: tuple[int, int]) -> None:
    master, slave = pty_pair

    async def main() -> tuple[bytes, str]:
        reader = _reader(slave)
        reader.start()
        os.write(master, b"last words")
        await asyncio.sleep(0.05)
        os.close(master)
        got = b""
        try:
            while True:
                got += b"".join(d for d, _ in await asyncio.wait_for(reader.batch(), 5))
        except DeviceVanished as err:
            reader.stop()
            return got, str(err)

    got, why = asyncio.run(main())
    assert got == b"last words"
    assert why
