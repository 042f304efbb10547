"""GPS LNAV (L1 C/A) navigation message: field layout, word parity and subframe decoding.

The layout is data: :data:`EPHEMERIS_FIELDS` lists every ephemeris field of subframes 1-3 with its
bit position in the 240 data bits of a subframe (ten 24-bit words, word 1 first, MSB first; the
numbering RTKLIB uses), its width, signedness and scale (IS-GPS-200 tables 20-I and 20-III). The
encoder (:mod:`groundstation.gnss.lnav_encode`) and the decoder here share it, so quantised values
round-trip exactly.

Two word forms exist:

- *data words*: 24 data bits per word, parity removed and polarity corrected (u-blox RXM-SFRB,
  AID-EPH, RTKLIB's frame buffer);
- *on-air words*: 30 bits ``D1..D30`` (``D1`` the MSB) as transmitted, data bits complemented when
  the previous word's ``D30`` is 1, six parity bits at the bottom (IS-GPS-200 table 20-XIV).

API: :func:`parity_decode` (on-air → data words, raises :class:`LnavParityError`),
:func:`subframe_id`, :func:`how_tow_s`, :func:`decode_ephemeris` (three data-word subframes →
:class:`~groundstation.gnss.ephemeris.BroadcastEphemeris`), :func:`decode_iono_utc`
(subframe 4 page 18), :class:`EphemerisAssembler` (feed subframes in any order, get ephemerides).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from groundstation.errors import GroundstationError
from groundstation.gnss.ephemeris import GPS_PI, BroadcastEphemeris

PREAMBLE = 0x8B
WORD_BITS = 24
SUBFRAME_BITS = 240


class LnavError(GroundstationError):
    """A subframe that cannot be decoded (parity, preamble, inconsistent issue of data)."""


class LnavParityError(LnavError):
    """A word failed its parity check; ``word`` is its 1-based index."""

    def __init__(self, word: int, message: str) -> None:
        super().__init__(message)
        self.word = word


@dataclass(frozen=True, slots=True)
class Field:
    """One navigation-message field.

    Attributes:
        name: ``BroadcastEphemeris`` attribute (or a local name for helper fields).
        subframe: 1-5.
        parts: ``(start_bit, n_bits)`` pieces, most significant piece first.
        signed: two's complement.
        scale_exp: the LSB is ``2**scale_exp`` (times ``GPS_PI`` when ``semicircles``).
        semicircles: the stored unit is semicircles (the attribute is in radians).
        factor: an extra integer LSB factor (``toe``/``toc`` 16 s are ``2**4``; AODO is 900 s).
    """

    name: str
    subframe: int
    parts: tuple[tuple[int, int], ...]
    signed: bool = False
    scale_exp: int = 0
    semicircles: bool = False
    factor: int = 1

    @property
    def n_bits(self) -> int:
        return sum(n for _, n in self.parts)

    def lsb(self) -> float:
        value = float(self.factor) * 2.0**self.scale_exp
        return value * GPS_PI if self.semicircles else value

    def to_value(self, raw: int) -> float:
        """Physical value of a raw integer (the one expression both directions use)."""
        if self.semicircles:
            return raw * 2.0**self.scale_exp * GPS_PI
        return raw * 2.0**self.scale_exp * self.factor

    def to_raw(self, value: float) -> int:
        """Nearest raw integer of a physical value; raises when it does not fit."""
        raw = round(value / self.lsb())
        lo, hi = (-(1 << (self.n_bits - 1)), (1 << (self.n_bits - 1)) - 1) if self.signed else (
            0,
            (1 << self.n_bits) - 1,
        )
        if not lo <= raw <= hi:
            raise LnavError(f"{self.name}={value!r} does not fit in {self.n_bits} bits")
        return raw


def _f(name: str, sf: int, *parts: tuple[int, int], s: bool = False, e: int = 0,
       sc: bool = False, k: int = 1) -> Field:
    return Field(name, sf, tuple(parts), s, e, sc, k)


EPHEMERIS_FIELDS: tuple[Field, ...] = (
    # subframe 1
    _f("week10", 1, (48, 10)),
    _f("code_on_l2", 1, (58, 2)),
    _f("ura_index", 1, (60, 4)),
    _f("health", 1, (64, 6)),
    _f("iodc", 1, (70, 2), (168, 8)),
    _f("l2p_data_flag", 1, (72, 1)),
    _f("tgd_s", 1, (160, 8), s=True, e=-31),
    _f("toc_s", 1, (176, 16), e=4),
    _f("af2_s_s2", 1, (192, 8), s=True, e=-55),
    _f("af1_s_s", 1, (200, 16), s=True, e=-43),
    _f("af0_s", 1, (216, 22), s=True, e=-31),
    # subframe 2
    _f("iode", 2, (48, 8)),
    _f("crs_m", 2, (56, 16), s=True, e=-5),
    _f("delta_n_rad_s", 2, (72, 16), s=True, e=-43, sc=True),
    _f("m0_rad", 2, (88, 32), s=True, e=-31, sc=True),
    _f("cuc_rad", 2, (120, 16), s=True, e=-29),
    _f("e", 2, (136, 32), e=-33),
    _f("cus_rad", 2, (168, 16), s=True, e=-29),
    _f("sqrt_a_sqrt_m", 2, (184, 32), e=-19),
    _f("toe_s", 2, (216, 16), e=4),
    _f("fit_interval_flag", 2, (232, 1)),
    _f("aodo_s", 2, (233, 5), k=900),
    # subframe 3
    _f("cic_rad", 3, (48, 16), s=True, e=-29),
    _f("omega0_rad", 3, (64, 32), s=True, e=-31, sc=True),
    _f("cis_rad", 3, (96, 16), s=True, e=-29),
    _f("i0_rad", 3, (112, 32), s=True, e=-31, sc=True),
    _f("crc_m", 3, (144, 16), s=True, e=-5),
    _f("omega_rad", 3, (160, 32), s=True, e=-31, sc=True),
    _f("omega_dot_rad_s", 3, (192, 24), s=True, e=-43, sc=True),
    _f("iode3", 3, (216, 8)),
    _f("idot_rad_s", 3, (224, 14), s=True, e=-43, sc=True),
)
"""Ephemeris fields of subframes 1-3 (IS-GPS-200 figures 20-1 to 20-3)."""

IONO_UTC_FIELDS: tuple[Field, ...] = (
    _f("alpha0", 4, (56, 8), s=True, e=-30),
    _f("alpha1", 4, (64, 8), s=True, e=-27),
    _f("alpha2", 4, (72, 8), s=True, e=-24),
    _f("alpha3", 4, (80, 8), s=True, e=-24),
    _f("beta0", 4, (88, 8), s=True, e=11),
    _f("beta1", 4, (96, 8), s=True, e=14),
    _f("beta2", 4, (104, 8), s=True, e=16),
    _f("beta3", 4, (112, 8), s=True, e=16),
    _f("a1", 4, (120, 24), s=True, e=-50),
    _f("a0", 4, (144, 32), s=True, e=-30),
    _f("tot", 4, (176, 8), e=12),
    _f("wnt", 4, (184, 8)),
    _f("dt_ls", 4, (192, 8), s=True),
    _f("wn_lsf", 4, (200, 8)),
    _f("dn", 4, (208, 8)),
    _f("dt_lsf", 4, (216, 8), s=True),
)
"""Subframe 4 page 18 (SV ID 56): Klobuchar coefficients and UTC parameters (table 20-X)."""


# -- bits ---------------------------------------------------------------------------------------


def words_to_int(data_words: Sequence[int]) -> int:
    """Ten 24-bit data words as one 240-bit integer (word 1 in the top bits)."""
    if len(data_words) != 10:
        raise LnavError(f"a subframe has 10 words, not {len(data_words)}")
    value = 0
    for w in data_words:
        value = (value << WORD_BITS) | (w & 0xFFFFFF)
    return value


def int_to_words(value: int) -> tuple[int, ...]:
    """Inverse of :func:`words_to_int`."""
    return tuple((value >> (WORD_BITS * (9 - i))) & 0xFFFFFF for i in range(10))


def get_bits(bits240: int, start: int, n: int) -> int:
    """Unsigned ``n`` bits starting at bit ``start`` (0 = MSB of word 1)."""
    return (bits240 >> (SUBFRAME_BITS - start - n)) & ((1 << n) - 1)


def set_bits(bits240: int, start: int, n: int, value: int) -> int:
    """``bits240`` with ``n`` bits at ``start`` replaced by ``value`` (two's complement)."""
    shift = SUBFRAME_BITS - start - n
    mask = ((1 << n) - 1) << shift
    return (bits240 & ~mask) | ((value & ((1 << n) - 1)) << shift)


def read_field(bits240: int, field: Field) -> int:
    """The raw integer of a field, sign-extended when signed."""
    raw = 0
    for start, n in field.parts:
        raw = (raw << n) | get_bits(bits240, start, n)
    if field.signed and raw & (1 << (field.n_bits - 1)):
        raw -= 1 << field.n_bits
    return raw


def write_field(bits240: int, field: Field, raw: int) -> int:
    """``bits240`` with a field's raw integer written into its parts."""
    remaining = field.n_bits
    for start, n in field.parts:
        remaining -= n
        bits240 = set_bits(bits240, start, n, raw >> remaining)
    return bits240


# -- parity (IS-GPS-200 table 20-XIV) -------------------------------------------------------------

# Data bits (1-based d1..d24) entering each parity bit D25..D30, and which previous bit (29/30).
_PARITY: tuple[tuple[int, tuple[int, ...]], ...] = (
    (29, (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23)),
    (30, (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24)),
    (29, (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22)),
    (30, (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23)),
    (30, (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24)),
    (29, (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24)),
)
_PARITY_MASKS = tuple(
    (prev, sum(1 << (24 - b) for b in bits)) for prev, bits in _PARITY
)


def parity_bits(data24: int, d29_prev: int, d30_prev: int) -> int:
    """The six parity bits ``D25..D30`` (as a 6-bit integer) of a source data word."""
    out = 0
    for prev, mask in _PARITY_MASKS:
        bit = (data24 & mask).bit_count() & 1
        bit ^= d29_prev if prev == 29 else d30_prev
        out = (out << 1) | bit
    return out


def parity_encode(
    data_words: Sequence[int], d29_prev: int = 0, d30_prev: int = 0
) -> tuple[int, ...]:
    """Source data words → on-air 30-bit words (data complemented by the previous ``D30``)."""
    out = []
    for d in data_words:
        d &= 0xFFFFFF
        par = parity_bits(d, d29_prev, d30_prev)
        tx = (d ^ 0xFFFFFF) if d30_prev else d
        word = (tx << 6) | par
        out.append(word)
        d29_prev, d30_prev = (par >> 1) & 1, par & 1
    return tuple(out)


def parity_decode(
    words30: Sequence[int], d29_prev: int = 0, d30_prev: int = 0
) -> tuple[int, ...]:
    """On-air 30-bit words → source data words, checking every word's parity.

    Args:
        words30: the words, ``D1`` in bit 29, ``D30`` in bit 0 (higher bits ignored).
        d29_prev: ``D29`` of the word before the first (0 after a word 10, by design of the
            parity-solving bits).
        d30_prev: ``D30`` of the word before the first.

    Raises:
        LnavParityError: naming the first word that fails.
    """
    out = []
    for i, w in enumerate(words30, start=1):
        w &= 0x3FFFFFFF
        tx, par = w >> 6, w & 0x3F
        d = (tx ^ 0xFFFFFF) if d30_prev else tx
        want = parity_bits(d, d29_prev, d30_prev)
        if want != par:
            raise LnavParityError(i, f"parity error in word {i}: {par:06b} != {want:06b}")
        out.append(d)
        d29_prev, d30_prev = (par >> 1) & 1, par & 1
    return tuple(out)


# -- decoding -----------------------------------------------------------------------------------


def subframe_id(data_words: Sequence[int]) -> int:
    """Subframe ID (1-5) from the HOW (word 2)."""
    return (data_words[1] >> 2) & 0x7


def how_tow_s(data_words: Sequence[int]) -> int:
    """Time of week (s) of the start of the *next* subframe, from the HOW's TOW count."""
    return ((data_words[1] >> 7) & 0x1FFFF) * 6


def check_preamble(data_words: Sequence[int]) -> None:
    if (data_words[0] >> 16) & 0xFF != PREAMBLE:
        raise LnavError(f"bad TLM preamble 0x{(data_words[0] >> 16) & 0xFF:02X}")


def resolve_week(week10: int, week_hint: int) -> int:
    """Full week number from the 10-bit broadcast week, nearest to ``week_hint``."""
    return week10 + round((week_hint - week10) / 1024) * 1024


_FIELDS_BY_SF = {sf: tuple(f for f in EPHEMERIS_FIELDS if f.subframe == sf) for sf in (1, 2, 3)}


def decode_ephemeris(
    sf1: Sequence[int], sf2: Sequence[int], sf3: Sequence[int], week_hint: int, sv: int = 0
) -> BroadcastEphemeris:
    """Subframes 1-3 (data words) → ephemeris.

    Args:
        sf1: ten data words of subframe 1 (likewise ``sf2``, ``sf3``).
        week_hint: a full GPS week near the data (the broadcast week is modulo 1024).
        sv: the satellite the subframes came from (they do not carry it).

    Raises:
        LnavError: bad preamble, wrong subframe IDs or inconsistent IODE/IODC.
    """
    values: dict[str, float] = {}
    raws: dict[str, int] = {}
    sv_words = (sf1, sf2, sf3)
    for sf, words in zip((1, 2, 3), sv_words, strict=True):
        check_preamble(words)
        if subframe_id(words) != sf:
            raise LnavError(f"expected subframe {sf}, got {subframe_id(words)}")
        bits = words_to_int(words)
        for field in _FIELDS_BY_SF[sf]:
            raw = read_field(bits, field)
            raws[field.name] = raw
            values[field.name] = field.to_value(raw)
    iode = raws["iode"]
    if raws["iode3"] != iode or raws["iodc"] & 0xFF != iode:
        raise LnavError(
            f"issue of data mismatch: IODE {iode}/{raws['iode3']}, IODC {raws['iodc']}"
        )
    tow_s = float(how_tow_s(sf1) - 6)
    week = resolve_week(raws["week10"], week_hint)
    # The broadcast week is the week of transmission; toe may lie in the next or last week.
    toe_week = week
    if values["toe_s"] < tow_s - 302_400:
        toe_week += 1
    elif values["toe_s"] > tow_s + 302_400:
        toe_week -= 1
    return BroadcastEphemeris(
        sv=sv,
        week=toe_week,
        toc_s=values["toc_s"],
        af0_s=values["af0_s"],
        af1_s_s=values["af1_s_s"],
        af2_s_s2=values["af2_s_s2"],
        iodc=raws["iodc"],
        iode=iode,
        tgd_s=values["tgd_s"],
        ura_index=raws["ura_index"],
        health=raws["health"],
        code_on_l2=raws["code_on_l2"],
        l2p_data_flag=raws["l2p_data_flag"],
        fit_interval_flag=raws["fit_interval_flag"],
        toe_s=values["toe_s"],
        sqrt_a_sqrt_m=values["sqrt_a_sqrt_m"],
        e=values["e"],
        i0_rad=values["i0_rad"],
        omega0_rad=values["omega0_rad"],
        omega_rad=values["omega_rad"],
        m0_rad=values["m0_rad"],
        delta_n_rad_s=values["delta_n_rad_s"],
        omega_dot_rad_s=values["omega_dot_rad_s"],
        idot_rad_s=values["idot_rad_s"],
        cuc_rad=values["cuc_rad"],
        cus_rad=values["cus_rad"],
        crc_m=values["crc_m"],
        crs_m=values["crs_m"],
        cic_rad=values["cic_rad"],
        cis_rad=values["cis_rad"],
        aodo_s=raws["aodo_s"] * 900,
        tow_s=tow_s,
    )


@dataclass(frozen=True, slots=True)
class IonoUtc:
    """Klobuchar coefficients and GPS-UTC parameters of subframe 4 page 18.

    ``alpha`` in s, s/semicircle, s/semicircle², s/semicircle³; ``beta`` in s, s/semicircle ...
    """

    alpha: tuple[float, float, float, float]
    beta: tuple[float, float, float, float]
    a0_s: float
    a1_s_s: float
    tot_s: int
    wnt: int
    dt_ls_s: int
    wn_lsf: int
    dn: int
    dt_lsf_s: int


def page_sv_id(data_words: Sequence[int]) -> int:
    """SV (page) ID of a subframe 4 or 5 (56 = page 18 of subframe 4)."""
    return get_bits(words_to_int(data_words), 50, 6)


def decode_iono_utc(sf4: Sequence[int]) -> IonoUtc | None:
    """Subframe 4 page 18 → :class:`IonoUtc`; ``None`` for any other page."""
    check_preamble(sf4)
    if subframe_id(sf4) != 4 or page_sv_id(sf4) != 56:
        return None
    bits = words_to_int(sf4)
    v = {f.name: read_field(bits, f) for f in IONO_UTC_FIELDS}
    by_name = {f.name: f for f in IONO_UTC_FIELDS}

    def val(name: str) -> float:
        return by_name[name].to_value(v[name])

    return IonoUtc(
        alpha=(val("alpha0"), val("alpha1"), val("alpha2"), val("alpha3")),
        beta=(val("beta0"), val("beta1"), val("beta2"), val("beta3")),
        a0_s=val("a0"),
        a1_s_s=val("a1"),
        tot_s=v["tot"] * 4096,
        wnt=v["wnt"],
        dt_ls_s=v["dt_ls"],
        wn_lsf=v["wn_lsf"],
        dn=v["dn"],
        dt_lsf_s=v["dt_lsf"],
    )


class EphemerisAssembler:
    """Collects subframes per satellite and yields an ephemeris when 1, 2 and 3 agree.

    Args:
        week_hint: a full GPS week near the data, to resolve the 10-bit broadcast week.
    """

    def __init__(self, week_hint: int) -> None:
        self.week_hint = week_hint
        self._frames: dict[int, dict[int, tuple[int, ...]]] = {}
        self._last: dict[int, BroadcastEphemeris] = {}
        self.errors = 0

    def add(self, sv: int, data_words: Sequence[int]) -> BroadcastEphemeris | None:
        """Add one subframe (data words); returns an ephemeris when a new one is complete.

        The same ephemeris repeated (every 30 s on air) is returned only the first time.
        """
        words = tuple(w & 0xFFFFFF for w in data_words)
        sid = subframe_id(words)
        if sid not in (1, 2, 3):
            return None
        store = self._frames.setdefault(sv, {})
        store[sid] = words
        if len(store) < 3:
            return None
        try:
            eph = decode_ephemeris(store[1], store[2], store[3], self.week_hint, sv)
        except LnavError:
            self.errors += 1
            return None
        store.clear()
        last = self._last.get(sv)
        if last is not None and replace(eph, tow_s=last.tow_s) == last:
            return None
        self._last[sv] = eph
        return eph
