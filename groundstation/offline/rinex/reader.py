"""Reading RINEX 3 observation files back, text-exact (tests, comparisons with other converters)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

# -- reading back (tests, comparisons with other converters) -----------------------------------


@dataclass(frozen=True, slots=True)
class ObsEpoch:
    """One epoch record of a RINEX 3 observation file, as text-exact values."""

    time: str
    flag: int
    sats: dict[str, dict[str, tuple[str, str]]]


def read_obs3(path: str | Path) -> tuple[dict[str, list[str]], list[ObsEpoch]]:
    """Parse a RINEX 3 observation file (``.gz`` too): obs types per system, and epochs.

    Values are kept as the 14-character text and the LLI character, so comparisons are exact.
    """
    import gzip

    p = Path(path)
    opener = gzip.open if p.suffix == ".gz" else open
    types: dict[str, list[str]] = {}
    epochs: list[ObsEpoch] = []
    with opener(p, "rt", encoding="ascii") as f:
        last_sys = ""
        for line in f:
            label = line[60:].strip()
            if label == "SYS / # / OBS TYPES":
                if line[0] != " ":
                    last_sys = line[0]
                    types[last_sys] = []
                types[last_sys].extend(line[7:60].split())
            elif label == "END OF HEADER":
                break
        cur: ObsEpoch | None = None
        for line in f:
            if line.startswith(">"):
                y, mo, d, hh, mi, sec = line[2:29].split()
                whole, frac = sec.split(".")
                t = f"{int(y):04d} {int(mo):02d} {int(d):02d} {int(hh):02d} {int(mi):02d} "
                cur = ObsEpoch(t + f"{int(whole):02d}.{frac}", int(line[31]), {})
                epochs.append(cur)
                continue
            if cur is None or len(line) < 3:
                continue
            sat = line[:3]
            tl = types.get(sat[0], [])
            rec: dict[str, tuple[str, str]] = {}
            body = line[3:].rstrip("\n")
            for j, t in enumerate(tl):
                fld = body[16 * j : 16 * j + 16].ljust(16)
                rec[t] = (fld[:14].strip(), fld[14].strip())
            cur.sats[sat] = rec
    return types, epochs
