"""UBX frames a LEA-6T sends: RXM-RAW, RXM-SFRB, NAV-SOL, NAV-SVINFO, TIM-TM2, packed from the
protocol layouts of :mod:`groundstation.ubx.layouts` (the decoder reads the same tables), and the
UART that puts them on the wire in time (:class:`Uart`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from groundstation.gpstime import NS_PER_S, NS_PER_WEEK
from groundstation.ubx import layouts as L

_TM2 = L.TIM_TM2_FLAGS
_SOL = L.NAV_SOL_FLAGS


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


class Uart:
    """Spaces messages in time as a UART at ``baud`` would: each leaves when it is ready and
    the one before it has been sent (10 bits a byte)."""

    def __init__(self, baud: int, receiver: str) -> None:
        self.byte_ns = 10 * NS_PER_S / baud
        self.cursor = 0
        self.receiver = receiver
        self.out: list[TimedMessage] = []

    def send(self, ready_ns: int, name: str, raw: bytes, tag: int) -> None:
        t = max(self.cursor, ready_ns)
        self.out.append(TimedMessage(t, name, raw, tag, self.receiver))
        self.cursor = t + int(math.ceil(len(raw) * self.byte_ns))


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
    names = L.RXM_RAW.block_names
    return L.RXM_RAW.frame((dict(zip(names, s, strict=True)) for s in sats), iTOW=tow_ms,
                           week=week)


def rxm_sfrb(channel: int, svid: int, words: Sequence[int]) -> bytes:
    """RXM-SFRB (02 11): the 10 data words of one subframe, 24 bits each in a U4."""
    return L.RXM_SFRB.frame(({"dwrd": w & 0xFFFFFF} for w in words), chn=channel, svid=svid)


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
    return L.NAV_SOL.frame(
        iTOW=tow_ms, fTOW=f_tow_ns, week=week, gpsFix=3,
        flags=_SOL.compose(gpsfixOK=1, wknSet=1, towSet=1),
        ecefX=ecef_cm[0], ecefY=ecef_cm[1], ecefZ=ecef_cm[2], pAcc=p_acc_cm,
        ecefVX=vel_cm_s[0], ecefVY=vel_cm_s[1], ecefVZ=vel_cm_s[2], sAcc=s_acc_cm_s,
        pDOP=pdop_x100, numSV=num_sv,
    )  # fmt: skip


def nav_svinfo(
    tow_ms: int, sats: Sequence[tuple[int, int, int, int, int, int, int, int]]
) -> bytes:
    """NAV-SVINFO (01 30), chip generation u-blox 6. Rows: chn, svid, flags, quality, cno,
    elev, azim, prRes (cm)."""
    names = L.NAV_SVINFO.block_names
    return L.NAV_SVINFO.frame(
        (dict(zip(names, s, strict=True)) for s in sats), iTOW=tow_ms,
        globalFlags=L.NAV_SVINFO_GLOBAL.compose(chipGen=2),
    )


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
    flags = _TM2.compose(
        mode=1, run=1, timeBase=1, utc=1, time=1, newFallingEdge=int(new_falling),
        newRisingEdge=int(new_rising),
    )

    def split(t: int | None) -> tuple[int, int, int]:
        if t is None:
            return 0, 0, 0
        week, rem = divmod(t, NS_PER_WEEK)
        ms, sub = divmod(rem, 1_000_000)
        return week, ms, sub

    wn_r, ms_r, sub_r = split(rising_gps_ns)
    wn_f, ms_f, sub_f = split(falling_gps_ns)
    return L.TIM_TM2.frame(
        ch=channel, flags=flags, count=count & 0xFFFF, wnR=wn_r, wnF=wn_f, towMsR=ms_r,
        towSubMsR=sub_r, towMsF=ms_f, towSubMsF=sub_f, accEst=acc_ns,
    )
