"""Sending CFG messages to a receiver one by one and checking each ACK-ACK / ACK-NAK reply.

The exchange per message: drop stale input, write the frame, read until an ACK-ACK or ACK-NAK
whose payload names the message's class and id arrives or the timeout passes; on a timeout send
again, up to ``retries`` more times. A NAK is final (the receiver understood and refused; sending
the same bytes again cannot help).

A message that changes the baud rate of the port we are talking through (CFG-PRT on UART1, or a
CFG-VALSET of ``CFG_UART1_BAUDRATE``) is acknowledged at the OLD baud rate; only then does the
receiver switch. So after its ACK the port is reopened at the new rate before the next message.
If that ACK is lost, the receiver may or may not have switched: the next attempt is made at the
new rate (the message is idempotent, so an ACK there proves the switch), the one after at the
old rate, and so on. If a baud change cannot be confirmed the remaining messages are skipped,
because nothing sent at a guessed rate can be trusted.

If a message is refused or never acknowledged, a final CFG-CFG (save) is skipped so that a
partial configuration is not written to flash.

This module is the exchange only, over any :class:`Link`; the serial port behind the command is
:class:`groundstation.serialport.SerialLink`, and ``groundstation configure`` (the command) is
``commands/configure.py``.
"""

from __future__ import annotations

import enum
import logging
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Protocol

from groundstation.ubx.cfg import ACK_ACK_ID, ACK_CLASS, ACK_NAK_ID, CfgMessage
from groundstation.ubx.framer import UbxFramer

log = logging.getLogger("groundstation.configure")

DEFAULT_TIMEOUT_S = 1.5
DEFAULT_RETRIES = 2
DEFAULT_SETTLE_S = 0.1
READ_SLICE_S = 0.05  # longest single blocking read; the ACK deadline is checked between reads


class Link(Protocol):
    """A byte link to the receiver that can change its baud rate."""

    @property
    def baud(self) -> int:
        """The baud rate the link is running at."""
        ...

    def write(self, data: bytes) -> None:
        """Send bytes and wait until they have left the host."""

    def read(self, max_wait_s: float) -> bytes:
        """Bytes received within at most ``max_wait_s`` (possibly none)."""
        ...

    def discard_input(self) -> None:
        """Drop whatever has been received and not read yet."""

    def reopen(self, baud: int) -> None:
        """Close the port and open it again at ``baud``."""


class Outcome(enum.StrEnum):
    """How one message ended."""

    ACK = "ACK"
    NAK = "NAK"
    TIMEOUT = "timeout"
    SKIPPED = "skipped"


@dataclass(frozen=True, slots=True)
class MessageResult:
    """What happened to one message.

    Attributes:
        message: the message.
        outcome: ACK, NAK, timeout (no reply after every attempt) or skipped (not sent).
        attempts: how many times it was written (0 if skipped).
        elapsed_s: from the first write to the outcome.
        baud: the link's baud rate after the message (differs from before on a baud change).
        detail: why, for anything but a plain ACK.
    """

    message: CfgMessage
    outcome: Outcome
    attempts: int
    elapsed_s: float
    baud: int
    detail: str = ""

    @property
    def ok(self) -> bool:
        """True if the receiver acknowledged the message."""
        return self.outcome is Outcome.ACK


def send_messages(
    link: Link,
    messages: Iterable[CfgMessage],
    *,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    retries: int = DEFAULT_RETRIES,
    follow_baud: bool = True,
    settle_s: float = DEFAULT_SETTLE_S,
) -> Iterator[MessageResult]:
    """Send each message and yield its result as soon as it is known.

    Args:
        link: the open link to the receiver.
        messages: in sending order.
        timeout_s: how long to wait for the ACK of one attempt.
        retries: further attempts after a timeout (not after a NAK).
        follow_baud: reopen the link at the new rate after a message that changes UART1's baud
            (false when connected through another port, e.g. USB, which the change leaves alone).
        settle_s: pause after reopening, while the receiver's UART switches.
    """
    if timeout_s <= 0 or retries < 0:
        raise ValueError("timeout_s must be > 0 and retries >= 0")
    framer = UbxFramer()
    failed: CfgMessage | None = None
    stop_reason = ""
    for msg in messages:
        if stop_reason:
            yield MessageResult(msg, Outcome.SKIPPED, 0, 0.0, link.baud, stop_reason)
            continue
        if msg.name == "CFG-CFG" and failed is not None:
            yield MessageResult(
                msg, Outcome.SKIPPED, 0, 0.0, link.baud,
                f"not saving a partial configuration (message {failed.index} {failed.name} "
                "failed)",
            )
            continue
        new_baud = msg.uart1_baud if follow_baud else None
        changes_baud = new_baud is not None and new_baud != link.baud
        old_baud = link.baud
        if new_baud is not None and changes_baud:
            result = _send_baud_change(link, framer, msg, new_baud, timeout_s, retries, settle_s)
        else:
            result = _send_plain(link, framer, msg, timeout_s, retries)
        if not result.ok:
            failed = failed or msg
            if changes_baud and result.outcome is Outcome.TIMEOUT:
                stop_reason = (
                    f"message {msg.index} ({msg.name}) should have switched the port from "
                    f"{old_baud} to {new_baud} baud and was acknowledged at neither"
                )
            elif result.outcome is Outcome.TIMEOUT and framer.stats.frames == 0:
                stop_reason = (
                    f"no valid UBX frame received at all at {link.baud} baud: wrong --baud, "
                    "wrong port, or a link that only carries data from the receiver"
                )
            if stop_reason:
                log.warning("stopping: %s", stop_reason)
        yield result


def _send_plain(
    link: Link, framer: UbxFramer, msg: CfgMessage, timeout_s: float, retries: int
) -> MessageResult:
    start = time.monotonic()
    outcome = Outcome.TIMEOUT
    attempt = 0
    for attempt in range(1, retries + 2):
        outcome = _attempt(link, framer, msg, timeout_s)
        if outcome is not Outcome.TIMEOUT:
            break
        log.info("%s (%d): no reply to attempt %d", msg.name, msg.index, attempt)
    detail = {
        Outcome.ACK: "",
        Outcome.NAK: "refused by the receiver (ACK-NAK): unsupported message or bad value",
        Outcome.TIMEOUT: f"no ACK within {timeout_s:g} s on any of {attempt} attempts",
    }[outcome]
    return MessageResult(msg, outcome, attempt, time.monotonic() - start, link.baud, detail)


def _send_baud_change(
    link: Link, framer: UbxFramer, msg: CfgMessage, new_baud: int,
    timeout_s: float, retries: int, settle_s: float,
) -> MessageResult:
    start = time.monotonic()
    old_baud = link.baud
    for attempt in range(1, retries + 2):
        at_old = link.baud == old_baud
        outcome = _attempt(link, framer, msg, timeout_s)
        if outcome is Outcome.NAK:
            return MessageResult(
                msg, outcome, attempt, time.monotonic() - start, link.baud,
                f"refused by the receiver (ACK-NAK); port stays at {link.baud} baud",
            )
        if outcome is Outcome.ACK:
            detail = ""
            if at_old:
                _switch(link, framer, new_baud, settle_s)
            else:
                detail = f"ACK at {old_baud} baud lost; acknowledged at {new_baud} baud"
            log.info("%s (%d): now at %d baud", msg.name, msg.index, new_baud)
            return MessageResult(
                msg, outcome, attempt, time.monotonic() - start, link.baud, detail
            )
        # No ACK: the receiver may have switched anyway. Try the other rate next.
        other = new_baud if at_old else old_baud
        log.info(
            "%s (%d): no reply to attempt %d at %d baud; trying %d baud",
            msg.name, msg.index, attempt, link.baud, other,
        )
        if attempt <= retries:
            _switch(link, framer, other, settle_s)
    return MessageResult(
        msg, Outcome.TIMEOUT, retries + 1, time.monotonic() - start, link.baud,
        f"no ACK within {timeout_s:g} s at {old_baud} or {new_baud} baud "
        f"({retries + 1} attempts)",
    )


def _switch(link: Link, framer: UbxFramer, baud: int, settle_s: float) -> None:
    link.reopen(baud)
    framer.flush()  # a frame cut by the switch is damage, not a reason to wait
    time.sleep(settle_s)
    link.discard_input()


def _attempt(link: Link, framer: UbxFramer, msg: CfgMessage, timeout_s: float) -> Outcome:
    """Write once and wait up to ``timeout_s`` for the matching ACK-ACK or ACK-NAK."""
    link.discard_input()
    link.write(msg.frame)
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        chunk = link.read(min(left, READ_SLICE_S))
        if not chunk:
            continue
        for frame in framer.feed(chunk, time.time_ns()):
            if frame.cls != ACK_CLASS or frame.payload[:2] != bytes((msg.cls, msg.id)):
                continue
            if frame.id == ACK_ACK_ID:
                return Outcome.ACK
            if frame.id == ACK_NAK_ID:
                return Outcome.NAK
    return Outcome.TIMEOUT
