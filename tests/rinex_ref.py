"""A minimal RINEX 3 observation reader for comparing against RTKLIB's output in tests."""

from __future__ import annotations

import datetime as dt
import gzip
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path

from groundstation.gpstime import GPS_EPOCH


@dataclass
class RinexObs:
    obs_types: dict[str, list[str]] = field(default_factory=dict)
    # epoch GPS ns -> satellite -> code -> (value, lli, ssi)
    epochs: dict[int, dict[str, dict[str, tuple[float, int, int]]]] = field(default_factory=dict)
    events: list[int] = field(default_factory=list)


def epoch_ns(fields: list[str]) -> int:
    y, mo, d, h, mi = (int(x) for x in fields[:5])
    sec = Decimal(fields[5])
    day = dt.datetime(y, mo, d, h, mi, tzinfo=dt.UTC) - GPS_EPOCH
    return (day.days * 86400 + day.seconds) * 1_000_000_000 + int(sec * 1_000_000_000)


def read_rinex3_obs(path: Path) -> RinexObs:
    opener = gzip.open if path.suffix == ".gz" else open
    out = RinexObs()
    with opener(path, "rt") as f:
        last_sys = ""
        for line in f:
            label = line[60:].strip()
            if label == "SYS / # / OBS TYPES":
                if line[0] != " ":
                    last_sys = line[0]
                    out.obs_types[last_sys] = []
                out.obs_types[last_sys] += line[7:60].split()
            if label == "END OF HEADER":
                break
        lines = f.readlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        i += 1
        if not line.startswith(">"):
            continue
        parts = line[1:].split()
        flag, n = int(parts[6]), int(parts[7])
        t = epoch_ns(parts)
        if flag == 5:
            out.events.append(t)
            i += n
            continue
        if flag > 1:
            i += n
            continue
        sats: dict[str, dict[str, tuple[float, int, int]]] = {}
        for _ in range(n):
            rec = lines[i].rstrip("\n")
            i += 1
            sat = rec[:3].replace(" ", "0")
            vals: dict[str, tuple[float, int, int]] = {}
            for k, code in enumerate(out.obs_types.get(sat[0], [])):
                fld = rec[3 + 16 * k : 3 + 16 * (k + 1)]
                if not fld[:14].strip():
                    continue
                lli = int(fld[14]) if len(fld) > 14 and fld[14].strip() else 0
                ssi = int(fld[15]) if len(fld) > 15 and fld[15].strip() else 0
                vals[code] = (float(fld[:14]), lli, ssi)
            sats[sat] = vals
        out.epochs[t] = sats
    return out
