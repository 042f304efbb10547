"""UBX frame -> record: ``pyubx2.UBXReader.parse`` on one verified frame, mapped to our records.

Messages we have a record for become that record; anything else stays a :class:`Frame`. A frame
that passed its checksum but that pyubx2 cannot parse becomes an :class:`UndecodedFrame`: it is
counted, logged and its bytes are kept, never dropped.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pyubx2 import UBXReader
from pyubx2.ubxtypes_core import UBX_MSGIDS

from groundstation.records import (
    Ephemeris,
    Frame,
    NavSolution,
    RawEpoch,
    Record,
    SatObs,
    Subframe,
    SvInfo,
    SvInfoSat,
    TimeMark,
    UndecodedFrame,
)
from groundstation.rules.phase import RawPhase, RawxPhase
from groundstation.ubx.timemark import timemark_from_fields

log = logging.getLogger("groundstation.decode")

RXM_RAW = (0x02, 0x10)
RXM_SFRB = (0x02, 0x11)
RXM_SFRBX = (0x02, 0x13)
RXM_RAWX = (0x02, 0x15)
TIM_TM2 = (0x0D, 0x03)
AID_EPH = (0x0B, 0x31)
NAV_POSLLH = (0x01, 0x02)
NAV_SOL = (0x01, 0x06)
NAV_PVT = (0x01, 0x07)
NAV_SVINFO = (0x01, 0x30)
NAV_SAT = (0x01, 0x35)


def message_name(cls: int, mid: int) -> str:
    """The message name as pyubx2 spells it, or ``UBX-CC-II`` for one pyubx2 does not know."""
    name = UBX_MSGIDS.get(bytes((cls, mid)))
    return name if name else f"UBX-{cls:02X}-{mid:02X}"


def gnss_of_svid(svid: int) -> tuple[int, int]:
    """(gnssId, sv) for the single-number satellite ids of RXM-RAW, RXM-SFRB and NAV-SVINFO."""
    if 1 <= svid <= 32:
        return 0, svid
    if 120 <= svid <= 158:
        return 1, svid
    if 33 <= svid <= 64:
        return 3, svid - 32
    if 65 <= svid <= 96:
        return 6, svid - 64
    if 159 <= svid <= 163:
        return 3, svid - 158
    if 193 <= svid <= 202:
        return 5, svid - 192
    if 211 <= svid <= 246:
        return 2, svid - 210
    return 6 if svid == 255 else 0, svid


def _n(msg: Any, name: str, i: int) -> Any:
    return getattr(msg, f"{name}_{i:02d}")


def _tow_ns_from_s(tow_s: float) -> int:
    return round(tow_s * 1e9)


@dataclass(frozen=True, slots=True)
class DecoderStats:
    decoded: dict[str, int]
    passed_through: int
    undecodable: int
    undecodable_by_type: dict[str, int]


class Decoder:
    """Maps frames to records.

    It keeps a little state: the phase rule's per-signal state (:mod:`groundstation.rules.phase`,
    the same LLI as the RINEX files) and the latest leap-second count the receiver
    reported (to put UTC-based time marks on GPS time).

    Args:
        raise_on_error: raise :class:`~groundstation.errors.DecodeError` instead of returning an
            :class:`UndecodedFrame` (for tests and strict offline tools).
    """

    def __init__(self, *, raise_on_error: bool = False) -> None:
        self.raise_on_error = raise_on_error
        self._decoded: Counter[str] = Counter()
        self._undecodable: Counter[str] = Counter()
        self._passed = 0
        self._raw_phase = RawPhase()  # the phase rule's per-signal state (rules/phase.py)
        self._rawx_phase = RawxPhase()
        self.leap_s: int | None = None
        self._handlers: dict[tuple[int, int], Callable[[Any, Frame], Record]] = {
            RXM_RAW: self._rxm_raw,
            RXM_RAWX: self._rxm_rawx,
            TIM_TM2: self._tim_tm2,
            RXM_SFRB: self._rxm_sfrb,
            RXM_SFRBX: self._rxm_sfrbx,
            AID_EPH: self._aid_eph,
            NAV_SOL: self._nav_sol,
            NAV_PVT: self._nav_pvt,
            NAV_POSLLH: self._nav_posllh,
            NAV_SVINFO: self._nav_svinfo,
            NAV_SAT: self._nav_sat,
        }

    @property
    def stats(self) -> DecoderStats:
        return DecoderStats(
            decoded=dict(self._decoded),
            passed_through=self._passed,
            undecodable=sum(self._undecodable.values()),
            undecodable_by_type=dict(self._undecodable),
        )

    def decode(self, frame: Frame) -> Record:
        handler = self._handlers.get((frame.cls, frame.id))
        if handler is None:
            self._passed += 1
            return frame
        name = message_name(frame.cls, frame.id)
        try:
            msg = UBXReader.parse(frame.raw, validate=0)
            record = handler(msg, frame)
        except Exception as err:  # pyubx2 raises a zoo of types on malformed payloads
            self._undecodable[name] += 1
            log.warning(
                "undecodable %s at offset %d (%d bytes kept): %s",
                name, frame.offset, len(frame.raw), err,
            )
            if self.raise_on_error:
                from groundstation.errors import DecodeError

                raise DecodeError(f"{name} at offset {frame.offset}: {err}") from err
            return UndecodedFrame(frame, f"{type(err).__name__}: {err}")
        self._decoded[name] += 1
        return record

    # -- observations -------------------------------------------------------------------------

    def _rxm_raw(self, msg: Any, frame: Frame) -> RawEpoch:
        sats = []
        for i in range(1, msg.numSV + 1):
            svid = _n(msg, "sv", i)
            gnss, sv = gnss_of_svid(svid)
            lli = _n(msg, "lli", i)
            if msg.week != 0:  # the phase rule: slips carried over blank phase
                lli = self._raw_phase.lli(svid, lli, _n(msg, "cpMes", i))
            sats.append(
                SatObs(
                    gnss=gnss,
                    sv=sv,
                    carrier_phase_cyc=_n(msg, "cpMes", i),
                    pseudorange_m=_n(msg, "prMes", i),
                    doppler_hz=_n(msg, "doMes", i),
                    cno_dbhz=_n(msg, "cno", i),
                    mes_qi=_n(msg, "mesQI", i),
                    lli=lli,
                    half_cycle_unresolved=bool(lli & 2),
                    slip=bool(lli & 1),
                )
            )
        return RawEpoch(msg.week, msg.iTOW * 1_000_000, tuple(sats), "RXM-RAW", frame.t_host_ns)

    def _rxm_rawx(self, msg: Any, frame: Frame) -> RawEpoch:
        p = frame.payload
        rec_stat = p[12]
        leap_valid = bool(rec_stat & 1)
        if leap_valid:
            self.leap_s = msg.leapS
        sats = []
        for i in range(1, msg.numMeas + 1):
            base = 16 + 32 * (i - 1)
            trk = p[base + 30]
            gnss, sv, sig = _n(msg, "gnssId", i), _n(msg, "svId", i), _n(msg, "sigId", i)
            lock_ms = _n(msg, "locktime", i)
            half_sub = bool(trk & 8)
            # The phase rule (rules/phase.py): usable phase, slip and half cycle, as in RINEX.
            ph = self._rawx_phase.measurement(
                (gnss, sv, sig), gnss=gnss, trk_stat=trk, lock_ms=lock_ms,
                cp_cyc=_n(msg, "cpMes", i), cp_stdev_idx=p[base + 28],
            ) if msg.week != 0 else None
            cp_valid = ph.cp_valid if ph is not None else bool(trk & 2)
            lli = ph.lli if ph is not None else 0
            slip = bool(lli & 1)
            half_unresolved = bool(lli & 2)
            sats.append(
                SatObs(
                    gnss=gnss,
                    sv=sv,
                    carrier_phase_cyc=_n(msg, "cpMes", i),
                    pseudorange_m=_n(msg, "prMes", i),
                    doppler_hz=_n(msg, "doMes", i),
                    cno_dbhz=_n(msg, "cno", i),
                    mes_qi=None,
                    lli=lli,
                    half_cycle_unresolved=half_unresolved,
                    slip=slip,
                    sig_id=sig,
                    freq_id=_n(msg, "freqId", i),
                    locktime_ms=lock_ms,
                    trk_stat=trk,
                    pr_valid=bool(trk & 1),
                    cp_valid=cp_valid,
                    half_cycle_subtracted=half_sub,
                    pr_stdev_idx=p[base + 27] & 0x0F,
                    cp_stdev_idx=p[base + 28] & 0x0F,
                    do_stdev_idx=p[base + 29] & 0x0F,
                )
            )
        if msg.week != 0 and msg.numMeas:
            sig_ids = (_n(msg, "sigId", i) for i in range(1, msg.numMeas + 1))
            self._rawx_phase.end_message(max(sig_ids))
        return RawEpoch(
            msg.week,
            _tow_ns_from_s(msg.rcvTow),
            tuple(sats),
            "RXM-RAWX",
            frame.t_host_ns,
            leap_s=msg.leapS if leap_valid else None,
            clock_reset=bool(rec_stat & 2),
        )

    # -- time marks ---------------------------------------------------------------------------

    def _tim_tm2(self, msg: Any, frame: Frame) -> TimeMark:
        return timemark_from_fields(
            msg.ch, frame.payload[1], msg.count, msg.wnR, msg.towMsR, msg.towSubMsR, msg.wnF,
            msg.towMsF, msg.towSubMsF, msg.accEst, leap_s=self.leap_s, t_host_ns=frame.t_host_ns,
        )

    # -- navigation data ----------------------------------------------------------------------

    def _rxm_sfrb(self, msg: Any, frame: Frame) -> Subframe:
        gnss, sv = gnss_of_svid(msg.svid)
        words = tuple(int.from_bytes(_n(msg, "dwrd", i), "little") for i in range(1, 11))
        return Subframe(gnss, sv, words, "RXM-SFRB", channel=msg.chn, t_host_ns=frame.t_host_ns)

    def _rxm_sfrbx(self, msg: Any, frame: Frame) -> Subframe:
        words = tuple(int(_n(msg, "dwrd", i)) for i in range(1, msg.numWords + 1))
        return Subframe(
            msg.gnssId,
            msg.svId,
            words,
            "RXM-SFRBX",
            channel=msg.chn,
            sig_id=msg.sigId,
            freq_id=msg.freqId,
            t_host_ns=frame.t_host_ns,
        )

    def _aid_eph(self, msg: Any, frame: Frame) -> Ephemeris:
        if len(frame.payload) < 104:
            return Ephemeris(msg.svid, msg.how, (), (), (), frame.t_host_ns)

        def sf(k: int) -> tuple[int, ...]:
            return tuple(int(getattr(msg, f"sf{k}d{j}_01")) for j in range(1, 9))

        return Ephemeris(msg.svid, msg.how, sf(1), sf(2), sf(3), frame.t_host_ns)

    # -- receiver's own solution --------------------------------------------------------------

    def _nav_sol(self, msg: Any, frame: Frame) -> NavSolution:
        from groundstation.geodesy import ecef_to_llh

        ecef = (msg.ecefX / 100.0, msg.ecefY / 100.0, msg.ecefZ / 100.0)
        has_pos = any(ecef)
        lat = lon = h = None
        if has_pos:
            lat, lon, h = ecef_to_llh(*ecef)
        return NavSolution(
            source="NAV-SOL",
            tow_ns=msg.iTOW * 1_000_000 + msg.fTOW,
            gps_week=msg.week if msg.wknSet else None,
            fix_type=msg.gpsFix,
            fix_ok=bool(msg.gpsfixOK),
            num_sv=msg.numSV,
            ecef_m=ecef if has_pos else None,
            lat_deg=lat,
            lon_deg=lon,
            height_m=h,
            h_acc_m=None,
            v_acc_m=None,
            p_acc_m=msg.pAcc / 100.0,
            t_host_ns=frame.t_host_ns,
        )

    def _llh_solution(
        self, source: str, msg: Any, frame: Frame, fix_type: int, fix_ok: bool, num_sv: int | None
    ) -> NavSolution:
        from groundstation.geodesy import llh_to_ecef

        lat, lon, h = float(msg.lat), float(msg.lon), msg.height / 1000.0
        has_pos = not (lat == 0.0 and lon == 0.0)
        return NavSolution(
            source=source,
            tow_ns=msg.iTOW * 1_000_000,
            gps_week=None,
            fix_type=fix_type,
            fix_ok=fix_ok,
            num_sv=num_sv,
            ecef_m=llh_to_ecef(lat, lon, h) if has_pos else None,
            lat_deg=lat if has_pos else None,
            lon_deg=lon if has_pos else None,
            height_m=h if has_pos else None,
            h_acc_m=msg.hAcc / 1000.0,
            v_acc_m=msg.vAcc / 1000.0,
            p_acc_m=math.hypot(msg.hAcc, msg.vAcc) / 1000.0,
            t_host_ns=frame.t_host_ns,
        )

    def _nav_pvt(self, msg: Any, frame: Frame) -> NavSolution:
        return self._llh_solution(
            "NAV-PVT", msg, frame, msg.fixType, bool(msg.gnssFixOk), msg.numSV
        )

    def _nav_posllh(self, msg: Any, frame: Frame) -> NavSolution:
        return self._llh_solution("NAV-POSLLH", msg, frame, -1, True, None)

    # -- tracking -----------------------------------------------------------------------------

    def _nav_svinfo(self, msg: Any, frame: Frame) -> SvInfo:
        sats = []
        for i in range(1, msg.numCh + 1):
            gnss, sv = gnss_of_svid(_n(msg, "svid", i))
            sats.append(
                SvInfoSat(
                    gnss=gnss,
                    sv=sv if gnss != 1 else _n(msg, "svid", i),
                    cno_dbhz=_n(msg, "cno", i),
                    elev_deg=_n(msg, "elev", i),
                    azim_deg=_n(msg, "azim", i),
                    used=bool(_n(msg, "svUsed", i)),
                    quality=_n(msg, "qualityInd", i),
                    healthy=not _n(msg, "unhealthy", i),
                )
            )
        return SvInfo("NAV-SVINFO", msg.iTOW * 1_000_000, tuple(sats), frame.t_host_ns)

    def _nav_sat(self, msg: Any, frame: Frame) -> SvInfo:
        sats = []
        for i in range(1, msg.numSvs + 1):
            sats.append(
                SvInfoSat(
                    gnss=_n(msg, "gnssId", i),
                    sv=_n(msg, "svId", i),
                    cno_dbhz=_n(msg, "cno", i),
                    elev_deg=_n(msg, "elev", i),
                    azim_deg=_n(msg, "azim", i),
                    used=bool(_n(msg, "svUsed", i)),
                    quality=_n(msg, "qualityInd", i),
                    healthy=_n(msg, "health", i) != 2,
                )
            )
        return SvInfo("NAV-SAT", msg.iTOW * 1_000_000, tuple(sats), frame.t_host_ns)
