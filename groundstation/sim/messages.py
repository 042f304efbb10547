"""UBX frames a LEA-6T sends, built with struct: RXM-RAW, RXM-SFRB, NAV-SOL, NAV-SVINFO, TIM-TM2."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from groundstation.ubx.build import build_frame

_RAW_HEAD = struct.Struct("<iHBB")
_RAW_SAT = struct.Struct("<ddfBbbB")
_SFRB = struct.Struct("<BB10I")
_NAV_SOL = struct.Struct("<IiHBBiiiIiiiIHBBI")
_SVINFO_HEAD = struct.Struct("<IBBH")
_SVINFO_SAT = struct.Struct("<BBBBBbhi")
_TM2 = struct.Struct("<BBHHHIIIII")

TM2_MODE_RUNNING = 0x01
TM2_RUN = 0x02
TM2_NEW_FALLING = 0x04
TM2_TIMEBASE_GPS = 0x08
TM2_UTC_VALID = 0x20
TM2_TIME_VALID = 0x40
TM2_NEW_RISING = 0x80


@dataclass(frozen=True, slots=True)
class TimedMessage:
    """One frame as the receiver sends it.

    Attributes:
        t_gps_ns: GPS time at which its first byte leaves the receiver's UART.
        name: message name (``RXM-RAW`` ...).
        raw: the complete frame.
        tag: what identifies it in the truth file: ``iTOW`` in ms for RXM-RAW, NAV-SOL and
            NAV-SVINFO, the mark ``count`` for TIM-TM2, the SV for RXM-SFRB.
        receiver: ``rover`` or ``base``.
    """

    t_gps_ns: int
    name: str
    raw: bytes
    tag: int
    receiver: str = "rover"


@dataclass(frozen=True, slots=True)
class RawSat:
    cp_cyc: float
    pr_m: float
    doppler_hz: float
    sv: int
    mes_qi: int
    cno_dbhz: int
    lli: int


def rxm_raw(tow_ms: int, week: int, sats: Sequence[tuple[float, float, float, int, int, int, int]]
            ) -> bytes:
    """RXM-RAW (02 10). ``sats`` rows: cpMes, prMes, doMes, sv, mesQI, cno, lli."""
    body = [_RAW_HEAD.pack(tow_ms, week, len(sats), 0)]
    body.extend(_RAW_SAT.pack(*s) for s in sats)
    return build_frame(0x02, 0x10, b"".join(body))


def rxm_sfrb(channel: int, svid: int, words: Sequence[int]) -> bytes:
    """RXM-SFRB (02 11): the 10 data words of one subframe, 24 bits each in a U4."""
    return build_frame(0x02, 0x11, _SFRB.pack(channel, svid, *(w & 0xFFFFFF for w in words)))


def nav_sol(
    tow_ms: int,
    week: int,
    ecef_cm: tuple[int, int, int],
    vel_cm_s: tuple[int, int, int],
    p_acc_cm: int,
    s_acc_cm_s: int,
    pdop_x100: int,
    num_sv: int,
    f_tow_ns: int = 0,
) -> bytes:
    """NAV-SOL (01 06): 3D fix, GPS fix OK, week and time of week valid."""
    flags = 0x01 | 0x04 | 0x08
    payload = _NAV_SOL.pack(
        tow_ms, f_tow_ns, week, 3, flags, *ecef_cm, p_acc_cm, *vel_cm_s, s_acc_cm_s,
        pdop_x100, 0, num_sv, 0,
    )
    return build_frame(0x01, 0x06, payload)


def nav_svinfo(
    tow_ms: int, sats: Sequence[tuple[int, int, int, int, int, int, int, int]]
) -> bytes:
    """NAV-SVINFO (01 30), chip generation u-blox 6. Rows: chn, svid, flags, quality, cno,
    elev, azim, prRes (cm)."""
    body = [_SVINFO_HEAD.pack(tow_ms, len(sats), 2, 0)]
    body.extend(_SVINFO_SAT.pack(*s) for s in sats)
    return build_frame(0x01, 0x30, b"".join(body))


def tim_tm2(
    count: int,
    rising_gps_ns: int | None,
    falling_gps_ns: int | None,
    new_rising: bool,
    new_falling: bool,
    acc_ns: int = 20,
    channel: int = 0,
) -> bytes:
    """TIM-TM2 (0D 03) of a LEA-6T in running mode, both edges, time base GPS."""
    flags = TM2_MODE_RUNNING | TM2_RUN | TM2_TIMEBASE_GPS | TM2_UTC_VALID | TM2_TIME_VALID
    if new_falling:
        flags |= TM2_NEW_FALLING
    if new_rising:
        flags |= TM2_NEW_RISING

    def split(t: int | None) -> tuple[int, int, int]:
        if t is None:
            return 0, 0, 0
        week, rem = divmod(t, 604_800 * 1_000_000_000)
        ms, sub = divmod(rem, 1_000_000)
        return week, ms, sub

    wn_r, ms_r, sub_r = split(rising_gps_ns)
    wn_f, ms_f, sub_f = split(falling_gps_ns)
    payload = _TM2.pack(channel, flags, count & 0xFFFF, wn_r, wn_f, ms_r, sub_r, ms_f, sub_f,
                        acc_ns)
    return build_frame(0x0D, 0x03, payload)
