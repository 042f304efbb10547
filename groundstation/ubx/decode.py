"""UBX frame -> record: the hot messages unpacked with ``struct`` from the layouts.

RXM-RAW/RAWX, RXM-SFRB/SFRBX, AID-EPH, TIM-TM2 and NAV-SOL/PVT/POSLLH/SVINFO/SAT become our
records (layouts in :mod:`~groundstation.ubx.layouts`); any other message stays a
:class:`Frame` (pyubx2 parses those where a tool needs them, and names them:
:func:`message_name`). A frame that passed its checksum but whose payload does not fit its
layout (shorter than its fixed part, or than its declared repeats need) becomes an
:class:`UndecodedFrame`: it is counted, logged and its bytes are kept, never dropped. So does a
frame whose time cannot belong to the session (a GPS week or time of week out of range, a value
that is not a finite number, a time far from the session's own clock: the one rule of
:mod:`groundstation.rules.plausible`, which the bulk decoder applies too): ``implausible``, counted
apart.

The values are those pyubx2 gives for the same fields: ``tests/unit/test_decode.py`` checks it
field for field on every real recording and on the simulator's output.
"""

from __future__ import annotations

import logging
import math
import struct
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from groundstation.geodesy import ecef_to_llh, llh_to_ecef
from groundstation.gpstime import NS_PER_WEEK, format_gps
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
    positional_constructor,
)
from groundstation.rules import plausible as P
from groundstation.rules.phase import RawPhase, RawxPhase
from groundstation.ubx import layouts as L
from groundstation.ubx.timemark import timemark_from_fields

log = logging.getLogger("groundstation.decode")

RXM_RAW = L.RXM_RAW.key
RXM_SFRB = L.RXM_SFRB.key
RXM_SFRBX = L.RXM_SFRBX.key
RXM_RAWX = L.RXM_RAWX.key
TIM_TM2 = L.TIM_TM2.key
AID_EPH = L.AID_EPH.key
NAV_POSLLH = L.NAV_POSLLH.key
NAV_SOL = L.NAV_SOL.key
NAV_PVT = L.NAV_PVT.key
NAV_SVINFO = L.NAV_SVINFO.key
NAV_SAT = L.NAV_SAT.key


def _expect(names: tuple[str, ...], spec: str) -> None:
    # The handlers below unpack positionally: fail at import if a layout's order changes.
    if names != tuple(spec.split()):
        raise RuntimeError(f"layout changed: {names} != {spec}")


_expect(L.RXM_RAW.head_names, "iTOW week numSV reserved1")
_expect(L.RXM_RAW.block_names, "cpMes prMes doMes sv mesQI cno lli")
_expect(L.RXM_RAWX.head_names, "rcvTow week leapS numMeas recStat version")
_expect(L.RXM_RAWX.block_names,
        "prMes cpMes doMes gnssId svId sigId freqId locktime cno prStdev cpStdev doStdev "
        "trkStat reserved2")  # fmt: skip
_expect(L.TIM_TM2.head_names,
        "ch flags count wnR wnF towMsR towSubMsR towMsF towSubMsF accEst")  # fmt: skip
_expect(L.NAV_SVINFO.block_names, "chn svid flags quality cno elev azim prRes")
_expect(L.NAV_SAT.block_names, "gnssId svId cno elev azim prRes flags")

_RAW_HEAD, _RAW_SV = L.RXM_RAW.head, L.RXM_RAW.block
_RAWX_HEAD, _RAWX_MEAS = L.RXM_RAWX.head, L.RXM_RAWX.block
_TM2 = L.TIM_TM2.head
_SFRB = struct.Struct(L.RXM_SFRB.head.format + L.RXM_SFRB.block.format[1:] * 10)
_SFRBX_HEAD = L.RXM_SFRBX.head
_EPH_HEAD = L.AID_EPH.head
_EPH_SF = L.AID_EPH.block
_SOL = L.NAV_SOL.head
_PVT = L.NAV_PVT.head
_POSLLH = L.NAV_POSLLH.head
_SVINFO_HEAD, _SVINFO_SAT = L.NAV_SVINFO.head, L.NAV_SVINFO.block
_SAT_HEAD, _SAT_SV = L.NAV_SAT.head, L.NAV_SAT.block

_PR_VALID = L.RAWX_TRK_STAT.mask("prValid")
_CP_VALID = L.RAWX_TRK_STAT.mask("cpValid")
_HALF_SUB = L.RAWX_TRK_STAT.mask("subHalfCyc")
_STD = L.RAWX_PR_STDEV.mask("prStd")
assert _STD == L.RAWX_CP_STDEV.mask("cpStd") == L.RAWX_DO_STDEV.mask("doStd")
_LEAP_VALID = L.RAWX_REC_STAT.mask("leapSec")
_CLK_RESET = L.RAWX_REC_STAT.mask("clkReset")
_LLI_SLIP = L.RAW_LLI.mask("slip")
_LLI_HALF = L.RAW_LLI.mask("halfCyc")
_SOL_FIX_OK = L.NAV_SOL_FLAGS.mask("gpsfixOK")
_SOL_WKN_SET = L.NAV_SOL_FLAGS.mask("wknSet")
_PVT_FIX_OK = L.NAV_PVT_FLAGS.mask("gnssFixOk")
_SVINFO_USED = L.NAV_SVINFO_FLAGS.mask("svUsed")
_SVINFO_UNHEALTHY = L.NAV_SVINFO_FLAGS.mask("unhealthy")
_SVINFO_QUALITY = L.NAV_SVINFO_QUALITY.mask("qualityInd")
_SAT_QUALITY = L.NAV_SAT_FLAGS.mask("qualityInd")
_SAT_USED = L.NAV_SAT_FLAGS.mask("svUsed")
_SAT_HEALTH_LO, _SAT_HEALTH_W = L.NAV_SAT_FLAGS.parts["health"]
_LAT_SCALE = L.NAV_PVT.scales["lat"]
assert L.NAV_POSLLH.scales["lat"] == _LAT_SCALE == L.NAV_POSLLH.scales["lon"]
# pyubx2's value round(raw * 1e-7, 12) is exactly raw / 1e7 for every int32 raw, at a tenth of
# round()'s cost: the product is within 3e-14 of the 7-decimal quotient (far inside half a
# 12-decimal step) and the division is correctly rounded.
assert _LAT_SCALE == 1e-7 and 7 <= L.SCALE_ROUND <= 12
_LAT_DIVISOR = 1e7


class PayloadError(ValueError):
    """A payload that does not fit its message's layout."""


class ImplausibleTime(Exception):
    """A frame whose time cannot belong to the session (:mod:`groundstation.rules.plausible`)."""


IMPLAUSIBLE_LOGGED = 20
"""Implausible frames of one type logged one by one; after that one line per 1000 (a burst of
noise must not flood the journal: the counts are in the status and the summaries)."""


def message_name(cls: int, mid: int) -> str:
    """The message name as pyubx2 spells it, or ``UBX-CC-II`` for one pyubx2 does not know."""
    key = (cls, mid)
    name = _NAMES.get(key)
    if name is None:
        # pyubx2 knows the long tail; imported on first need (it takes ~50 ms to import)
        from pyubx2.ubxtypes_core import UBX_MSGIDS

        name = UBX_MSGIDS.get(bytes(key)) or f"UBX-{cls:02X}-{mid:02X}"
        _NAMES[key] = name
    return name


_NAMES: dict[tuple[int, int], str] = {k: m.name for k, m in L.MESSAGES.items()}


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


_SVID = tuple(gnss_of_svid(s) for s in range(256))  # one lookup per satellite in the hot path


# the records made per frame or per satellite, built without the frozen ``__init__``'s cost
_sat_obs = positional_constructor(SatObs)
_sv_info_sat = positional_constructor(SvInfoSat)
_raw_epoch = positional_constructor(RawEpoch)
_nav_solution = positional_constructor(NavSolution)
_sv_info = positional_constructor(SvInfo)
_ephemeris = positional_constructor(Ephemeris)
_subframe = positional_constructor(Subframe)
# SatObs.half_cycle_unresolved and .slip of each LLI byte (a lookup instead of two bool calls)
_LLI_HALF_OF = tuple(bool(b & _LLI_HALF) for b in range(256))
_LLI_SLIP_OF = tuple(bool(b & _LLI_SLIP) for b in range(256))


def _receiver_lli(svid: int, lli: int, cp: float) -> int:
    """RXM-RAW LLI of a message without a GPS week: the receiver's byte as it is."""
    return lli


def _need(name: str, payload: bytes, size: int, count: int | None = None, unit: str = "") -> None:
    # the message is formatted only on failure: this runs for every frame
    if len(payload) < size:
        what = name if count is None else f"{name} with {count} {unit}"
        raise PayloadError(f"{len(payload)}-byte payload, {what} needs {size}")


@dataclass(frozen=True, slots=True)
class DecoderStats:
    decoded: dict[str, int]
    passed_through: int
    undecodable: int
    undecodable_by_type: dict[str, int]
    implausible: int = 0
    """Frames whose time cannot belong to the session (also in ``undecodable``)."""
    implausible_by_type: dict[str, int] = field(default_factory=dict)
    time_jumps: int = 0
    """Confirmed jumps of the session's clock (the receiver's new time)."""


class Decoder:
    """Maps frames to records.

    It keeps a little state: the phase rule's per-signal state (:mod:`groundstation.rules.phase`,
    the same LLI as the RINEX files), the session's clock (:mod:`groundstation.rules.plausible`,
    which times can belong to the session) and the latest leap-second count the receiver
    reported (to put UTC-based time marks on GPS time).

    Args:
        raise_on_error: raise :class:`~groundstation.errors.DecodeError` instead of returning an
            :class:`UndecodedFrame` (for tests and strict offline tools); an implausible time is
            never raised, it is the rule.
        now_ns: the host's clock for frames without a reception time (default: now).
    """

    def __init__(
        self, *, raise_on_error: bool = False, now_ns: int | None = None
    ) -> None:
        self.raise_on_error = raise_on_error
        self.clock = P.SessionClock(now_ns)
        self._decoded: Counter[str] = Counter()
        self._undecodable: Counter[str] = Counter()
        self._implausible: Counter[str] = Counter()
        self._taken: deque[tuple[str, int]] = deque(maxlen=P.ODD_RUN_MAX + 1)  # as the clock's
        self.refuted_offsets: list[int] = []
        """Stream offsets of epochs decoded, then found to be odd ones by the epochs after them
        (``clock.refuted`` are their times): a reader that collects epochs leaves them out."""
        self._passed = 0
        self._raw_phase = RawPhase()  # the phase rule's per-signal state (rules/phase.py)
        self._rawx_phase = RawxPhase()
        self.leap_s: int | None = None
        handlers: dict[tuple[int, int], Callable[[Frame], Record]] = {
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
        # by (class << 8 | id), with the message's name: one lookup per frame
        self._dispatch: dict[int, tuple[Callable[[Frame], Record], str]] = {
            (cls << 8) | mid: (handler, _NAMES[cls, mid])
            for (cls, mid), handler in handlers.items()
        }

    @property
    def stats(self) -> DecoderStats:
        return DecoderStats(
            decoded=dict(self._decoded),
            passed_through=self._passed,
            undecodable=sum(self._undecodable.values()) + sum(self._implausible.values()),
            undecodable_by_type=dict(self._undecodable + self._implausible),
            implausible=sum(self._implausible.values()),
            implausible_by_type=dict(self._implausible),
            time_jumps=len(self.clock.jumps),
        )

    def decode(self, frame: Frame) -> Record:
        entry = self._dispatch.get((frame.cls << 8) | frame.id)
        if entry is None:
            self._passed += 1
            return frame
        handler, name = entry
        try:
            record = handler(frame)
        except ImplausibleTime as err:
            self._count_implausible(name, frame, err)
            return UndecodedFrame(frame, f"implausible time: {err}", implausible=True)
        except (ValueError, struct.error, ArithmeticError) as err:  # PayloadError, or math
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

    def judge_epoch(self, frame: Frame) -> int | None:
        """Take a measurement epoch (RXM-RAW / RXM-RAWX) into the session's clock without
        decoding its measurements, for a reader that wants only marks and fixes (the solver):
        the marks are then judged as :meth:`decode` judges them after the same frames. Returns
        the epoch's GPS time when it is plausible, else None (an implausible one is counted and
        logged, a payload that does not fit is not an epoch, week 0 has no time yet)."""
        name = "RXM-RAW" if frame.key == RXM_RAW else "RXM-RAWX"
        rows_of = _raw_epoch_rows if frame.key == RXM_RAW else _rawx_epoch_rows
        try:
            week, tow_ns, _ = rows_of(frame.payload)
            self._epoch(week, tow_ns, frame)
        except PayloadError:
            return None
        except ImplausibleTime as err:
            self._count_implausible(name, frame, err)
            return None
        return week * NS_PER_WEEK + tow_ns if week != 0 else None

    def _count_implausible(self, name: str, frame: Frame, err: ImplausibleTime) -> None:
        n = self._implausible[name] = self._implausible[name] + 1
        if n <= IMPLAUSIBLE_LOGGED or n % 1000 == 0:
            log.warning(
                "implausible %s at offset %d (%d bytes kept, not decoded; %d so far): %s",
                name, frame.offset, len(frame.raw), n, err,
            )

    def _log_jump(self) -> None:
        if self.clock.jumps:
            jump = self.clock.jumps[-1]
            log.warning(
                "the receiver's time jumped %s (to %s), confirmed by a second epoch: the "
                "session's clock follows it; the epoch at %s before it was not used",
                "from the host's clock" if jump.from_t_gps_ns is None else
                P.span_text(jump.to_t_gps_ns - jump.from_t_gps_ns),
                format_gps(jump.to_t_gps_ns), format_gps(jump.skipped_t_gps_ns),
            )

    # -- observations -------------------------------------------------------------------------

    def _epoch(self, week: int, tow_ns: int, frame: Frame) -> None:
        """The session's clock takes an epoch within the ranges (week 0: no time yet). When it
        shows the epoch taken before it to be the odd one, that one is counted implausible now
        (it was passed on; a reader that collects epochs leaves out ``clock.refuted``)."""
        if week != 0:
            refuted, jumps = len(self.clock.refuted), len(self.clock.jumps)
            why = self.clock.epoch(week * NS_PER_WEEK + tow_ns, frame.t_host_ns)
            if why is not None:
                raise ImplausibleTime(why)
            for _ in range(len(self.clock.refuted) - refuted):
                name, offset = self._taken.pop()
                self._implausible[name] += 1
                self.refuted_offsets.append(offset)
                log.warning("implausible %s at offset %d, found by the epochs after it: %s",
                            name, offset, P.ODD_EPOCH)
            if len(self.clock.jumps) != jumps:
                self._taken.clear()
                self._log_jump()
            self._taken.append((_NAMES[frame.key], frame.offset))

    def _rxm_raw(self, frame: Frame) -> RawEpoch:
        p = frame.payload
        week, tow_ns, rows = _raw_epoch_rows(p)
        self._epoch(week, tow_ns, frame)
        # the hot loop (one turn per satellite): everything it uses bound locally
        svid_map, half_of, slip_of, sat_obs = _SVID, _LLI_HALF_OF, _LLI_SLIP_OF, _sat_obs
        sats: list[SatObs] = []
        append = sats.append
        # the phase rule (rules/phase.py): slips carried over blank phase; a week-0 message (cold
        # start) keeps the receiver's bits and does not advance the rule's state
        rule = self._raw_phase.lli if week != 0 else _receiver_lli
        for cp, pr, do, svid, qi, cno, lli in rows:
            gnss, sv = svid_map[svid]
            lli = rule(svid, lli, cp)
            append(sat_obs(gnss, sv, cp, pr, do, cno, qi, lli, half_of[lli], slip_of[lli]))
        return _raw_epoch(week, tow_ns, tuple(sats), "RXM-RAW", frame.t_host_ns)

    def _rxm_rawx(self, frame: Frame) -> RawEpoch:
        p = frame.payload
        week, tow_ns, rows = _rawx_epoch_rows(p)
        self._epoch(week, tow_ns, frame)
        _, _, leap_s, n, rec_stat, _ = _RAWX_HEAD.unpack_from(p)
        leap_valid = bool(rec_stat & _LEAP_VALID)
        if leap_valid:
            self.leap_s = leap_s
        rule = self._rawx_phase
        max_sig = -1
        sats = []
        for (pr, cp, do, gnss, sv, sig, freq, lock_ms, cno, pr_std, cp_std, do_std, trk,
             _) in rows:
            half_sub = bool(trk & _HALF_SUB)
            if week != 0:
                # The phase rule (rules/phase.py): usable phase, slip and half cycle, as in RINEX.
                ph = rule.measurement((gnss, sv, sig), gnss=gnss, trk_stat=trk, lock_ms=lock_ms,
                                      cp_cyc=cp, cp_stdev_idx=cp_std)
                cp_valid, lli = ph.cp_valid, ph.lli
            else:  # a week-0 message (cold start) must not advance the rule's state
                cp_valid, lli = bool(trk & _CP_VALID), 0
            max_sig = max(max_sig, sig)
            sats.append(_sat_obs(
                gnss, sv, cp, pr, do, cno, None, lli, _LLI_HALF_OF[lli], _LLI_SLIP_OF[lli],
                sig, freq, lock_ms, trk, bool(trk & _PR_VALID), cp_valid,
                half_sub, pr_std & _STD, cp_std & _STD, do_std & _STD,
            ))  # fmt: skip
        if week != 0 and n:
            rule.end_message(max_sig)
        return _raw_epoch(
            week,
            tow_ns,
            tuple(sats),
            "RXM-RAWX",
            frame.t_host_ns,
            leap_s=leap_s if leap_valid else None,
            clock_reset=bool(rec_stat & _CLK_RESET),
        )

    # -- time marks ---------------------------------------------------------------------------

    def _tim_tm2(self, frame: Frame) -> TimeMark:
        p = frame.payload
        _need("TIM-TM2", p, _TM2.size)
        ch, flags, count, wn_r, wn_f, ms_r, sub_r, ms_f, sub_f, acc = _TM2.unpack_from(p)
        why = P.edge_range_problem(wn_r, ms_r, sub_r) or P.edge_range_problem(wn_f, ms_f, sub_f)
        if why is not None:
            raise ImplausibleTime(why)
        tm = timemark_from_fields(
            ch, flags, count, wn_r, ms_r, sub_r, wn_f, ms_f, sub_f, acc, leap_s=self.leap_s,
            t_host_ns=frame.t_host_ns,
        )
        why = self.clock.mark(
            ((tm.falling_t_gps_ns, tm.new_falling), (tm.rising_t_gps_ns, tm.new_rising)),
            frame.t_host_ns,
        )
        if why is not None:
            raise ImplausibleTime(why)
        return tm

    # -- navigation data ----------------------------------------------------------------------

    def _rxm_sfrb(self, frame: Frame) -> Subframe:
        p = frame.payload
        _need("RXM-SFRB", p, _SFRB.size)
        chn, svid, *words = _SFRB.unpack_from(p)
        gnss, sv = _SVID[svid]
        return _subframe(gnss, sv, tuple(words), "RXM-SFRB", channel=chn, t_host_ns=frame.t_host_ns)

    def _rxm_sfrbx(self, frame: Frame) -> Subframe:
        p = frame.payload
        _need("RXM-SFRBX", p, 8)
        gnss, sv, sig, freq, n, chn, _, _ = _SFRBX_HEAD.unpack_from(p)
        _need("RXM-SFRBX", p, 8 + 4 * n, n, "words")
        words = struct.unpack_from(f"<{n}I", p, 8)
        return _subframe(
            gnss, sv, words, "RXM-SFRBX", channel=chn, sig_id=sig, freq_id=freq,
            t_host_ns=frame.t_host_ns,
        )

    def _aid_eph(self, frame: Frame) -> Ephemeris:
        p = frame.payload
        _need("AID-EPH", p, 8)
        svid, how = _EPH_HEAD.unpack_from(p)
        if len(p) < 8 + _EPH_SF.size:  # no ephemeris for this satellite: header only
            return _ephemeris(svid, how, (), (), (), frame.t_host_ns)
        w = _EPH_SF.unpack_from(p, 8)
        return _ephemeris(svid, how, w[0:8], w[8:16], w[16:24], frame.t_host_ns)

    # -- receiver's own solution --------------------------------------------------------------

    def _nav_sol(self, frame: Frame) -> NavSolution:
        p = frame.payload
        _need("NAV-SOL", p, _SOL.size)
        (itow, ftow, week, gps_fix, flags, x, y, z, p_acc, _, _, _, _, _, _, num_sv,
         _) = _SOL.unpack_from(p)  # fmt: skip
        why = self.clock.fix(itow, ftow, week if flags & _SOL_WKN_SET else None,
                             frame.t_host_ns)
        if why is not None:
            raise ImplausibleTime(why)
        ecef = (x / 100.0, y / 100.0, z / 100.0)
        has_pos = any(ecef)
        lat = lon = h = None
        if has_pos:
            lat, lon, h = ecef_to_llh(*ecef)
        return _nav_solution(
            source="NAV-SOL",
            tow_ns=itow * 1_000_000 + ftow,
            gps_week=week if flags & _SOL_WKN_SET else None,
            fix_type=gps_fix,
            fix_ok=bool(flags & _SOL_FIX_OK),
            num_sv=num_sv,
            ecef_m=ecef if has_pos else None,
            lat_deg=lat,
            lon_deg=lon,
            height_m=h,
            h_acc_m=None,
            v_acc_m=None,
            p_acc_m=p_acc / 100.0,
            t_host_ns=frame.t_host_ns,
        )

    def _tow_ms(self, itow: int, frame: Frame) -> None:
        """A fix or tracking message's time of week: in range, and near the session's clock."""
        why = self.clock.fix(itow, 0, None, frame.t_host_ns)
        if why is not None:
            raise ImplausibleTime(why)

    def _llh_solution(
        self, source: str, frame: Frame, itow: int, lat_raw: int, lon_raw: int, height_mm: int,
        h_acc: int, v_acc: int, fix_type: int, fix_ok: bool, num_sv: int | None,
    ) -> NavSolution:
        self._tow_ms(itow, frame)
        lat = lat_raw / _LAT_DIVISOR
        lon = lon_raw / _LAT_DIVISOR
        h = height_mm / 1000.0
        has_pos = not (lat == 0.0 and lon == 0.0)
        return _nav_solution(
            source=source,
            tow_ns=itow * 1_000_000,
            gps_week=None,
            fix_type=fix_type,
            fix_ok=fix_ok,
            num_sv=num_sv,
            ecef_m=llh_to_ecef(lat, lon, h) if has_pos else None,
            lat_deg=lat if has_pos else None,
            lon_deg=lon if has_pos else None,
            height_m=h if has_pos else None,
            h_acc_m=h_acc / 1000.0,
            v_acc_m=v_acc / 1000.0,
            p_acc_m=math.hypot(h_acc, v_acc) / 1000.0,
            t_host_ns=frame.t_host_ns,
        )

    def _nav_pvt(self, frame: Frame) -> NavSolution:
        p = frame.payload
        _need("NAV-PVT", p, L.NAV_PVT.min_length or _PVT.size)
        if len(p) < _PVT.size:  # older firmware: the missing trailing fields read as zero
            p = p + bytes(_PVT.size - len(p))
        v = dict(zip(L.NAV_PVT.head_names, _PVT.unpack_from(p), strict=True))
        return self._llh_solution(
            "NAV-PVT", frame, v["iTOW"], v["lat"], v["lon"], v["height"], v["hAcc"], v["vAcc"],
            v["fixType"], bool(v["flags"] & _PVT_FIX_OK), v["numSV"],
        )

    def _nav_posllh(self, frame: Frame) -> NavSolution:
        p = frame.payload
        _need("NAV-POSLLH", p, _POSLLH.size)
        itow, lon, lat, height, _, h_acc, v_acc = _POSLLH.unpack_from(p)
        return self._llh_solution(
            "NAV-POSLLH", frame, itow, lat, lon, height, h_acc, v_acc, -1, True, None
        )

    # -- tracking -----------------------------------------------------------------------------

    def _nav_svinfo(self, frame: Frame) -> SvInfo:
        p = frame.payload
        _need("NAV-SVINFO", p, 8)
        itow, n, _, _ = _SVINFO_HEAD.unpack_from(p)
        end = 8 + 12 * n
        _need("NAV-SVINFO", p, end, n, "channels")
        self._tow_ms(itow, frame)
        svid_map = _SVID
        sats = []
        for _, svid, flags, quality, cno, elev, azim, _ in _SVINFO_SAT.iter_unpack(p[8:end]):
            gnss, sv = svid_map[svid]
            sats.append(_sv_info_sat(
                gnss, sv if gnss != 1 else svid, cno, elev, azim, bool(flags & _SVINFO_USED),
                quality & _SVINFO_QUALITY, not flags & _SVINFO_UNHEALTHY,
            ))  # fmt: skip
        return _sv_info("NAV-SVINFO", itow * 1_000_000, tuple(sats), frame.t_host_ns)

    def _nav_sat(self, frame: Frame) -> SvInfo:
        p = frame.payload
        _need("NAV-SAT", p, 8)
        itow, _, n = _SAT_HEAD.unpack_from(p)
        end = 8 + 12 * n
        _need("NAV-SAT", p, end, n, "satellites")
        self._tow_ms(itow, frame)
        sats = [
            _sv_info_sat(
                gnss, sv, cno, elev, azim, bool(flags & _SAT_USED), flags & _SAT_QUALITY,
                (flags >> _SAT_HEALTH_LO) & ((1 << _SAT_HEALTH_W) - 1) != 2,
            )
            for gnss, sv, cno, elev, azim, _, flags in _SAT_SV.iter_unpack(p[8:end])
        ]
        return _sv_info("NAV-SAT", itow * 1_000_000, tuple(sats), frame.t_host_ns)


_PR_MAX, _CP_MAX, _DO_MAX = P.PR_MAX_M, P.CP_MAX_CYC, P.DO_MAX_HZ


def _raw_epoch_rows(p: bytes) -> tuple[int, int, list[tuple[Any, ...]]]:
    """An RXM-RAW payload's week, time of week (ns) and satellite rows, the receiver's ranges
    checked (:mod:`groundstation.rules.plausible`, rule 1).

    Raises:
        PayloadError: too short for its satellites.
        ImplausibleTime: out of the ranges, or a value that is not a finite number.
    """
    _need("RXM-RAW", p, 8)
    itow, week, n, _ = _RAW_HEAD.unpack_from(p)
    end = 8 + 24 * n
    _need("RXM-RAW", p, end, n, "satellites")
    why = P.tow_ms_problem(itow) or (P.week_problem(week) if week != 0 else None)
    if why is not None:
        raise ImplausibleTime(why)
    rows = list(_RAW_SV.iter_unpack(p[8:end]))
    for r in rows:  # rules.plausible.measurement_ok, inlined (a NaN fails)
        if not (-_CP_MAX <= r[0] <= _CP_MAX and -_PR_MAX <= r[1] <= _PR_MAX
                and -_DO_MAX <= r[2] <= _DO_MAX):
            raise ImplausibleTime(
                f"a measurement no receiver makes (pr {r[1]}, cp {r[0]}, do {r[2]})")
    return week, itow * 1_000_000, rows


def _rawx_epoch_rows(p: bytes) -> tuple[int, int, list[tuple[Any, ...]]]:
    """:func:`_raw_epoch_rows` for RXM-RAWX (``rcvTow`` in s, rounded to the ns)."""
    _need("RXM-RAWX", p, 16)
    rcv_tow, week, leap_s, n, rec_stat, _ = _RAWX_HEAD.unpack_from(p)
    end = 16 + 32 * n
    _need("RXM-RAWX", p, end, n, "measurements")
    why = P.tow_s_problem(rcv_tow) or (P.week_problem(week) if week != 0 else None)
    if why is None and week != 0 and rec_stat & _LEAP_VALID:
        why = P.leap_problem(leap_s, week * NS_PER_WEEK + round(rcv_tow * 1e9))
    if why is not None:
        raise ImplausibleTime(why)
    rows = list(_RAWX_MEAS.iter_unpack(p[16:end]))
    for r in rows:  # rules.plausible.measurement_ok, inlined
        if not (-_PR_MAX <= r[0] <= _PR_MAX and -_CP_MAX <= r[1] <= _CP_MAX
                and -_DO_MAX <= r[2] <= _DO_MAX):
            raise ImplausibleTime(
                f"a measurement no receiver makes (pr {r[0]}, cp {r[1]}, do {r[2]})")
    return week, round(rcv_tow * 1e9), rows
