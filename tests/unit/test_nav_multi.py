"""GLONASS strings, Galileo I/NAV pages and BeiDou D1 subframes built bit by bit from the ICDs:
checks that catch damage, field positions and scales, time resolution, RINEX records."""

from __future__ import annotations

import datetime as dt

import pytest

from groundstation import gpstime
from groundstation.gnss import beidou, galileo, glonass
from groundstation.offline.multinav import MultiNav
from groundstation.offline.rinex import nav_multi as rinexnav_multi
from groundstation.ubx.framer import crc24q

# -- GLONASS --------------------------------------------------------------------------------


def _put(value: int, icd_top: int, n: int, raw: int) -> int:
    """``value`` with ``raw`` (n bits) written so that its MSB is ICD bit ``icd_top``."""
    shift = icd_top - n
    return (value & ~(((1 << n) - 1) << shift)) | ((raw & ((1 << n) - 1)) << shift)


def _sm(x: int, n: int) -> int:
    """Sign-magnitude encoding."""
    return (1 << (n - 1)) | -x if x < 0 else x


def _with_check_bits(string: int) -> int:
    """Set beta_1..beta_8 so that every check sum is zero (what a satellite sends)."""
    string &= ~0xFF
    for k, mask in enumerate(glonass._C_MASKS):
        if (string & mask).bit_count() & 1:
            string |= 1 << k
    if string.bit_count() & 1:
        string |= 1 << 7
    return string


def _glonass_strings(slot: int, tb: int, tk_h: int, tk_m: int) -> list[int]:
    s = [0, 0, 0, 0]
    for m in range(4):
        s[m] = _put(0, 84, 4, m + 1)
    s[0] = _put(s[0], 76, 5, tk_h)
    s[0] = _put(s[0], 71, 6, tk_m)
    s[1] = _put(s[1], 76, 7, tb)
    for k, (x, v, a) in enumerate(((-1000, 2000, -3), (5000, -6000, 7), (9000, 100, 0))):
        s[k] = _put(s[k], 64, 24, _sm(v, 24))
        s[k] = _put(s[k], 40, 5, _sm(a, 5))
        s[k] = _put(s[k], 35, 27, _sm(x, 27))
    s[2] = _put(s[2], 79, 11, _sm(-5, 11))
    s[3] = _put(s[3], 80, 22, _sm(-1234, 22))
    s[3] = _put(s[3], 53, 5, 3)
    s[3] = _put(s[3], 15, 5, slot)
    return [_with_check_bits(x) for x in s]


def test_glonass_hamming_accepts_clean_and_rejects_any_single_data_bit_error() -> None:
    strings = _glonass_strings(7, 49, 12, 15)
    assert all(glonass.hamming_ok(s) for s in strings)
    for bit in range(8, 84):  # data bits b9..b84
        assert not glonass.hamming_ok(strings[0] ^ (1 << bit)), bit


def test_glonass_ephemeris_fields_and_the_day_from_an_approximate_time() -> None:
    strings = _glonass_strings(7, 49, 15, 22)  # tb 49 -> 12:15 Moscow = 09:15 UTC
    approx = gpstime.datetime_to_gps_ns(dt.datetime(2018, 10, 9, 21, 0, tzinfo=dt.UTC))
    e = glonass.decode_ephemeris(strings, -3, approx)
    assert e is not None and e.slot == 7 and e.fcn == -3 and e.tb == 49 and e.age_days == 3
    utc = dt.UTC
    toe_utc = gpstime.gps_as_datetime(e.toe_gps_ns - 18 * gpstime.NS_PER_S)
    assert toe_utc == dt.datetime(2018, 10, 9, 9, 15, tzinfo=utc)
    tof_utc = gpstime.gps_as_datetime(e.tof_gps_ns - 18 * gpstime.NS_PER_S)
    assert tof_utc == dt.datetime(2018, 10, 9, 12, 22, tzinfo=utc)
    assert e.pos_m == (-1000 * 2.0**-11 * 1e3, 5000 * 2.0**-11 * 1e3, 9000 * 2.0**-11 * 1e3)
    assert e.vel_m_s[1] == -6000 * 2.0**-20 * 1e3 and e.acc_m_s2[0] == -3 * 2.0**-30 * 1e3
    assert e.tau_n_s == -1234 * 2.0**-30 and e.gamma_n == -5 * 2.0**-40
    # The day is the one that puts tb within 12 h of the receiver's time: at 23:00 UTC a
    # 09:15 UTC tb is tomorrow's.
    late = glonass.decode_ephemeris(strings, -3, approx + 2 * 3600 * 10**9)
    assert late is not None and late.toe_gps_ns == e.toe_gps_ns + 86_400 * 10**9
    rec = rinexnav_multi.glonass_record(e, lambda v: f"{v:19.12E}")
    assert rec.startswith("R07 2018 10 09 09 15 00 1.149252057076E-06-4.547473508865E-12 2.1732")
    assert len(rec.splitlines()) == 4


def test_glonass_assembler_needs_strings_of_one_frame_and_a_new_tb() -> None:
    a = glonass.GlonassAssembler()
    s = _glonass_strings(7, 49, 12, 15)
    t = gpstime.datetime_to_gps_ns(dt.datetime(2018, 10, 9, 12, 0, tzinfo=dt.UTC))
    a.add(7, s[0], 1, 0, t)
    a.add(7, s[1], 1, 0, t)
    assert a.add(7, s[3], 2, 0, t) is None  # string 4 of another frame: buffer flushed
    for x in s:
        e = a.add(7, x, 3, 0, t)
    assert e is not None
    assert all(a.add(7, x, 4, 0, t) is None for x in s)  # same tb again
    assert a.add(7, s[0] ^ (1 << 40), 4, 0, t) is None and a.hamming_errors == 1


# -- Galileo ------------------------------------------------------------------------------


def _gal_page(word: int) -> int:
    """A nominal E1-B page (256 bits: even part, then odd part) carrying a 128-bit word."""

    def put(page: int, start: int, n: int, raw: int) -> int:
        return page | ((raw & ((1 << n) - 1)) << (256 - start - n))

    page = put(0, 2, 112, word >> 16)  # even/odd 0, page type 0 (nominal)
    page = put(page, 128, 1, 1)  # odd part
    page = put(page, 130, 16, word & 0xFFFF)
    protected = (galileo._bits(page, 256, 0, 114) << 82) | galileo._bits(page, 256, 128, 82)
    return put(page, 210, 24, crc24q(protected.to_bytes(25, "big")))


def _gal_word(wtype: int, fields: list[tuple[int, int]]) -> int:
    """A word from (n_bits, raw) fields after the 6-bit type (two's complement raws)."""
    w, pos = wtype, 6
    for n, raw in fields:
        w = (w << n) | (raw & ((1 << n) - 1))
        pos += n
    return w << (128 - pos)


def test_galileo_page_crc_and_word() -> None:
    word = _gal_word(4, [(10, 77), (6, 12)])
    page = _gal_page(word)
    assert galileo.word_from_page(page) == word
    assert galileo.word_from_page(page ^ (1 << 200)) is None
    assert galileo.word_from_page(page ^ (1 << (255 - 135))) is None  # odd-part data bit


def test_galileo_ephemeris_week_of_toe_and_rinex_record() -> None:
    iod = 45
    words = {
        1: _gal_word(1, [(10, iod), (14, 408000 // 60), (32, -5), (32, 1 << 20), (32, 5440 << 19)]),
        2: _gal_word(2, [(10, iod), (32, 1), (32, 2), (32, 3), (14, -4)]),
        3: _gal_word(3, [(10, iod), (24, -6), (16, 7), (16, 8), (16, 9), (16, 10), (16, 11),
                         (8, 107)]),
        4: _gal_word(4, [(10, iod), (6, 8), (16, 1), (16, 2), (14, 408000 // 60), (31, -100),
                         (21, 5), (6, 0)]),
        # a word 5 sent at the very start of the next GST week (toe at the end of this one)
        5: _gal_word(5, [(11, 0), (11, 0), (14, 0), (5, 0), (10, -3), (10, 4), (2, 0), (2, 0),
                         (1, 0), (1, 0), (12, 1358), (20, 100)]),
    }
    e = galileo.decode_ephemeris(words)
    assert e is not None and e.prn == 8 and e.week == 1357 + 1024 and e.toe_s == 408000
    assert e.tx_s == 100 + 604800 and e.accuracy_m == pytest.approx(2.0 + 7 * 0.16)
    assert e.tgd1_s == -3 * 2.0**-32 and e.data_source == 513
    assert galileo.decode_ephemeris({**words, 2: _gal_word(2, [(10, iod + 1)])}) is None
    rec = rinexnav_multi.kepler_record(e, lambda v: f"{v:19.12E}")
    assert rec.startswith("E08 2025 ") and len(rec.splitlines()) == 8


# -- BeiDou -------------------------------------------------------------------------------


def _bds_sf(fields: list[tuple[int, int, int]]) -> int:
    """A 300-bit subframe from (start, n_bits, raw) fields."""
    sf = 0
    for start, n, raw in fields:
        sf |= (raw & ((1 << n) - 1)) << (300 - start - n)
    return sf


def _bds_frame(sow1: int, toe: int, week: int) -> dict[int, int]:
    def head(sid: int, sow: int) -> list[tuple[int, int, int]]:
        return [(15, 3, sid), (18, 8, sow >> 12), (30, 12, sow & 0xFFF)]

    t8 = toe // 8
    return {
        1: _bds_sf(head(1, sow1) + [(60, 13, week), (73, 9, t8 >> 8), (90, 8, t8 & 0xFF),
                                    (48, 4, 2), (43, 5, 1), (98, 10, -20)]),
        2: _bds_sf(head(2, sow1 + 6) + [(290, 2, t8 >> 15), (250, 12, 5282 >> 1)]),
        3: _bds_sf(head(3, sow1 + 12) + [(42, 10, (t8 >> 5) & 0x3FF), (60, 5, t8 & 0x1F)]),
    }


def test_beidou_d1_fields_week_and_consistency() -> None:
    frame = _bds_frame(604_790, 8, 1000)  # toe just after the week starts: next week
    e = beidou.decode_ephemeris(frame, 21)
    assert e is not None and e.week == 1001 and e.toc_s == e.toe_s == 8.0
    assert e.tx_s == 604_790 - 604_800 and e.accuracy_m == 4.0 and e.iodc == 1
    assert e.tgd1_s == pytest.approx(-2e-9) and e.iode == 0
    assert beidou.decode_ephemeris({**frame, 2: _bds_frame(0, 8, 1000)[2]}, 21) is None
    rec = rinexnav_multi.kepler_record(e, lambda v: f"{v:19.12E}")
    assert rec.startswith("C21 2025 03 09 00 00 08")  # BDT calendar of week 1001 + 8 s
    multi = MultiNav(kepler=[e])
    assert rinexnav_multi.header_system(True, multi) == "M: Mixed"
    assert rinexnav_multi.header_system(False, multi) == "C: BeiDou"
    assert rinexnav_multi.header_system(True, MultiNav()) == "G: GPS"
