"""BeiDou D1 navigation message (BDS-SIS-ICD-2.1, section 5.2): ephemeris of the MEO and IGSO
satellites from subframes 1-3.

A subframe is ten 30-bit words (word 1: 26 data bits and 4 parity bits; words 2-10: 22 data
bits and 8 parity bits). Field positions below count bits from the start of the 300-bit
subframe *with* the parity bits in place, so a field that straddles two words has two parts.
The GEO satellites' D2 message (ten pages of subframe 1) is not decoded here.

API: :func:`subframe_from_ublox`, :func:`decode_ephemeris`, :class:`D1Assembler`.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping, Sequence

from groundstation.gnss.ephemeris import GPS_PI
from groundstation.gnss.kepler import KeplerEphemeris

SUBFRAME_BITS = 300
BDT_EPOCH = dt.datetime(2006, 1, 1, tzinfo=dt.UTC)
"""BDT week 0 began here (on BDT's own scale, 14 s behind GPS time)."""
URA_NOMINAL_M = (2.0, 2.8, 4.0, 5.7, 8.0, 11.3, 16.0, 32.0, 64.0, 128.0, 256.0, 512.0, 1024.0,
                 2048.0, 4096.0, 8192.0)  # fmt: skip
"""Nominal user range accuracy (m) of each URA index, as RTKLIB writes it."""
_HALF_WEEK_S = 302_400


def is_geo(prn: int) -> bool:
    """GEO satellites (C01-C05, C59-C63) broadcast D2, the others D1."""
    return prn <= 5 or prn >= 59


def subframe_from_ublox(words: Sequence[int]) -> int:
    """The 300-bit subframe of a u-blox BeiDou RXM-SFRBX (ten words, 30 bits each at the
    bottom of every 32-bit word)."""
    bits = 0
    for w in words[:10]:
        bits = (bits << 30) | (w & 0x3FFFFFFF)
    return bits


def _field(sf: int, parts: tuple[tuple[int, int], ...], signed: bool = False) -> int:
    raw, n = 0, 0
    for start, length in parts:
        raw = (raw << length) | ((sf >> (SUBFRAME_BITS - start - length)) & ((1 << length) - 1))
        n += length
    if signed and raw >> (n - 1):
        raw -= 1 << n
    return raw


def subframe_id(sf: int) -> int:
    return _field(sf, ((15, 3),))


def sow(sf: int) -> int:
    """Seconds of the BDT week at the start of the subframe."""
    return _field(sf, ((18, 8), (30, 12)))


def decode_ephemeris(subframes: Mapping[int, int], prn: int) -> KeplerEphemeris | None:
    """Subframes 1-3 → ephemeris; ``None`` when they are not three consecutive subframes of one
    frame or ``toc`` differs from ``toe``."""
    if any(k not in subframes for k in (1, 2, 3)):
        return None
    s1, s2, s3 = subframes[1], subframes[2], subframes[3]
    if (subframe_id(s1), subframe_id(s2), subframe_id(s3)) != (1, 2, 3):
        return None
    sow1 = sow(s1)
    if sow(s2) != sow1 + 6 or sow(s3) != sow1 + 12:
        return None
    sc = GPS_PI

    def f(sf: int, *parts: tuple[int, int], s: bool = False) -> int:
        return _field(sf, parts, s)

    toc_s = f(s1, (73, 9), (90, 8)) * 8.0
    toe_s = f(s2, (290, 2)) * 2**15 * 8.0 + f(s3, (42, 10), (60, 5)) * 8.0
    if toc_s != toe_s:
        return None
    week_tx = f(s1, (60, 13))
    # The week of toe: the one that puts toe within half a week of the transmission time.
    # (RTKLIB-EX moves the week the other way; it matters only across a week rollover.)
    week = week_tx
    if toe_s < sow1 - _HALF_WEEK_S:
        week += 1
    elif toe_s > sow1 + _HALF_WEEK_S:
        week -= 1
    return KeplerEphemeris(
        system="C",
        prn=prn,
        week=week,
        toc_s=toc_s,
        toe_s=toe_s,
        af0_s=f(s1, (225, 7), (240, 17), s=True) * 2.0**-33,
        af1_s_s=f(s1, (257, 5), (270, 17), s=True) * 2.0**-50,
        af2_s_s2=f(s1, (214, 11), s=True) * 2.0**-66,
        iode=int(toc_s / 720.0) % 240,  # AODE as RTKLIB derives it (per the ICD)
        iodc=f(s1, (43, 5)),
        sqrt_a_sqrt_m=f(s2, (250, 12), (270, 20)) * 2.0**-19,
        e=f(s2, (132, 10), (150, 22)) * 2.0**-33,
        i0_rad=f(s3, (65, 17), (90, 15), s=True) * 2.0**-31 * sc,
        omega0_rad=f(s3, (211, 21), (240, 11), s=True) * 2.0**-31 * sc,
        omega_rad=f(s3, (251, 11), (270, 21), s=True) * 2.0**-31 * sc,
        m0_rad=f(s2, (92, 20), (120, 12), s=True) * 2.0**-31 * sc,
        delta_n_rad_s=f(s2, (42, 10), (60, 6), s=True) * 2.0**-43 * sc,
        omega_dot_rad_s=f(s3, (131, 11), (150, 13), s=True) * 2.0**-43 * sc,
        idot_rad_s=f(s3, (189, 13), (210, 1), s=True) * 2.0**-43 * sc,
        cuc_rad=f(s2, (66, 16), (90, 2), s=True) * 2.0**-31,
        cus_rad=f(s2, (180, 18), s=True) * 2.0**-31,
        crc_m=f(s2, (198, 4), (210, 14), s=True) * 2.0**-6,
        crs_m=f(s2, (224, 8), (240, 10), s=True) * 2.0**-6,
        cic_rad=f(s3, (105, 7), (120, 11), s=True) * 2.0**-31,
        cis_rad=f(s3, (163, 9), (180, 9), s=True) * 2.0**-31,
        tgd1_s=f(s1, (98, 10), s=True) * 0.1e-9,
        tgd2_s=f(s1, (108, 4), (120, 6), s=True) * 0.1e-9,
        accuracy_m=URA_NOMINAL_M[min(f(s1, (48, 4)), 15)],
        health=f(s1, (42, 1)),
        data_source=0,
        tx_s=float(sow1 + (week_tx - week) * 604_800),
    )


class D1Assembler:
    """Keeps each satellite's latest subframes 1-3; when a subframe 3 arrives, decodes them and
    yields the ephemeris unless its ``toe`` repeats the satellite's last one."""

    def __init__(self) -> None:
        self._subframes: dict[int, dict[int, int]] = {}
        self._last: dict[int, tuple[int, float]] = {}

    def add(self, prn: int, sf: int) -> KeplerEphemeris | None:
        """Add one D1 subframe of satellite ``prn``."""
        sid = subframe_id(sf)
        if not 1 <= sid <= 3:
            return None
        store = self._subframes.setdefault(prn, {})
        store[sid] = sf
        if sid != 3:
            return None
        eph = decode_ephemeris(store, prn)
        if eph is None or self._last.get(prn) == (eph.week, eph.toe_s):
            return None
        self._last[prn] = (eph.week, eph.toe_s)
        return eph


def bdt_datetime(week: int, seconds: float) -> dt.datetime:
    """Calendar time on the BDT scale of a BDT week and second."""
    return BDT_EPOCH + dt.timedelta(weeks=week, seconds=seconds)
