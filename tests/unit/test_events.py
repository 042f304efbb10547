"""The event-kind catalogue is the wire format: every kind and alert name the Zenoh document
promises is catalogued, and every catalogued one is documented."""

from __future__ import annotations

import re
from pathlib import Path

from groundstation import events as kinds

DOC = Path(__file__).resolve().parents[2] / "docs" / "zenoh.md"


def documented() -> tuple[set[str], set[str]]:
    text = DOC.read_text(encoding="utf-8")
    table = text[text.index("## Event kinds"):]
    table = table[: table.index("\n\n", table.index("| kind |"))]
    names: set[str] = set()
    alerts: set[str] = set()
    for line in table.splitlines()[2:]:
        first, rest = line.split("|")[1], line.split("|", 2)[2]
        names.update(re.findall(r"`([a-z_]+\.[a-z_]+)`", first))
        if "alert.raised" in first:
            alerts.update(re.findall(r"`([a-z_]+)`", rest.split("(+ details)")[0]))
    return names, alerts


def test_documented_kinds_are_catalogued_and_back() -> None:
    names, _ = documented()
    catalogued = set(kinds.CATALOGUE) | {kinds.behind("recorder"), kinds.caught_up("recorder")}
    assert names - catalogued == set()
    assert catalogued - names == set()


def test_documented_alerts_are_catalogued_and_back() -> None:
    _, alerts = documented()
    alerts -= {"alert", "likely_cause", "baud_or_noise", "nmea_only", "error", "errno"}
    assert alerts == set(kinds.ALERTS)


def test_sink_kinds() -> None:
    assert kinds.sink_of(kinds.behind("recorder"), kinds.BEHIND_SUFFIX) == "recorder"
    assert kinds.sink_of(kinds.caught_up("zenoh"), kinds.BEHIND_SUFFIX) is None
    assert all(k.name == name for name, k in kinds.CATALOGUE.items())
