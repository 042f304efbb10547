"""RTKLIB's RINEX 3 observations as numbers keyed by GPS time, for comparisons in tests.

Parsing is :func:`groundstation.offline.rinex.read_obs3`'s; this only converts its text-exact
values to floats and its epoch strings to GPS ns.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path

from groundstation.gpstime import GPS_EPOCH
from groundstation.offline.rinex import read_obs3


@dataclass
class RinexObs:
    obs_types: dict[str, list[str]] = field(default_factory=dict)
    # epoch GPS ns -> satellite -> code -> (value, lli)
    epochs: dict[int, dict[str, dict[str, tuple[float, int]]]] = field(default_factory=dict)
    events: list[int] = field(default_factory=list)


def epoch_ns(text: str) -> int:
    """GPS ns of a RINEX epoch ``YYYY MM DD hh mm ss.sssssss`` (GPS time scale)."""
    y, mo, d, h, mi, sec = text.split()
    day = dt.datetime(int(y), int(mo), int(d), int(h), int(mi), tzinfo=dt.UTC) - GPS_EPOCH
    return (day.days * 86400 + day.seconds) * 1_000_000_000 + int(Decimal(sec) * 1_000_000_000)


def read_rinex3_obs(path: Path) -> RinexObs:
    types, epochs = read_obs3(path)
    out = RinexObs(obs_types=types)
    for ep in epochs:
        t = epoch_ns(ep.time)
        if ep.flag == 5:
            out.events.append(t)
        elif ep.flag <= 1:
            out.epochs[t] = {
                sat.replace(" ", "0"): {
                    code: (float(v), int(lli or 0)) for code, (v, lli) in vals.items() if v
                }
                for sat, vals in ep.sats.items()
            }
    return out
