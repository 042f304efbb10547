"""The monitor's alerts: raised once with a message and data, updated while raised, cleared once.

Each raise and clear is an event (``alert.raised`` / ``alert.cleared``); the names are the
catalogue's (:data:`groundstation.events.ALERTS`).
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


class Alerts:
    """The alerts currently raised."""

    def __init__(self) -> None:
        self.active: dict[str, Alert] = {}

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

    def clear(self, name: str, now_ns: int, events: list[Event]) -> None:
        """Clear ``name`` if raised (an event saying for how long it was)."""
        alert = self.active.pop(name, None)
        if alert is None:
            return
        events.append(Event(kinds.ALERT_CLEARED, now_ns, f"cleared: {alert.message}", "info",
                            {"alert": name, "duration_s": (now_ns - alert.since_ns) / 1e9}))

    def messages(self) -> tuple[str, ...]:
        return tuple(sorted(a.message for a in self.active.values()))
