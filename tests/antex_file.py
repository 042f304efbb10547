"""A small ANTEX 1.4 file written as the format describes it (fixed columns, labels from column
61), for the tests of the base antenna's phase-centre offset."""

from __future__ import annotations

from pathlib import Path


def _line(content: str, label: str) -> str:
    return f"{content:<60}{label}\n"


def antenna_block(kind: str, radome: str, offsets_mm: dict[str, tuple[float, float, float]],
                  serial: str = "") -> str:
    """One antenna: ``offsets_mm`` maps a frequency code (``G01``) to north/east/up in mm,
    each followed by a line of variations (not read)."""
    text = _line("", "START OF ANTENNA")
    text += _line(f"{kind:<16}{radome:<4}{serial:<20}", "TYPE / SERIAL NO")
    text += _line("ROBOT               Test lab                 1    01-JAN-20",
                  "METH / BY / # / DATE")
    text += _line("     5.0", "DAZI")
    text += _line("     0.0  90.0   5.0", "ZEN1 / ZEN2 / DZEN")
    text += _line(f"{len(offsets_mm):6d}", "# OF FREQUENCIES")
    for freq, (n, e, u) in offsets_mm.items():
        text += _line(f"   {freq}", "START OF FREQUENCY")
        text += _line(f"{n:10.2f}{e:10.2f}{u:10.2f}", "NORTH / EAST / UP")
        text += "   NOAZI" + "".join(f"{v:8.2f}" for v in [0.0] * 19) + "\n"
        text += _line(f"   {freq}", "END OF FREQUENCY")
    return text + _line("", "END OF ANTENNA")


def write_antex(path: Path, *blocks: str) -> Path:
    """An ANTEX file with a header and the antennas ``blocks``."""
    head = (_line("     1.4            M", "ANTEX VERSION / SYST")
            + _line("A", "PCV TYPE / REFANT") + _line("", "END OF HEADER"))
    path.write_text(head + "".join(blocks))
    return path
