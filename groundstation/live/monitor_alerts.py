"""The monitor's alerts: raised once with a message and data, updated while raised, cleared once.

Each raise and clear is an event (``alert.raised`` / ``alert.cleared``); the names are the
catalogue's (:data:`groundstation.events.ALERTS`). A cleared event says what is OK now, not the
problem again ("cleared: only 4 satellites ..." read like a new problem).

Conditions that hover around their threshold (the half-cycle fraction, the PPK-ready count) go
through :meth:`Alerts.hold`: the condition must hold for ``raise_after_s`` before the alert is
raised and be gone for ``clear_after_s`` before it is cleared, so the alert changes state a few
times per flight instead of every few seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from groundstation import events as kinds
from groundstation.records import Event


@dataclass(slots=True)
class Alert:
    name: str
    message: str
    since_ns: int
    data: dict[str, Any] = field(default_factory=dict)


@dataclass(slots=True)
class _Pending:
    """When a held condition last changed (host ns), to time the hysteresis."""

    true_since_ns: int | None = None
    false_since_ns: int | None = None


class Alerts:
    """The alerts currently raised."""

    def __init__(self) -> None:
        self.active: dict[str, Alert] = {}
        self._pending: dict[str, _Pending] = {}

    def raise_(
        self, name: str, message: str, now_ns: int, events: list[Event],
        data: dict[str, Any] | None = None,
    ) -> None:
        """Raise ``name`` (an event the first time; later calls only update the message)."""
        alert = self.active.get(name)
        if alert is not None:
            alert.message = message
            return
        self.active[name] = Alert(name, message, now_ns, data or {})
        events.append(Event(kinds.ALERT_RAISED, now_ns, message, "warning",
                            {"alert": name, **(data or {})}))

    def clear(self, name: str, now_ns: int, events: list[Event], ok: str = "") -> None:
        """Clear ``name`` if raised (an event saying what is OK now and for how long it was not).

        Args:
            ok: what is OK now ("PPK ready: 7 satellites ..."); default: the alert's name and
                its last message in the past tense.
        """
        alert = self.active.pop(name, None)
        if alert is None:
            return
        text = f"OK: {ok}" if ok else f"OK again (was: {alert.message})"
        events.append(Event(kinds.ALERT_CLEARED, now_ns, text, "info",
                            {"alert": name, "was": alert.message,
                             "duration_s": (now_ns - alert.since_ns) / 1e9}))

    def hold(
        self, name: str, condition: bool, now_ns: int, events: list[Event], *,
        message: str, ok: str, raise_after_s: float, clear_after_s: float,
        data: dict[str, Any] | None = None,
    ) -> None:
        """Raise ``name`` once ``condition`` has held ``raise_after_s`` (breaks shorter than
        that do not restart the wait); clear it once it has been false ``clear_after_s``
        without a break (module docstring). While raised the message follows."""
        p = self._pending.setdefault(name, _Pending())
        if condition:
            p.false_since_ns = None
            if p.true_since_ns is None:
                p.true_since_ns = now_ns
            if name in self.active:
                self.active[name].message = message
            elif now_ns - p.true_since_ns >= raise_after_s * 1e9:
                self.raise_(name, message, now_ns, events, data)
        else:
            if p.false_since_ns is None:
                p.false_since_ns = now_ns
            false_s = (now_ns - p.false_since_ns) / 1e9
            # A short break does not restart the wait for raising: a condition true 8 s in
            # every 10 is a standing problem, not a new one every 10 s.
            if false_s >= raise_after_s:
                p.true_since_ns = None
            if name in self.active and false_s >= clear_after_s:
                self.clear(name, now_ns, events, ok)

    def messages(self) -> tuple[str, ...]:
        return tuple(sorted(a.message for a in self.active.values()))
