"""A receiver antenna's L1 phase-centre offset from an ANTEX file the user supplies (IGS's
``igs20.atx``, a calibration service's file), for the base antenna.

ANTEX (IGS, version 1.4) lists antennas between ``START OF ANTENNA`` and ``END OF ANTENNA``;
``TYPE / SERIAL NO`` names the type (columns 1-16) and radome (17-20), and each frequency's
block (``START OF FREQUENCY``, ``G01`` for GPS L1) gives its mean phase-centre offset from the
antenna reference point as ``NORTH / EAST / UP`` in millimetres (3F10.2). What follows (the
elevation- and azimuth-dependent variations) is not read: for a survey antenna they are a few
millimetres at most on L1, and a position given to the millimetre only matters through the
offset, which is centimetres to a decimetre (the phase centre sits above the ARP).

The engine works with the phase centre: the base's antenna reference point plus this offset.
"""

from __future__ import annotations

import gzip
from pathlib import Path

from groundstation.errors import ConfigError

L1 = "G01"
"""ANTEX frequency code of GPS L1, the LEA-6T's signal."""


def antenna_name(text: str) -> tuple[str, str]:
    """(type, radome) of a name as users write it: ``TRM55971.00 NONE``, ``TRM55971.00`` (no
    radome: NONE) or the 20 columns of a RINEX header."""
    parts = text.split()
    if not parts:
        return "", "NONE"
    return parts[0].upper(), (parts[1].upper() if len(parts) > 1 else "NONE")


def _read_text(path: Path, option: str) -> str:
    try:
        data = path.read_bytes()
        if data[:2] == b"\x1f\x8b":
            data = gzip.decompress(data)
    except (OSError, EOFError, gzip.BadGzipFile) as err:
        raise ConfigError(option, f"{path}: cannot read it ({err})") from err
    text = data.decode("latin-1")
    if "ANTEX VERSION / SYST" not in text[:400]:
        raise ConfigError(option, f"{path}: not an ANTEX file (no ANTEX VERSION / SYST header "
                          "line)")
    return text


def l1_offset(path: Path, antenna: str, option: str = "--antex",
              antenna_option: str = "--base-antenna") -> tuple[float, float, float]:
    """The antenna's GPS L1 phase-centre offset (east, north, up) in metres.

    Raises:
        ConfigError: naming ``option``: not an ANTEX file; naming ``antenna_option``: the
            antenna is not in it, or has no GPS L1 calibration (the types nearest by name are
            suggested).
    """
    want = antenna_name(antenna)
    text = _read_text(path, option)
    names: list[tuple[str, str]] = []
    current: tuple[str, str] | None = None
    in_l1 = False
    for line in text.splitlines():
        label = line[60:].strip()
        if label == "TYPE / SERIAL NO":
            current = (line[0:16].strip().upper(), line[16:20].strip().upper() or "NONE")
            names.append(current)
        elif label == "START OF FREQUENCY":
            in_l1 = current == want and line[3:6].strip() == L1
        elif label == "NORTH / EAST / UP" and in_l1:
            try:
                north, east, up = (float(line[i:i + 10]) / 1000.0 for i in (0, 10, 20))
            except ValueError as err:
                raise ConfigError(option, f"{path}: unreadable NORTH / EAST / UP of "
                                  f"{' '.join(want)}: {line[:30].strip()!r}") from err
            return east, north, up
        elif label == "END OF ANTENNA":
            current, in_l1 = None, False
    if want in names:
        raise ConfigError(antenna_option, f"{' '.join(want)} has no GPS L1 ({L1}) calibration "
                          f"in {path.name}")
    near = sorted({f"{t} {r}" for t, r in names if t[:5] == want[0][:5]})[:5]
    some = sorted({f"{t} {r}" for t, r in names})
    raise ConfigError(antenna_option, (
        f"{' '.join(want)} is not in {path.name} ({len(names)} antennas"
        + (f"; of a similar name: {', '.join(near)}" if near else
           f": {', '.join(some[:5])}{' ...' if len(some) > 5 else ''}" if some else "")
        + "): give the type as the file spells it, radome after a space (NONE without one)"))


def rinex_antenna(path: Path) -> str | None:
    """The antenna type (and radome) in a RINEX observation header's ``ANT # / TYPE`` line
    (columns 21-40), None when there is none or it is blank."""
    try:
        opener = gzip.open if path.name.lower().endswith(".gz") else open
        with opener(path, "rt", encoding="latin-1") as f:
            for _, line in zip(range(200), f, strict=False):
                label = line[60:].strip()
                if label == "ANT # / TYPE":
                    name = line[20:40].strip()
                    return name or None
                if label == "END OF HEADER":
                    return None
    except (OSError, EOFError, gzip.BadGzipFile):
        return None
    return None
