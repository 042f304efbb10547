"""GLONASS L1 navigation strings (ICD GLONASS 5.1, section 4.4): Hamming check and ephemeris.

A string is 85 bits: an idle 0 (bit 85), the string number ``m`` (bits 84-81), data, and eight
Hamming check bits (bits 8-1). Strings 1-4 of one 30 s frame carry the immediate data (position,
velocity and lunisolar acceleration in PZ-90 at ``tb``, clock offset ``tau_n``, relative frequency
bias ``gamma_n``). Here a string is an ``int`` whose bit ``k - 1`` is ICD bit ``k`` (bit 85 on
top); :func:`string_from_ublox` builds it from the four words u-blox RXM-SFRBX delivers.

Times: ``tk`` and ``tb`` are Moscow time (UTC + 3 h) of the day; the day comes from an
approximate GPS time the caller knows (a receiver epoch), as only the day is ambiguous.

API: :func:`hamming_ok`, :func:`string_number`, :class:`GlonassEphemeris`,
:func:`decode_ephemeris`, :class:`GlonassAssembler` (feed strings, get new ephemerides).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from groundstation import gpstime

STRING_BITS = 85
_DAY_S = 86_400
_MOSCOW_OFFSET_S = 10_800


def _hamming_masks() -> tuple[tuple[int, ...], int]:
    """Masks of the check sums ``c1..c7`` and ``c_sigma`` (ICD 4.7).

    Data bits ``b9..b84`` take the positions of an extended Hamming code that skip the powers
    of two (3, 5, 6, 7, 9 ...); ``c_k`` covers ``beta_k`` and every data bit whose position has
    bit ``k - 1`` set. ``c_sigma`` covers all 85 bits.
    """
    masks = [1 << (k - 1) for k in range(1, 8)]  # beta_k is ICD bit k
    pos = 2
    for icd_bit in range(9, 85):
        pos += 1
        while pos & (pos - 1) == 0:
            pos += 1
        for k in range(7):
            if pos >> k & 1:
                masks[k] |= 1 << (icd_bit - 1)
    return tuple(masks), (1 << STRING_BITS) - 1


_C_MASKS, _C_SIGMA_MASK = _hamming_masks()


def hamming_ok(string: int) -> bool:
    """Whether a string passes its Hamming check (ICD 4.7: no error, or one in a check bit)."""
    sums = [(string & m).bit_count() & 1 for m in _C_MASKS]
    c_sigma = (string & _C_SIGMA_MASK).bit_count() & 1
    bad = sum(sums)
    return (bad == 0 and c_sigma == 0) or (bad == 1 and c_sigma == 1)


def string_from_ublox(words: Sequence[int]) -> tuple[int, int]:
    """(string, frame id) from the four 32-bit words of a u-blox GLONASS RXM-SFRBX.

    The first 85 of the 128 bits (word 1's MSB first) are the string, bit 85 on top; u-blox
    puts the superframe and frame numbers in the upper half of word 4, which tells strings of
    different frames apart.
    """
    bits128 = 0
    for w in words[:4]:
        bits128 = (bits128 << 32) | (w & 0xFFFFFFFF)
    return bits128 >> (128 - STRING_BITS), (words[3] >> 16) & 0xFFFF


def _u(string: int, icd_top: int, n: int) -> int:
    """Unsigned ``n`` bits whose most significant is ICD bit ``icd_top``."""
    return (string >> (icd_top - n)) & ((1 << n) - 1)


def _sm(string: int, icd_top: int, n: int) -> int:
    """Sign-magnitude ``n`` bits (the sign is the top bit), as GLONASS encodes signed values."""
    v = _u(string, icd_top, n)
    mag = v & ((1 << (n - 1)) - 1)
    return -mag if v >> (n - 1) else mag


def string_number(string: int) -> int:
    """String number ``m`` (1-15)."""
    return _u(string, 84, 4)


@dataclass(frozen=True, slots=True)
class GlonassEphemeris:
    """One GLONASS satellite's immediate data (strings 1-4), in SI units.

    Attributes:
        slot: orbital slot (RINEX ``Rnn``).
        fcn: frequency channel number (-7..+6), from the receiver.
        toe_gps_ns: ``tb`` as GPS time.
        tof_gps_ns: frame start ``tk`` as GPS time.
        tb: the 15-minute index of ``tb`` in the Moscow day (the issue of data).
        tau_n_s: satellite clock offset (``t_GLONASS - t_sat``); RINEX writes ``-tau_n``.
        gamma_n: relative frequency bias.
        pos_m, vel_m_s, acc_m_s2: PZ-90 state at ``tb``.
        health: the most significant bit of ``Bn`` (what RINEX 3.04 calls the health flag).
        age_days: ``En``.
        delta_tau_n_s: L1/L2 group delay difference.
        ft: accuracy index ``FT``.
        ln: string-3 health flag ``ln``.
    """

    slot: int
    fcn: int
    toe_gps_ns: int
    tof_gps_ns: int
    tb: int
    tau_n_s: float
    gamma_n: float
    pos_m: tuple[float, float, float]
    vel_m_s: tuple[float, float, float]
    acc_m_s2: tuple[float, float, float]
    health: int
    age_days: int
    delta_tau_n_s: float
    ft: int
    ln: int


def _near_day(moscow_s: int, approx_gps_ns: int) -> int:
    """GPS ns of a Moscow time-of-day, on the UTC day that puts it within 12 h of the
    approximate time (leap seconds as of that time)."""
    leap_ns = gpstime.leap_seconds_at_gps(approx_gps_ns) * gpstime.NS_PER_S
    utc_ns = approx_gps_ns - leap_ns
    day_start_ns = utc_ns - utc_ns % (_DAY_S * gpstime.NS_PER_S)
    tod_ns = utc_ns - day_start_ns
    t_ns = (moscow_s - _MOSCOW_OFFSET_S) * gpstime.NS_PER_S
    half = _DAY_S // 2 * gpstime.NS_PER_S
    if t_ns < tod_ns - half:
        t_ns += _DAY_S * gpstime.NS_PER_S
    elif t_ns > tod_ns + half:
        t_ns -= _DAY_S * gpstime.NS_PER_S
    return day_start_ns + t_ns + leap_ns


def decode_ephemeris(
    strings: Sequence[int], fcn: int, approx_gps_ns: int
) -> GlonassEphemeris | None:
    """Strings 1-4 (in order) → ephemeris, or ``None`` when they are not strings 1-4.

    Args:
        strings: four Hamming-checked strings of one frame.
        fcn: frequency channel number of the satellite.
        approx_gps_ns: a GPS time within a few hours of the data (resolves the day).
    """
    if [string_number(s) for s in strings] != [1, 2, 3, 4]:
        return None
    s1, s2, s3, s4 = strings
    tk_s = _u(s1, 76, 5) * 3600 + _u(s1, 71, 6) * 60 + _u(s1, 65, 1) * 30
    tb = _u(s2, 76, 7)
    scale_v, scale_a, scale_x = 2.0**-20 * 1e3, 2.0**-30 * 1e3, 2.0**-11 * 1e3
    vel, acc, pos = [], [], []
    for s in (s1, s2, s3):
        vel.append(_sm(s, 64, 24) * scale_v)
        acc.append(_sm(s, 40, 5) * scale_a)
        pos.append(_sm(s, 35, 27) * scale_x)
    return GlonassEphemeris(
        slot=_u(s4, 15, 5),
        fcn=fcn,
        toe_gps_ns=_near_day(tb * 900, approx_gps_ns),
        tof_gps_ns=_near_day(tk_s, approx_gps_ns),
        tb=tb,
        tau_n_s=_sm(s4, 80, 22) * 2.0**-30,
        gamma_n=_sm(s3, 79, 11) * 2.0**-40,
        pos_m=(pos[0], pos[1], pos[2]),
        vel_m_s=(vel[0], vel[1], vel[2]),
        acc_m_s2=(acc[0], acc[1], acc[2]),
        health=_u(s2, 80, 1),
        age_days=_u(s4, 53, 5),
        delta_tau_n_s=_sm(s4, 58, 5) * 2.0**-30,
        ft=_u(s4, 33, 4),
        ln=_u(s3, 65, 1),
    )


class GlonassAssembler:
    """Collects Hamming-checked strings per slot; yields an ephemeris when string 4 completes
    strings 1-4 of one frame and its ``tb`` differs from the slot's last one."""

    def __init__(self) -> None:
        self._frames: dict[int, tuple[int, dict[int, int]]] = {}
        self._last_tb: dict[int, int] = {}
        self.hamming_errors = 0

    def add(
        self, slot: int, string: int, frame_id: int, fcn: int, approx_gps_ns: int
    ) -> GlonassEphemeris | None:
        """Add one string of a satellite (``slot`` as the receiver names it)."""
        if not hamming_ok(string):
            self.hamming_errors += 1
            return None
        m = string_number(string)
        if not 1 <= m <= 15:
            return None
        fid, store = self._frames.get(slot, (-1, {}))
        if fid != frame_id:
            # Strings of a new frame must not be combined with the previous frame's.
            store = {}
            self._frames[slot] = (frame_id, store)
        store[m] = string
        if m != 4 or any(k not in store for k in (1, 2, 3)):
            return None
        eph = decode_ephemeris([store[1], store[2], store[3], store[4]], fcn, approx_gps_ns)
        if eph is None or eph.slot != slot or self._last_tb.get(slot) == eph.tb:
            return None
        self._last_tb[slot] = eph.tb
        return eph
