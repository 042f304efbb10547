"""Galileo I/NAV (E1-B) pages (Galileo OS SIS ICD 2.0, section 4.3): CRC check, word assembly,
ephemeris from word types 1-5.

A nominal page is an even part (120 bits: even/odd 0, page type, 112 data bits, tail) and an odd
part (even/odd 1, page type, 16 data bits, reserved and SAR fields, CRC-24Q, ...). The CRC covers
the even part's first 114 bits and the odd part's first 82; the 128-bit *word* is the 112 even
data bits followed by the 16 odd ones, its first six bits the word type.

API: :func:`page_from_ublox`, :func:`word_from_page`, :func:`decode_ephemeris`,
:class:`InavAssembler` (feed pages, get new ephemerides).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from groundstation.gnss.ephemeris import GPS_PI
from groundstation.gnss.kepler import KeplerEphemeris
from groundstation.ubx.framer import crc24q

WORD_BITS = 128
GST_WEEK_OFFSET = 1024
"""GST week 0 began at GPS week 1024 (1999-08-22)."""
_HALF_WEEK_S = 302_400


def page_from_ublox(words: Sequence[int]) -> int:
    """The 256-bit page (even half in the top 128 bits) of a u-blox E1-B RXM-SFRBX's 8 words."""
    page = 0
    for w in words[:8]:
        page = (page << 32) | (w & 0xFFFFFFFF)
    return page


def _bits(value: int, width: int, start: int, n: int) -> int:
    return (value >> (width - start - n)) & ((1 << n) - 1)


def word_from_page(page: int) -> int | None:
    """The 128-bit data word of a nominal page whose CRC checks, else ``None`` (alert pages,
    halves out of order and CRC failures)."""
    if _bits(page, 256, 0, 1) != 0 or _bits(page, 256, 128, 1) != 1:
        return None
    if _bits(page, 256, 1, 1) or _bits(page, 256, 129, 1):
        return None
    # 4 zero bits pad the 196 protected bits to 25 bytes.
    protected = (_bits(page, 256, 0, 114) << 82) | _bits(page, 256, 128, 82)
    if crc24q(protected.to_bytes(25, "big")) != _bits(page, 256, 210, 24):
        return None
    return (_bits(page, 256, 2, 112) << 16) | _bits(page, 256, 130, 16)


def word_type(word: int) -> int:
    return _bits(word, WORD_BITS, 0, 6)


class _Reader:
    """Sequential field reader over one word."""

    def __init__(self, word: int, start: int = 6) -> None:
        self.word, self.pos = word, start

    def u(self, n: int) -> int:
        v = _bits(self.word, WORD_BITS, self.pos, n)
        self.pos += n
        return v

    def s(self, n: int) -> int:
        v = self.u(n)
        return v - (1 << n) if v >> (n - 1) else v

    def skip(self, n: int) -> None:
        self.pos += n


def sisa_m(index: int) -> float:
    """Signal-in-space accuracy (m) of a SISA index (ICD table 76); -1 when unknown (NAPA)."""
    if index < 0 or index > 125:
        return -1.0
    if index <= 49:
        return index * 0.01
    if index <= 74:
        return 0.5 + (index - 50) * 0.02
    if index <= 99:
        return 1.0 + (index - 75) * 0.04
    return 2.0 + (index - 100) * 0.16


def decode_ephemeris(words: Mapping[int, int], data_source: int = 1) -> KeplerEphemeris | None:
    """Word types 1-5 → ephemeris; ``None`` when a type is missing or the IODnav differ.

    Args:
        words: data words by word type.
        data_source: RINEX data-source bits besides bit 9 (1 = I/NAV E1-B).
    """
    if any(k not in words for k in (1, 2, 3, 4, 5)):
        return None
    sc = GPS_PI
    r1, r2, r3, r4, r5 = (_Reader(words[k]) for k in (1, 2, 3, 4, 5))
    iods = [r.u(10) for r in (r1, r2, r3, r4)]
    if len(set(iods)) != 1:
        return None
    toe_s = r1.u(14) * 60.0
    m0 = r1.s(32) * 2.0**-31 * sc
    e = r1.u(32) * 2.0**-33
    sqrt_a = r1.u(32) * 2.0**-19
    omega0 = r2.s(32) * 2.0**-31 * sc
    i0 = r2.s(32) * 2.0**-31 * sc
    omega = r2.s(32) * 2.0**-31 * sc
    idot = r2.s(14) * 2.0**-43 * sc
    omega_dot = r3.s(24) * 2.0**-43 * sc
    delta_n = r3.s(16) * 2.0**-43 * sc
    cuc, cus = r3.s(16) * 2.0**-29, r3.s(16) * 2.0**-29
    crc, crs = r3.s(16) * 2.0**-5, r3.s(16) * 2.0**-5
    sisa = r3.u(8)
    svid = r4.u(6)
    cic, cis = r4.s(16) * 2.0**-29, r4.s(16) * 2.0**-29
    toc_s = r4.u(14) * 60.0
    af0, af1, af2 = r4.s(31) * 2.0**-34, r4.s(21) * 2.0**-46, r4.s(6) * 2.0**-59
    r5.skip(11 + 11 + 14 + 5)  # ionosphere (NeQuick) and region flags
    bgd_a, bgd_b = r5.s(10) * 2.0**-32, r5.s(10) * 2.0**-32
    e5b_hs, e1b_hs, e5b_dvs, e1b_dvs = r5.u(2), r5.u(2), r5.u(1), r5.u(1)
    gst_week, tow = r5.u(12), r5.u(20)
    if not 1 <= svid <= 36:
        return None
    # The week of toe: the one that puts toe within half a week of the transmission time.
    week = gst_week
    dt_s = toe_s - tow
    if dt_s > _HALF_WEEK_S:
        week -= 1
    elif dt_s < -_HALF_WEEK_S:
        week += 1
    return KeplerEphemeris(
        system="E",
        prn=svid,
        week=week + GST_WEEK_OFFSET,
        toc_s=toc_s,
        toe_s=toe_s,
        af0_s=af0,
        af1_s_s=af1,
        af2_s_s2=af2,
        iode=iods[0],
        iodc=iods[0],
        sqrt_a_sqrt_m=sqrt_a,
        e=e,
        i0_rad=i0,
        omega0_rad=omega0,
        omega_rad=omega,
        m0_rad=m0,
        delta_n_rad_s=delta_n,
        omega_dot_rad_s=omega_dot,
        idot_rad_s=idot,
        cuc_rad=cuc,
        cus_rad=cus,
        crc_m=crc,
        crs_m=crs,
        cic_rad=cic,
        cis_rad=cis,
        tgd1_s=bgd_a,
        tgd2_s=bgd_b,
        accuracy_m=sisa_m(sisa),
        health=(e5b_hs << 7) | (e5b_dvs << 6) | (e1b_hs << 1) | e1b_dvs,
        # bit 9: af0-af2, toc and SISA are for the E5b-E1 pair (I/NAV)
        data_source=(1 << 9) | data_source,
        tx_s=float(tow + (gst_week - week) * 604_800),
    )


class InavAssembler:
    """Keeps each satellite's latest word of every type; when a word type 5 arrives, decodes
    types 1-5 and yields the ephemeris unless IODnav, toe and toc repeat the last one."""

    def __init__(self) -> None:
        self._words: dict[int, dict[int, int]] = {}
        self._last: dict[int, tuple[int, float, float, int]] = {}
        self.crc_errors = 0

    def add(self, prn: int, page: int) -> KeplerEphemeris | None:
        """Add one E1-B page of satellite ``prn``."""
        if _bits(page, 256, 1, 1) or _bits(page, 256, 129, 1):
            return None  # alert page
        word = word_from_page(page)
        if word is None:
            self.crc_errors += 1
            return None
        t = word_type(word)
        if t > 6:
            return None
        store = self._words.setdefault(prn, {})
        store[t] = word
        if t != 5:
            return None
        eph = decode_ephemeris(store)
        if eph is None or eph.prn != prn:
            return None
        key = (eph.iode, eph.toe_s, eph.toc_s, eph.week)
        if self._last.get(prn) == key:
            return None
        self._last[prn] = key
        return eph
