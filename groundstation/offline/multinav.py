"""GLONASS, Galileo and BeiDou broadcast ephemerides of a recording, from u-blox RXM-SFRBX.

The receiver-specific part: where RXM-SFRBX keeps a GLONASS string, a Galileo I/NAV page or a
BeiDou D1 subframe, and
what the receiver's clock said when the message arrived (GLONASS times are times of day, so the
day comes from the nearest receiver epoch, NAV-SOL or NAV-TIMEGPS before it). Decoding is
:mod:`groundstation.gnss.glonass`'s, :mod:`~groundstation.gnss.galileo`'s and
:mod:`~groundstation.gnss.beidou`'s job; the GPS part of
the same messages stays in :mod:`groundstation.offline.ephemeris`.
"""

from __future__ import annotations

import datetime as dt
import struct
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
from numpy.lib.stride_tricks import sliding_window_view

from groundstation import gpstime
from groundstation.gnss import glonass
from groundstation.rules import plausible
from groundstation.ubx.fastraw import FrameIndex, SessionTimes

if TYPE_CHECKING:
    from groundstation.gnss.kepler import KeplerEphemeris

RXM_SFRBX = (0x02, 0x13)
GNSS_GALILEO = 2
GNSS_BEIDOU = 3
GNSS_GLONASS = 6
_GAL_FNAV_SIG = 3
_GAL_E6_SIG = 8
_BDS_CNAV_SIGS = (6, 8)  # B1C and B2a carry B-CNAV1/2, not D1/D2


@dataclass(slots=True)
class MultiNav:
    """GLONASS and Galileo ephemerides of a recording, in the order they were completed.

    Attributes:
        glonass: new GLONASS ephemerides (a new ``tb`` per slot).
        kepler: new Galileo ephemerides (new IODnav/toe/toc per satellite) and BeiDou D1
            ones (new toe per satellite).
        glonass_strings: GLONASS strings that passed their Hamming check.
        hamming_errors: GLONASS strings that failed it.
        galileo_pages: Galileo E1-B pages looked at.
        crc_errors: Galileo pages whose CRC failed.
    """

    glonass: list[glonass.GlonassEphemeris] = field(default_factory=list)
    kepler: list[KeplerEphemeris] = field(default_factory=list)
    glonass_strings: int = 0
    hamming_errors: int = 0
    galileo_pages: int = 0
    crc_errors: int = 0


def _fields(rows: npt.NDArray[np.uint8], at: int, dtype: str
            ) -> npt.NDArray[np.int64]:
    """One little-endian field at byte ``at`` of every payload row, as int64 (floats kept)."""
    size = np.dtype(dtype).itemsize
    return np.ascontiguousarray(rows[:, at : at + size]).view(dtype).ravel()


def _plausible(
    key: tuple[int, int], rows: npt.NDArray[np.uint8], sel: npt.NDArray[np.int64],
    week: npt.NDArray[np.int64], session: SessionTimes,
) -> npt.NDArray[np.bool_]:
    """Which of these messages' times can belong to the session (the decoder's verdicts)."""
    if key in ((0x02, 0x15), (0x02, 0x10)):  # epochs: the verdicts on them
        k = np.searchsorted(session.frame, sel)
        k = np.minimum(k, max(session.frame.size - 1, 0))
        if session.frame.size == 0:
            return np.zeros(sel.size, dtype=bool)
        found: npt.NDArray[np.bool_] = (session.frame[k] == sel) & session.verdicts.ok[k]
        return found
    itow = _fields(rows, 0, "<u4").tolist()
    ftow = _fields(rows, 4, "<i4").tolist()
    return np.array([
        session.fix_problem(i, t, f, w) is None
        for i, t, f, w in zip(sel.tolist(), itow, ftow, week.tolist(), strict=True)
    ], dtype=bool)


def receiver_times(
    data: bytes | memoryview, index: FrameIndex, session: SessionTimes | None = None
) -> list[tuple[int, int]]:
    """(stream offset, GPS ns) of every message that states the receiver's GPS time with a
    valid week: RXM-RAWX, RXM-RAW, NAV-SOL, NAV-TIMEGPS (week 0 or not valid: skipped; with
    ``session``, only the epochs and fixes whose times can belong to the session)."""
    arr = np.frombuffer(data, dtype=np.uint8)
    offsets: list[npt.NDArray[np.int64]] = []
    times: list[npt.NDArray[np.int64]] = []
    for key, need in (((0x02, 0x15), 16), ((0x02, 0x10), 8), ((0x01, 0x06), 12),
                      ((0x01, 0x20), 12)):
        sel = index.select(key)
        sel = sel[index.length[sel] >= need]
        if sel.size == 0:
            continue
        rows = sliding_window_view(arr, need)[index.start[sel] + 6]
        if key == (0x02, 0x15):
            tow_s = _fields(rows, 0, "<f8")
            week = _fields(rows, 8, "<u2").astype(np.int64)
            with np.errstate(invalid="ignore"):
                finite = (tow_s >= 0.0) & (tow_s < plausible.WEEK_S)  # and not NaN
            week[~finite] = 0
            tow_ns = np.rint(np.where(finite, tow_s, 0.0) * 1e9).astype(np.int64)
        elif key == (0x02, 0x10):
            tow_ns = _fields(rows, 0, "<i4").astype(np.int64) * 1_000_000
            week = _fields(rows, 4, "<i2").astype(np.int64)
        else:
            tow_ns = (_fields(rows, 0, "<u4").astype(np.int64) * 1_000_000
                      + _fields(rows, 4, "<i4"))
            week = _fields(rows, 8, "<i2").astype(np.int64)
            # the week is valid only with NAV-SOL flags bit 2 (WKNSET), NAV-TIMEGPS valid bit 1
            valid_bit = 0x04 if key == (0x01, 0x06) else 0x02
            week[(rows[:, 11] & valid_bit) == 0] = 0
        # within the receiver's ranges (a week beyond them overflows the ns below)
        keep = (week >= plausible.MIN_WEEK) & (week <= plausible.MAX_WEEK) & (tow_ns >= 0) & (
            tow_ns < gpstime.NS_PER_WEEK)
        if session is not None:
            keep &= _plausible(key, rows, sel, week, session)
        offsets.append(index.start[sel][keep])
        times.append(week[keep] * gpstime.NS_PER_WEEK + tow_ns[keep])
    if not offsets:
        return []
    off = np.concatenate(offsets)
    order = np.argsort(off, kind="stable")
    return list(zip(off[order].tolist(), np.concatenate(times)[order].tolist(), strict=True))


def today_gps_week() -> int:
    """The GPS week of the computer's clock (resolves broadcast weeks when nothing else can)."""
    return gpstime.week_tow(gpstime.datetime_to_gps_ns(dt.datetime.now(dt.UTC)))[0]


def collect_multi(
    data: bytes | memoryview,
    index: FrameIndex,
    times: list[tuple[int, int]],
    fallback_gps_ns: int | None = None,
) -> MultiNav:
    """Every new GLONASS and Galileo (I/NAV) ephemeris in a recording, in stream order.

    Args:
        data: the recording.
        index: its frame index.
        times: (stream offset, GPS ns) of the receiver's time statements, in stream order
            (:func:`receiver_times`, possibly completed from GPS subframes).
        fallback_gps_ns: a time near the data for GLONASS strings that arrive when no receiver
            time is known at all.
    """
    result = MultiNav()
    glo = glonass.GlonassAssembler()
    # The header bytes of every RXM-SFRBX with numpy; the loops see only GLONASS, Galileo and
    # BeiDou messages whose words are all there (GPS subframes are collect_ephemerides').
    arr = np.frombuffer(data, dtype=np.uint8)
    sel = index.select(RXM_SFRBX)
    sel = sel[index.length[sel] >= 8]
    p0 = index.start[sel] + 6
    gnss_a = arr[p0].astype(np.int64)
    fits = index.length[sel] >= 8 + 4 * arr[p0 + 4].astype(np.int64)
    is_glo = fits & (gnss_a == GNSS_GLONASS)
    is_kepler = fits & ((gnss_a == GNSS_GALILEO) | (gnss_a == GNSS_BEIDOU))
    # the receiver time stated last before each GLONASS message (bisect over the statements)
    offsets = np.array([o for o, _ in times], dtype=np.int64)
    last_time = np.searchsorted(offsets, index.start[sel[is_glo]], side="right") - 1
    unpack = struct.unpack_from
    for at, j in zip(p0[is_glo].tolist(), last_time.tolist(), strict=True):
        sv, _sig, freq, nwords = data[at + 1 : at + 5]
        if nwords >= 4 and 1 <= sv <= 27:
            approx = times[j][1] if j >= 0 else times[0][1] if times else fallback_gps_ns
            if approx is None:
                continue
            string, frame_id = glonass.string_from_ublox(unpack("<4I", data, at + 8))
            before = glo.hamming_errors
            eph = glo.add(sv, string, frame_id, freq - 7, approx)
            if glo.hamming_errors == before:
                result.glonass_strings += 1
            if eph is not None:
                result.glonass.append(eph)
    result.hamming_errors = glo.hamming_errors
    if is_kepler.any():
        # imported only for a recording that has Galileo or BeiDou: most have GPS and GLONASS
        # only, and imports are part of every run's start-up
        from groundstation.gnss import beidou, galileo

        gal = galileo.InavAssembler()
        bds = beidou.D1Assembler()
        for at in p0[is_kepler].tolist():
            gnss, sv, sig, _freq, nwords = data[at : at + 5]
            if (gnss == GNSS_GALILEO and nwords >= 8 and 1 <= sv <= 36
                    and sig not in (_GAL_FNAV_SIG, _GAL_E6_SIG)):
                result.galileo_pages += 1
                gal_eph = gal.add(sv, galileo.page_from_ublox(unpack("<8I", data, at + 8)))
                if gal_eph is not None:
                    result.kepler.append(gal_eph)
            elif (gnss == GNSS_BEIDOU and nwords >= 10 and 1 <= sv <= 63
                  and not beidou.is_geo(sv) and sig not in _BDS_CNAV_SIGS):
                bds_eph = bds.add(sv, beidou.subframe_from_ublox(unpack("<10I", data, at + 8)))
                if bds_eph is not None:
                    result.kepler.append(bds_eph)
        result.crc_errors = gal.crc_errors
    return result
