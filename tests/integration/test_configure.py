"""``groundstation configure`` against a simulated receiver on a real pty pair.

The simulated receiver parses what we send with :class:`UbxFramer`, answers ACK-ACK, ACK-NAK or
nothing, and models the UART baud rate: it reads the pty's line speed (set by the tool through
pyserial) and treats bytes sent at a speed other than its own as line noise, exactly as a real
UART would. A tool that does not follow a baud change therefore gets no more ACKs.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import struct
import termios
import threading
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from pyubx2 import SET, UBXMessage, UBXReader

from groundstation.cli import main
from groundstation.ubx.build import build_frame
from groundstation.ubx.framer import UbxFramer

FAST = ["--timeout", "0.3", "--retries", "2", "--settle", "0.02"]
SPEEDS = {
    getattr(termios, f"B{b}"): b for b in (4800, 9600, 19200, 38400, 57600, 115200, 230400)
}
UART1_BAUD_KEY = 0x40520001


@dataclass
class Received:
    """One frame the receiver got: class, id, payload, and the line speed it came at."""

    cls: int
    id: int
    payload: bytes
    line_baud: int

    @property
    def name(self) -> str:
        frame = build_frame(self.cls, self.id, self.payload)
        return str(UBXReader.parse(frame, msgmode=SET).identity)


@dataclass
class FakeReceiver:
    """A u-blox receiver's UART1 on the master side of a pty.

    Attributes:
        baud: the rate its UART runs at; bytes arriving at another line speed are noise.
        nak: identities (``"CFG-TP5"``) to refuse with ACK-NAK.
        drop: raw frame -> how many times to ignore it before answering.
        lose_baud_ack: switch baud on a CFG-PRT that changes it, but lose its ACK.
        connected_via_uart1: False models a USB connection: a UART1 baud change does not touch
            the line we talk over.
        chatter: also stream unrelated frames (a NAV-SOL every 20 ms) the tool must skip.
    """

    baud: int = 9600
    nak: set[str] = field(default_factory=set)
    drop: dict[bytes, int] = field(default_factory=dict)
    lose_baud_ack: bool = False
    connected_via_uart1: bool = True
    chatter: bool = False
    received: list[Received] = field(default_factory=list)
    noise_chunks: int = 0

    def start(self) -> str:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fake-receiver", daemon=True)
        self._thread.start()
        return os.ttyname(self.slave)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        os.close(self.master)
        os.close(self.slave)

    def line_baud(self) -> int:
        return SPEEDS[termios.tcgetattr(self.slave)[4]]

    def _run(self) -> None:
        framer = UbxFramer()
        next_chatter = time.monotonic()
        while not self._stop.is_set():
            if self.chatter and time.monotonic() >= next_chatter:
                next_chatter += 0.02
                self._send(build_frame(0x01, 0x06, bytes(52)))
            ready, _, _ = select.select([self.master], [], [], 0.01)
            if not ready:
                continue
            try:
                chunk = os.read(self.master, 4096)
            except OSError:  # the tool closed its side while reopening: no reader for a moment
                time.sleep(0.005)
                continue
            if self.connected_via_uart1 and self.line_baud() != self.baud:
                self.noise_chunks += 1  # a UART at the wrong speed sees framing errors
                framer = UbxFramer()
                continue
            for frame in framer.feed(chunk, 0):
                self._answer(Received(frame.cls, frame.id, frame.payload, self.line_baud()))

    def _answer(self, got: Received) -> None:
        self.received.append(got)
        raw = build_frame(got.cls, got.id, got.payload)
        if self.drop.get(raw, 0) > 0:
            self.drop[raw] -= 1
            return
        new_baud = self._uart1_baud(got)
        ack_id = 0x00 if got.name in self.nak else 0x01
        if ack_id == 0x01 and new_baud not in (None, self.baud) and self.connected_via_uart1:
            assert new_baud is not None
            if not self.lose_baud_ack:
                self._send(build_frame(0x05, ack_id, bytes((got.cls, got.id))))
                termios.tcdrain(self.master)
            self.baud = new_baud
            return
        self._send(build_frame(0x05, ack_id, bytes((got.cls, got.id))))

    def _send(self, data: bytes) -> None:
        if self.connected_via_uart1 and self.line_baud() != self.baud:
            data = b"\xff\x00" * len(data)  # what the host's UART makes of it
        with contextlib.suppress(OSError):  # the tool is between close and reopen
            os.write(self.master, data)

    @staticmethod
    def _uart1_baud(got: Received) -> int | None:
        if (got.cls, got.id) == (0x06, 0x00) and len(got.payload) == 20 and got.payload[0] == 1:
            return int(struct.unpack_from("<I", got.payload, 8)[0])
        if (got.cls, got.id) == (0x06, 0x8A) and got.payload[1] & 0x01:  # VALSET in RAM
            i = 4
            while i + 4 <= len(got.payload):
                key = struct.unpack_from("<I", got.payload, i)[0]
                size = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8}[(key >> 28) & 0x7]
                if key == UART1_BAUD_KEY:
                    return int(struct.unpack_from("<I", got.payload, i + 4)[0])
                i += 4 + size
        return None


@pytest.fixture
def receiver() -> Iterator[FakeReceiver]:
    rx = FakeReceiver()
    yield rx
    if hasattr(rx, "_thread"):
        rx.stop()


def configure(rx: FakeReceiver, *args: str) -> list[str]:
    port = rx.start()
    return ["configure", "--port", port, *FAST, *args]


def report(out: str) -> dict[int, str]:
    """Report lines by message number."""
    return {int(m.group(1)): m.group(0) for m in re.finditer(r"^ ?(\d+) CFG-.*$", out, re.M)}


def test_all_acknowledged_and_baud_followed(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    receiver.chatter = True
    rc = main(configure(receiver, "--baud", "9600", "--profile", "lea6t-5hz"))
    out = capsys.readouterr().out
    assert rc == 0, out
    lines = report(out)
    assert len(lines) == 9
    assert all(" ACK " in line and "attempts 1" in line for line in lines.values()), out
    assert "9 acknowledged, 0 refused (NAK), 0 without reply, 0 skipped of 9" in out
    assert "now at 57600 baud" in out
    names = [r.name for r in receiver.received]
    assert names == ["CFG-PRT", "CFG-RATE"] + ["CFG-MSG"] * 5 + ["CFG-TP5", "CFG-CFG"]
    # CFG-PRT went at the old rate, everything after it at the new one.
    assert [r.line_baud for r in receiver.received] == [9600] + [57600] * 8
    assert receiver.noise_chunks == 0
    assert "28 bytes" in lines[1] and "21 bytes" in lines[9]


def test_nak_reported_and_save_skipped(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    receiver.nak = {"CFG-TP5"}
    rc = main(configure(receiver, "--profile", "lea6t-5hz"))
    out = capsys.readouterr().out
    assert rc == 1
    lines = report(out)
    assert " NAK " in lines[8] and "attempts 1" in lines[8]  # a NAK is never retried
    assert "refused by the receiver (ACK-NAK)" in out
    assert " skipped " in lines[9] and "attempts 0" in lines[9]
    assert "not saving a partial configuration (message 8 CFG-TP5 failed)" in out
    assert "CFG-CFG" not in [r.name for r in receiver.received]
    assert "CONFIGURATION INCOMPLETE: 7 acknowledged, 1 refused (NAK)" in out


def test_silence_retried_then_acknowledged(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    tm2 = UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x0D, msgID=0x03, rateUART1=1).serialize()
    receiver.drop = {bytes(tm2): 2}
    rc = main(configure(receiver, "--profile", "lea6t-5hz"))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert " ACK " in report(out)[5] and "attempts 3" in report(out)[5]
    assert sum(build_frame(r.cls, r.id, r.payload) == tm2 for r in receiver.received) == 3


def test_silence_exhausts_retries(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    rate = UBXMessage("CFG", "CFG-RATE", SET, measRate=200, navRate=1, timeRef=1).serialize()
    receiver.drop = {bytes(rate): 99}
    t0 = time.monotonic()
    rc = main(configure(receiver, "--profile", "lea6t-5hz", "--retries", "1"))
    elapsed = time.monotonic() - t0
    out = capsys.readouterr().out
    assert rc == 1
    line = report(out)[2]
    assert " timeout " in line and "attempts 2" in line
    assert "no ACK within 0.3 s on any of 2 attempts" in out
    assert " skipped " in report(out)[9]  # no save after a failure
    assert all(" ACK " in report(out)[i] for i in range(3, 9))  # the rest still went out
    assert elapsed < 10


def test_lost_baud_ack_confirmed_at_new_baud(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    receiver.lose_baud_ack = True
    rc = main(configure(receiver, "--profile", "lea6t-5hz"))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert " ACK " in report(out)[1] and "attempts 2" in report(out)[1]
    assert "ACK at 9600 baud lost; acknowledged at 57600 baud" in out
    assert [r.line_baud for r in receiver.received[:2]] == [9600, 57600]


def test_receiver_already_at_profile_baud(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    receiver.baud = 57600  # a second run, but the operator passed the factory default
    rc = main(configure(receiver, "--baud", "9600", "--profile", "lea6t-5hz"))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert receiver.noise_chunks == 1  # the attempt at 9600 was noise to a 57600 UART


def test_baud_change_unconfirmed_stops(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    receiver.baud = 38400  # neither the rate we claim nor the profile's
    rc = main(configure(receiver, "--baud", "9600", "--profile", "lea6t-5hz"))
    out = capsys.readouterr().out
    assert rc == 1
    assert " timeout " in report(out)[1] and "attempts 3" in report(out)[1]
    assert "should have switched the port from 9600 to 57600 baud" in out
    assert all(" skipped " in report(out)[i] for i in range(2, 10))
    assert receiver.received == []


def test_wrong_baud_no_frames_stops_early(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    profile = tmp_path / "rates.toml"
    profile.write_text(
        '[[messages]]\nname = "CFG-RATE"\nfields = { measRate = 200, navRate = 1, timeRef = 1 }\n'
        '[[messages]]\nname = "CFG-MSG"\nfields = { msgClass = 2, msgID = 0x10, rateUART1 = 1 }\n'
    )
    receiver.baud = 115200
    rc = main(configure(receiver, "--baud", "9600", "--profile", str(profile)))
    out = capsys.readouterr().out
    assert rc == 1
    assert "no valid UBX frame received at all at 9600 baud" in out
    assert " skipped " in report(out)[2]


def test_via_other_port_does_not_follow_baud(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    receiver.connected_via_uart1 = False
    rc = main(configure(receiver, "--profile", "lea6t-5hz", "--via", "other"))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert {r.line_baud for r in receiver.received} == {9600}
    assert "now at" not in out


def test_f9p_valset_baud_change(
    receiver: FakeReceiver, capsys: pytest.CaptureFixture[str]
) -> None:
    receiver.baud = 38400  # the F9P's factory default
    rc = main(configure(receiver, "--baud", "38400", "--profile", "f9p-raw"))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert [r.name for r in receiver.received] == ["CFG-VALSET", "CFG-VALSET"]
    assert [r.line_baud for r in receiver.received] == [38400, 115200]


def test_dry_run_hex_matches_pyubx2_and_opens_nothing(
    capsys: pytest.CaptureFixture[str],
) -> None:
    rc = main(["configure", "--port", "/dev/does-not-exist", "--dry-run", "--profile",
               "lea6t-5hz"])
    out = capsys.readouterr().out
    assert rc == 0
    frames = [bytes.fromhex(h) for h in re.findall(r"^\s+\d+ bytes: ([0-9a-f ]+)$", out, re.M)]
    assert len(frames) == 9
    expected = [
        UBXMessage("CFG", "CFG-PRT", SET, portID=1, reserved2=16, charLen=3, parity=4,
                   nStopBits=0, baudRate=57600, inUBX=1, outUBX=1),
        UBXMessage("CFG", "CFG-RATE", SET, measRate=200, navRate=1, timeRef=1),
        UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x02, msgID=0x10, rateUART1=1),
        UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x02, msgID=0x11, rateUART1=1),
        UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x0D, msgID=0x03, rateUART1=1),
        UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x01, msgID=0x06, rateUART1=1),
        UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x01, msgID=0x30, rateUART1=5),
    ]
    assert frames[:7] == [bytes(m.serialize()) for m in expected]
    # The save-everything command as u-blox documents it, byte for byte.
    assert frames[8].hex(" ") == (
        "b5 62 06 09 0d 00 00 00 00 00 ff ff 00 00 00 00 00 00 17 31 bf"
    )
    # Every frame parses back; the TP5 puts time marks on the GPS grid.
    tp5 = UBXReader.parse(frames[7])
    assert tp5.identity == "CFG-TP5" and tp5.gridUtcGnss == 1 and tp5.active == 1
    assert "[UART1 -> 57600 baud after the ACK]" in out


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--profile", "no-such-profile", "--dry-run"], "unknown profile 'no-such-profile'"),
        (["--profile", "lea6t-5hz"], "port: --port is required"),
        (["--profile", "lea6t-5hz", "--dry-run", "--retries", "-1"], "retries: must be >= 0"),
        (["--profile", "lea6t-5hz", "--dry-run", "--timeout", "0"], "timeout: must be > 0"),
        (["--profile", "lea6t-5hz", "--dry-run", "--baud", "0"], "baud: must be a positive"),
    ],
)
def test_bad_arguments_exit_2(
    args: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["configure", *args]) == 2
    assert needle in capsys.readouterr().err


def test_bad_profile_names_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[[messages]]\nname = "CFG-MSG"\nfields = { msgClass = 2, msgID = 16, '
                   'rateUART = 1 }\n')
    assert main(["configure", "--profile", str(bad), "--dry-run"]) == 2
    assert "messages[0].fields.rateUART: CFG-MSG has no field 'rateUART'" in capsys.readouterr().err


def test_missing_device_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["configure", "--port", "/dev/does-not-exist", "--profile", "lea6t-5hz"]) == 1
    assert "/dev/does-not-exist does not exist" in capsys.readouterr().err
