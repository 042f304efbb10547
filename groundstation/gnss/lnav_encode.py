"""GPS LNAV encoder: ephemeris → subframes 1-3, filler subframes 4-5, TLM/HOW and parity.

Produces *data words* (24 bits, what u-blox RXM-SFRB carries) and *on-air words* (30 bits with
parity, via :func:`groundstation.gnss.lnav.parity_encode`). Word 2 and word 10 of every subframe
end with the two parity-solving bits chosen so that ``D29 = D30 = 0`` (IS-GPS-200 20.3.5.2), so
each subframe's parity chain starts from zeros.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.lnav import (
    EPHEMERIS_FIELDS,
    IONO_UTC_FIELDS,
    PREAMBLE,
    Field,
    LnavError,
    int_to_words,
    parity_bits,
    parity_encode,
    set_bits,
    write_field,
)


@dataclass(frozen=True, slots=True)
class IonoUtcParams:
    """Values to broadcast in subframe 4 page 18 (already on the LSB grid if they should
    round-trip exactly; see :func:`quantise`)."""

    alpha: tuple[float, float, float, float]
    beta: tuple[float, float, float, float]
    a0_s: float = 0.0
    a1_s_s: float = 0.0
    tot_s: int = 0
    wnt: int = 0
    dt_ls_s: int = 18
    wn_lsf: int = 0
    dn: int = 7
    dt_lsf_s: int = 18


def quantise(field: Field, value: float) -> float:
    """The value a field can carry that is nearest to ``value``."""
    return field.to_value(field.to_raw(value))


FIELDS = {f.name: f for f in EPHEMERIS_FIELDS}


def _solve_t_bits(word: int, d29_prev: int = 0, d30_prev: int = 0) -> int:
    """Set the two low data bits of a word so that its parity bits D29 and D30 are zero."""
    for t in range(4):
        cand = (word & ~0x3) | t
        if parity_bits(cand, d29_prev, d30_prev) & 0x3 == 0:
            return cand
    raise LnavError("no parity-solving bits found")  # pragma: no cover - impossible


def _finish(bits240: int, sf_id: int, how_tow_count: int, alert: int = 0, as_flag: int = 0
            ) -> tuple[int, ...]:
    bits240 = set_bits(bits240, 0, 8, PREAMBLE)
    bits240 = set_bits(bits240, 8, 16, 0)  # TLM message, integrity flag, reserved
    bits240 = set_bits(bits240, 24, 17, how_tow_count)
    bits240 = set_bits(bits240, 41, 1, alert)
    bits240 = set_bits(bits240, 42, 1, as_flag)
    bits240 = set_bits(bits240, 43, 3, sf_id)
    words = list(int_to_words(bits240))
    # Parity of word 2 depends on word 1's D29/D30, which depend on the data: chain it.
    chained = parity_encode(words[:1])
    words[1] = _solve_t_bits(words[1], (chained[0] >> 1) & 1, chained[0] & 1)
    chained = parity_encode(words[:9])
    words[9] = _solve_t_bits(words[9], (chained[8] >> 1) & 1, chained[8] & 1)
    return tuple(words)


def encode_ephemeris(
    eph: BroadcastEphemeris, tx_week: int, sf1_tow_s: int
) -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
    """Subframes 1, 2, 3 as data words.

    Args:
        eph: the ephemeris; its values should lie on the LSB grid (otherwise they are rounded).
        tx_week: full GPS week of transmission (broadcast modulo 1024).
        sf1_tow_s: time of week at which subframe 1 starts (a multiple of 30 s); subframes 2
            and 3 follow at +6 s and +12 s.
    """
    if sf1_tow_s % 30:
        raise LnavError(f"subframe 1 starts on a 30 s boundary, not at tow {sf1_tow_s}")
    values: dict[str, float] = {
        "week10": tx_week % 1024,
        "code_on_l2": eph.code_on_l2,
        "ura_index": eph.ura_index,
        "health": eph.health,
        "iodc": eph.iodc,
        "l2p_data_flag": eph.l2p_data_flag,
        "iode3": eph.iode,
        "aodo_s": eph.aodo_s,
    }
    bits = {1: 0, 2: 0, 3: 0}
    for field in EPHEMERIS_FIELDS:
        value = values[field.name] if field.name in values else getattr(eph, field.name)
        if field.name in ("week10", "code_on_l2", "ura_index", "health", "iodc",
                          "l2p_data_flag", "iode", "iode3", "fit_interval_flag"):
            raw = int(value)
        else:
            raw = field.to_raw(float(value))
        bits[field.subframe] = write_field(bits[field.subframe], field, raw)
    count = sf1_tow_s // 6
    return (
        _finish(bits[1], 1, count + 1),
        _finish(bits[2], 2, count + 2),
        _finish(bits[3], 3, count + 3),
    )


def encode_iono_utc_page(params: IonoUtcParams, how_tow_count: int) -> tuple[int, ...]:
    """Subframe 4 page 18 (data ID 1, SV ID 56) as data words."""
    bits = set_bits(0, 48, 2, 1)
    bits = set_bits(bits, 50, 6, 56)
    vals: dict[str, float] = {
        "alpha0": params.alpha[0], "alpha1": params.alpha[1],
        "alpha2": params.alpha[2], "alpha3": params.alpha[3],
        "beta0": params.beta[0], "beta1": params.beta[1],
        "beta2": params.beta[2], "beta3": params.beta[3],
        "a1": params.a1_s_s, "a0": params.a0_s,
    }
    ints = {
        "tot": params.tot_s // 4096, "wnt": params.wnt % 256, "dt_ls": params.dt_ls_s,
        "wn_lsf": params.wn_lsf % 256, "dn": params.dn, "dt_lsf": params.dt_lsf_s,
    }
    for field in IONO_UTC_FIELDS:
        raw = ints[field.name] if field.name in ints else field.to_raw(vals[field.name])
        bits = write_field(bits, field, raw)
    return _finish(bits, 4, how_tow_count)


def encode_filler(sf_id: int, how_tow_count: int, page_sv_id: int = 0) -> tuple[int, ...]:
    """A subframe 4 or 5 page carrying no data: data ID 1, the given page SV ID (0 = dummy)."""
    bits = set_bits(0, 48, 2, 1)
    bits = set_bits(bits, 50, 6, page_sv_id)
    # Reserved/dummy content: alternating ones and zeros as the spec's filler pattern.
    for start in range(56, 232, 8):
        bits = set_bits(bits, start, 8, 0xAA)
    return _finish(bits, sf_id, how_tow_count)


def subframe_for(
    eph: BroadcastEphemeris,
    iono: IonoUtcParams,
    tx_week: int,
    start_tow_s: int,
) -> tuple[int, ...]:
    """The data words of the subframe that starts at ``start_tow_s`` (a multiple of 6 s)."""
    if start_tow_s % 6:
        raise LnavError(f"subframes start every 6 s, not at tow {start_tow_s}")
    sf_id = (start_tow_s // 6) % 5 + 1
    frame_start = start_tow_s - (sf_id - 1) * 6
    count_next = start_tow_s // 6 + 1
    if sf_id <= 3:
        return encode_ephemeris(eph, tx_week, frame_start)[sf_id - 1]
    if sf_id == 4:
        # Page 18 every other frame, a dummy page in between (real receivers see 25 pages).
        if (frame_start // 30) % 2 == 0:
            return encode_iono_utc_page(iono, count_next)
        return encode_filler(4, count_next, 57)
    return encode_filler(5, count_next, 0)


def to_on_air(data_words: Sequence[int]) -> tuple[int, ...]:
    """Data words of one subframe → 30-bit on-air words (chain starting from D29*=D30*=0)."""
    return parity_encode(data_words)
