"""GPS broadcast ephemerides of a recording, from RXM-SFRB, RXM-SFRBX (parity checked) and AID-EPH.

The receiver-specific part lives here (where each message keeps its navigation words, and how
u-blox presents LNAV parity); decoding the words is :mod:`groundstation.gnss.lnav`'s job.
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from groundstation.gnss import lnav
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.ubx.fastraw import FrameIndex

RXM_SFRB = (0x02, 0x11)
RXM_SFRBX = (0x02, 0x13)
AID_EPH = (0x0B, 0x31)


@dataclass(slots=True)
class NavResult:
    """What the navigation messages of a recording gave.

    Attributes:
        ephemerides: distinct ephemerides in the order they were completed.
        iono_utc: the last subframe-4 page-18 parameters seen, if any.
        subframes: subframes used, by source message.
        parity_errors: RXM-SFRBX GPS subframes rejected for a parity error.
        decode_errors: subframe sets rejected by the LNAV decoder (preamble, IODE mismatch).
    """

    ephemerides: list[BroadcastEphemeris] = field(default_factory=list)
    iono_utc: lnav.IonoUtc | None = None
    subframes: Counter[str] = field(default_factory=Counter)
    parity_errors: int = 0
    decode_errors: int = 0


def ublox_sfrbx_data_words(words: tuple[int, ...]) -> tuple[int, ...] | None:
    """Data words of one GPS L1 C/A RXM-SFRBX subframe, or ``None`` if a parity check fails.

    u-blox delivers each 30-bit word with its data bits already polarity-corrected and the
    parity bits complemented whenever the previous word's ``D30`` was 1 (checked on every
    real M8 recording we have); the first word follows a word 10, whose ``D29``/``D30`` are 0.
    """
    d29 = d30 = 0
    out = []
    for w in words:
        data = (w >> 6) & 0xFFFFFF
        par = w & 0x3F
        if lnav.parity_bits(data, d29, d30) ^ (0x3F if d30 else 0) != par:
            return None
        out.append(data)
        d29, d30 = (par >> 1) & 1, par & 1
    return tuple(out)


def _aid_eph_subframes(payload: bytes) -> list[tuple[int, ...]] | None:
    """Subframes 1-3 (ten data words each) rebuilt from an AID-EPH payload, or ``None``."""
    if len(payload) < 104:
        return None
    vals = struct.unpack_from("<26I", payload)
    how = vals[1] & 0xFFFFFF
    if how == 0:
        return None
    out = []
    for sf in (1, 2, 3):
        body = tuple(w & 0xFFFFFF for w in vals[2 + 8 * (sf - 1) : 2 + 8 * sf])
        tlm = lnav.PREAMBLE << 16
        out.append((tlm, (how & ~(0x7 << 2)) | (sf << 2), *body))
    return out


def collect_ephemerides(data: bytes | memoryview, index: FrameIndex, week_hint: int) -> NavResult:
    """Every distinct GPS ephemeris in a recording, in stream order.

    Args:
        data: the recording.
        index: its frame index.
        week_hint: a full GPS week near the data (resolves the 10-bit broadcast week).
    """
    result = NavResult()
    asm = lnav.EphemerisAssembler(week_hint)
    seen: set[tuple[int, tuple[int, ...]]] = set()
    seen_raw: set[tuple[int, tuple[int, ...]]] = set()
    # Subframe 4 repeats with only the HOW changing: decode each distinct body once (a 10-hour
    # LEA-6T flight has 11 000 subframes 4; RXM-SFRB has no page filter before decoding).
    iono_seen: dict[tuple[int, ...], lnav.IonoUtc | None] = {}
    mv = memoryview(data)
    wanted = ((index.cls == 0x02) & ((index.id == 0x11) | (index.id == 0x13))) | (
        (index.cls == 0x0B) & (index.id == 0x31)
    )
    for i in np.flatnonzero(wanted).tolist():
        key = (int(index.cls[i]), int(index.id[i]))
        s = int(index.start[i]) + 6
        payload = bytes(mv[s : s + int(index.length[i])])
        subframes: list[tuple[int, tuple[int, ...]]] = []
        if key == RXM_SFRBX:
            if len(payload) < 48 or payload[0] != 0 or payload[2] != 0 or payload[4] != 10:
                continue
            # GPS L1 C/A LNAV only (sigId 0; L2C and L5 carry CNAV). Subframes 1-3 repeat
            # every 30 s with only the HOW changing: check each once. Subframe 4 matters only
            # for page 18 (ionosphere, UTC).
            raw_words = struct.unpack_from("<10I", payload, 8)
            sid = (raw_words[1] >> 8) & 0x7
            if sid == 5 or (sid == 4 and (raw_words[2] >> 22) & 0x3F != 56):
                continue
            if sid in (1, 2, 3) and (payload[1], (sid, *raw_words[2:])) in seen_raw:
                continue
            words = ublox_sfrbx_data_words(raw_words)
            if words is None:
                result.parity_errors += 1
                continue
            # Only a copy that passed parity makes later copies duplicates: a bit error in the
            # TLM or HOW (not part of the key) must not hide the next, clean copy.
            seen_raw.add((payload[1], (sid, *raw_words[2:])))
            subframes.append((payload[1], words))
            source = "RXM-SFRBX"
        elif key == RXM_SFRB:
            if len(payload) < 42 or not 1 <= payload[1] <= 32:
                continue
            words = tuple(map((0xFFFFFF).__and__, struct.unpack_from("<10I", payload, 2)))
            subframes.append((payload[1], words))
            source = "RXM-SFRB"
        else:
            rebuilt = _aid_eph_subframes(payload)
            sv = int.from_bytes(payload[:4], "little") if len(payload) >= 4 else 0
            if rebuilt is None or not 1 <= sv <= 32:
                continue
            subframes.extend((sv, w) for w in rebuilt)
            source = "AID-EPH"
        for sv, words in subframes:
            if (words[0] >> 16) & 0xFF != lnav.PREAMBLE:
                result.decode_errors += 1
                continue
            sid = lnav.subframe_id(words)
            if sid == 4:
                body = tuple(words[2:])
                if body in iono_seen:
                    iono = iono_seen[body]
                else:
                    try:
                        iono = lnav.decode_iono_utc(words)
                    except lnav.LnavError:
                        iono = None
                    iono_seen[body] = iono
                if iono is not None:
                    result.iono_utc = iono
                continue
            if sid not in (1, 2, 3):
                continue
            # Subframes 1-3 repeat every 30 s with only the HOW changing: decode each once.
            dedup = (sv, (sid, *words[2:]))
            if dedup in seen and source != "AID-EPH":
                continue
            seen.add(dedup)
            result.subframes[source] += 1
            before = asm.errors
            eph = asm.add(sv, words)
            result.decode_errors += asm.errors - before
            if eph is not None:
                result.ephemerides.append(eph)
    return result
