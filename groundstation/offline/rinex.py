"""UBX recording → RINEX 2.11/3.04 observation and navigation files and the time-mark table.

Observations follow RTKLIB demo5's u-blox rules (``ublox.c`` ``decode_rxmraw`` and
``decode_rxmrawx``) so that every epoch convbin writes is reproduced value for value:

- RXM-RAW: values as sent, LLI = the receiver's ``lli`` byte (bit 0 slip, bit 1 half cycle).
- RXM-RAWX: pseudorange blank unless ``trkStat`` bit 0; phase blank unless ``trkStat`` bit 1,
  ``cpMes != -0.5`` and ``cpStdev`` within the receiver class's limit (5 for u-blox 8, 14 once a
  second-band signal was seen in an earlier message); BeiDou GEO phase shifted by +0.5 cycle;
  a slip is a lock-time reset or decrease, a change of the half-cycle-subtracted bit or
  ``cpStdev`` = 15; a slip seen while the phase was blank is carried to the next valid phase;
  LLI bit 1 = half cycle not yet resolved (SBAS: lock time <= 8 s) on a valid phase.

Unlike convbin, every signal keeps its own RINEX 3 code (``C2L`` and ``C2S``, ``C1C`` and
``C1B`` ...) instead of being merged into ``X`` codes, every falling edge (or the chosen edge)
becomes an event epoch, frames after damage are recovered, and AID-EPH gives a navigation file.
"""

from __future__ import annotations

import bisect
import datetime as dt
import functools
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation import __version__, gpstime
from groundstation.errors import InputError
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.offline import marks as marks_mod
from groundstation.offline import rinexnav_multi
from groundstation.offline.ephemeris import NavResult, collect_ephemerides
from groundstation.offline.multinav import MultiNav, collect_multi, receiver_times, today_gps_week
from groundstation.records import TimeMark
from groundstation.storage.reading import Recording
from groundstation.ubx.fastraw import (
    FrameIndex,
    RawBlock,
    decode_raw,
    decode_rawx,
    decode_timtm2,
    index_frames,
)
from groundstation.ubx.timemark import timemark_from_fields

log = logging.getLogger("groundstation.rinex")

ProgressFn = Callable[[str, float], None]
"""Progress callback: (stage name, fraction done 0..1)."""

SYSTEMS = "GRECJSI"
"""RINEX system letters, in the order systems are written."""
GNSS_LETTER = {0: "G", 1: "S", 2: "E", 3: "C", 5: "J", 6: "R"}
MAX_PRN = {"G": (1, 32), "S": (120, 158), "E": (1, 36), "C": (1, 63), "J": (1, 10), "R": (1, 27)}

SIGNAL_CODES: dict[tuple[int, int], str] = {
    (0, 0): "1C", (0, 3): "2L", (0, 4): "2S", (0, 6): "5I", (0, 7): "5Q",
    (1, 0): "1C",
    (2, 0): "1C", (2, 1): "1B", (2, 3): "5I", (2, 4): "5Q", (2, 5): "7I", (2, 6): "7Q",
    (3, 0): "2I", (3, 1): "2I", (3, 2): "7I", (3, 3): "7I", (3, 7): "5X",
    (5, 0): "1C", (5, 1): "1Z", (5, 4): "2S", (5, 5): "2L", (5, 8): "5I", (5, 9): "5Q",
    (6, 0): "1C", (6, 2): "2C",
}  # fmt: skip
"""RINEX 3.04 band+attribute for each u-blox (gnssId, sigId) of RXM-RAWX version 1."""
VERSION0_CODES = {0: "1C", 1: "1C", 2: "1X", 3: "2I", 5: "1C", 6: "1C"}
"""RXM-RAWX version 0 (u-blox 8) has no sigId: one L1-band signal per system."""
CODE_ORDER = ("1C", "1B", "1X", "1Z", "2C", "2L", "2S", "2I", "2X", "5I", "5Q", "5X", "7I", "7Q")
CODE_INDEX = {c: i for i, c in enumerate(CODE_ORDER)}
_CODE_NAMES = np.array(CODE_ORDER)
_CODE_TABLE_V1 = np.full((8, 16), -1, dtype=np.int64)
for (_g, _s), _c in SIGNAL_CODES.items():
    _CODE_TABLE_V1[_g, _s] = CODE_INDEX[_c]
_CODE_TABLE_V0 = np.full(8, -1, dtype=np.int64)
for _g, _c in VERSION0_CODES.items():
    _CODE_TABLE_V0[_g] = CODE_INDEX[_c]

CPSTD_VALID_GEN8 = 5
CPSTD_VALID_GEN9 = 14
CPSTD_SLIP = 15
SBAS_HALF_CYCLE_LOCK_MS = 8000

# IS-GPS-200 nominal URA (m) per index, as RINEX writers give it.
URA_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0,
         3072.0, 6144.0, 6144.0)  # fmt: skip

RINEX_VERSIONS = ("2.11", "3.04")


@dataclass(frozen=True, slots=True)
class ObsSet:
    """Observations after the RTKLIB rules, one row per signal measurement, in stream order.

    Attributes:
        t_gps_ns: time of each epoch (GPS ns), one per message kept.
        leap_s: leap seconds each RXM-RAWX message declared valid (-1 where not).
        epoch: epoch row of each measurement.
        sys: RINEX system letter of each measurement (``"G"``, ``"R"`` ...).
        prn: RINEX satellite number (SBAS 120-158).
        code: RINEX 3 band+attribute (``"1C"``, ``"2L"`` ...).
        pr_m, cp_cyc, do_hz, cno_dbhz: values; 0.0 means blank (as in RTKLIB).
        lli: loss-of-lock indicator (bit 0 slip, bit 1 half cycle unresolved).
        glo_fcn: GLONASS frequency channel per slot.
        source: the message type the epochs came from.
    """

    t_gps_ns: npt.NDArray[np.int64]
    leap_s: npt.NDArray[np.int64]
    epoch: npt.NDArray[np.int64]
    sys: npt.NDArray[np.str_]
    prn: npt.NDArray[np.int64]
    code: npt.NDArray[np.str_]
    pr_m: npt.NDArray[np.float64]
    cp_cyc: npt.NDArray[np.float64]
    do_hz: npt.NDArray[np.float64]
    cno_dbhz: npt.NDArray[np.float64]
    lli: npt.NDArray[np.int64]
    glo_fcn: dict[int, int]
    source: str


def _empty_obs(source: str) -> ObsSet:
    z = np.zeros(0, dtype=np.int64)
    f = np.zeros(0, dtype=np.float64)
    s = np.zeros(0, dtype="<U2")
    return ObsSet(z, z, z, s, z, s, f, f, f, f, z, {}, source)


def _slip_since_valid(
    ks: npt.NDArray[np.int64],
    same_prev: npt.NDArray[np.bool_],
    slip: npt.NDArray[np.bool_],
    valid: npt.NDArray[np.bool_],
) -> npt.NDArray[np.bool_]:
    """For rows sorted by signal (time order inside), whether a slip happened since the
    signal's last valid phase, this row included (RTKLIB's carried-forward ``lockflag``)."""
    n = ks.size
    pos = np.arange(n)
    group_start = np.maximum.accumulate(np.where(np.concatenate(([True], ~same_prev)), pos, 0))
    last_valid_incl = np.maximum.accumulate(np.where(valid, pos, -1))
    last_valid_excl = np.concatenate(([-1], last_valid_incl[:-1]))
    base = np.maximum(last_valid_excl, group_start - 1)
    csum = np.cumsum(slip.astype(np.int64))
    csum_at = np.where(base >= 0, csum[np.maximum(base, 0)], 0)
    return np.asarray((csum - csum_at) > 0)


def obs_from_raw(block: RawBlock) -> ObsSet:
    """RXM-RAW (u-blox 4/5/6) messages → observations, as RTKLIB ``decode_rxmraw``."""
    h, m = block.header, block.meas
    keep_epoch = h["week"] != 0
    t = block.gps_week * gpstime.NS_PER_WEEK + block.tow_ns
    sv = m["sv"].astype(np.int64)
    is_sbas = sv >= 120
    ok = keep_epoch[block.epoch] & (((sv >= 1) & (sv <= 32)) | (is_sbas & (sv <= 158)))
    new_row = np.cumsum(keep_epoch) - 1
    m = m[ok]
    sv = sv[ok]
    n = int(ok.sum())
    # A slip flagged while the phase was blank is carried to the next valid phase (RTKLIB).
    raw_lli = m["lli"].astype(np.int64) & 3
    if n:
        order = np.argsort(sv, kind="stable")
        ks = sv[order]
        same_prev = ks[1:] == ks[:-1]
        carried = _slip_since_valid(
            ks, same_prev, (raw_lli[order] & 1) != 0, m["cpMes"][order] != 0.0
        )
        lli_s = raw_lli[order] | np.where(carried & (m["cpMes"][order] != 0.0), 1, 0)
        raw_lli = np.empty(n, dtype=np.int64)
        raw_lli[order] = lli_s
    return ObsSet(
        t_gps_ns=t[keep_epoch],
        leap_s=np.full(int(keep_epoch.sum()), -1, dtype=np.int64),
        epoch=new_row[block.epoch[ok]],
        sys=np.where(sv >= 120, "S", "G"),
        prn=sv,
        code=np.full(n, "1C"),
        pr_m=m["prMes"].astype(np.float64),
        cp_cyc=m["cpMes"].astype(np.float64),
        do_hz=m["doMes"].astype(np.float64),
        cno_dbhz=np.floor(m["cno"].astype(np.float64) + 0.5),
        lli=raw_lli,
        glo_fcn={},
        source="RXM-RAW",
    )


def _group_prev(
    values: npt.NDArray[Any], same_prev: npt.NDArray[np.bool_], default: int
) -> npt.NDArray[Any]:
    prev = np.empty_like(values)
    prev[0:1] = default
    prev[1:] = np.where(same_prev, values[:-1], default)
    return prev


def obs_from_rawx(block: RawBlock) -> ObsSet:
    """RXM-RAWX (u-blox 8/9/10) messages → observations, as RTKLIB ``decode_rxmrawx``."""
    h, m = block.header, block.meas
    if m.size == 0:
        return _empty_obs("RXM-RAWX")
    keep_epoch = h["week"] != 0
    gnss = m["gnssId"].astype(np.int64)
    sv = m["svId"].astype(np.int64)
    sig = m["sigId"].astype(np.int64)
    version = h["version"][block.epoch]
    letters = np.array([GNSS_LETTER.get(g, "") for g in range(8)])
    sysl = letters[np.minimum(gnss, 7)]
    prn = sv
    lo = np.array([MAX_PRN.get(s, (1, 0))[0] for s in letters.tolist()])
    hi = np.array([MAX_PRN.get(s, (1, 0))[1] for s in letters.tolist()])
    g7 = np.minimum(gnss, 7)
    sat_ok = (sysl != "") & (prn >= lo[g7]) & (prn <= hi[g7])
    code_i = np.where(
        version >= 1, _CODE_TABLE_V1[g7, np.minimum(sig, 15)], _CODE_TABLE_V0[g7]
    )
    ok = keep_epoch[block.epoch] & sat_ok & (code_i >= 0)
    idx = np.flatnonzero(ok)
    m = m[idx]
    ep = block.epoch[idx]
    sysl, prn, gnss, sv = sysl[idx], prn[idx], gnss[idx], sv[idx]
    code_i = code_i[idx]
    code = _CODE_NAMES[code_i]
    trk = m["trkStat"].astype(np.int64)
    lockt = m["locktime"].astype(np.int64)
    cpstd = m["cpStdev"].astype(np.int64) & 15
    pr = np.where(trk & 1, m["prMes"], 0.0)
    # Gen9 limit once any earlier message carried a second-band signal (RTKLIB's rcvtype).
    gen9_msg = np.zeros(h.size, dtype=bool)
    np.logical_or.at(gen9_msg, block.epoch, block.meas["sigId"] > 1)
    gen9_msg &= keep_epoch  # RTKLIB returns before looking at a week-0 message
    gen9_before = np.concatenate(([False], np.logical_or.accumulate(gen9_msg)[:-1]))
    cp_limit = np.where(gen9_before[ep], CPSTD_VALID_GEN9, CPSTD_VALID_GEN8)
    cp = m["cpMes"].astype(np.float64)
    cp = np.where(((trk & 2) == 0) | (cp == -0.5) | (cpstd > cp_limit), 0.0, cp)
    bds_geo = (sysl == "C") & ((prn <= 5) | (prn >= 59)) & (cp != 0.0)
    cp = np.where(bds_geo, cp + 0.5, cp)
    halfv = np.where(sysl == "S", lockt > SBAS_HALF_CYCLE_LOCK_MS, (trk & 4) != 0)
    halfc = ((trk & 8) != 0).astype(np.int64)
    # Per-signal state in stream order: sort by signal, keep time order inside each signal.
    key = (gnss * 256 + sv) * 64 + code_i
    order = np.argsort(key, kind="stable")
    ks = key[order]
    same_prev = ks[1:] == ks[:-1]
    lt, hc, cpv = lockt[order], halfc[order], cp[order] != 0.0
    prev_lt = _group_prev(lt, same_prev, 0)
    prev_hc = _group_prev(hc, same_prev, 0)
    slip = (lt == 0) | (lt < prev_lt) | (hc != prev_hc) | (cpstd[order] >= CPSTD_SLIP)
    lockflag = _slip_since_valid(ks, same_prev, slip, cpv)
    n = ks.size
    lli_s = (
        np.where(~halfv[order] & cpv, 2, 0)
        | np.where(hc != prev_hc, 1, 0)
        | np.where(cpv & lockflag, 1, 0)
    )
    lli = np.empty(n, dtype=np.int64)
    lli[order] = lli_s
    new_row = np.cumsum(keep_epoch) - 1
    glo = sysl == "R"
    fcn = {int(p): int(f) - 7 for p, f in zip(prn[glo], m["freqId"][glo], strict=True)}
    leap = np.where(h["recStat"] & 1, h["leapS"].astype(np.int64), -1)
    return ObsSet(
        t_gps_ns=(block.gps_week * gpstime.NS_PER_WEEK + block.tow_ns)[keep_epoch],
        leap_s=leap[keep_epoch],
        epoch=new_row[ep],
        sys=sysl,
        prn=prn,
        code=code,
        pr_m=pr.astype(np.float64),
        cp_cyc=cp,
        do_hz=m["doMes"].astype(np.float64),
        cno_dbhz=m["cno"].astype(np.float64),
        lli=lli,
        glo_fcn=dict(sorted(fcn.items())),
        source="RXM-RAWX",
    )


# -- header information ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class HeaderInfo:
    """What the observation header says besides the observation types."""

    marker: str = "UNKNOWN"
    marker_type: str = "NON_GEODETIC"
    observer: str = ""
    agency: str = ""
    receiver_number: str = ""
    receiver_type: str = "u-blox"
    receiver_version: str = ""
    antenna_number: str = ""
    antenna_type: str = ""
    approx_ecef_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    leap_s: int | None = None
    comments: tuple[str, ...] = ()


def _hl(content: str, label: str) -> str:
    return f"{content:<60.60s}{label:<20s}\n"


def _utc_now() -> str:
    return dt.datetime.now(dt.UTC).strftime("%Y%m%d %H%M%S UTC")


def _epoch_fields(t_gps_ns: int) -> tuple[int, int, int, int, int, float, int]:
    """(y, m, d, h, min, s, 100ns-units) on the GPS time scale, seconds rounded to 100 ns."""
    t100 = (t_gps_ns + 50) // 100
    day_ns = t100 * 100
    d = gpstime.GPS_EPOCH + dt.timedelta(microseconds=day_ns // 1000)
    sec_100ns = (t100 % (60 * 10_000_000))
    return d.year, d.month, d.day, d.hour, d.minute, sec_100ns / 1e7, sec_100ns


def _fmt_sec(sec_100ns: int) -> str:
    return f"{sec_100ns // 10_000_000:02d}.{sec_100ns % 10_000_000:07d}"


def _obs_types(obs: ObsSet) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    pairs = set(zip(obs.sys.tolist(), obs.code.tolist(), strict=True))
    for s in SYSTEMS:
        codes = sorted((c for (ss, c) in pairs if ss == s), key=lambda c: CODE_INDEX[c])
        if codes:
            out[s] = codes
    return out


@dataclass(frozen=True, slots=True)
class ObsWriteResult:
    """What was written to the observation file."""

    epochs: int
    events: int
    dropped_epochs: int
    first_t_gps_ns: int | None
    last_t_gps_ns: int | None
    skipped_systems: tuple[str, ...]


def _kept_epochs(obs: ObsSet) -> npt.NDArray[np.int64]:
    """Epoch rows to write: with at least one satellite, strictly later than the one before."""
    has = np.zeros(obs.t_gps_ns.size, dtype=bool)
    has[obs.epoch] = True
    rows = np.flatnonzero(has)
    keep: list[int] = []
    last: int | None = None
    for r, t in zip(rows.tolist(), obs.t_gps_ns[rows].tolist(), strict=True):
        if last is not None and t <= last:
            continue
        keep.append(r)
        last = t
    return np.asarray(keep, dtype=np.int64)


def write_obs(
    path: Path,
    obs: ObsSet,
    events_t_gps_ns: Sequence[int],
    info: HeaderInfo,
    version: str = "3.04",
    interval_ns: int | None = None,
    progress: ProgressFn | None = None,
) -> ObsWriteResult:
    """Write a RINEX observation file.

    Args:
        path: output file.
        obs: observations (after the RTKLIB rules).
        events_t_gps_ns: event epochs (flag 5) to interleave, GPS ns.
        info: header content.
        version: ``"3.04"`` or ``"2.11"``.
        interval_ns: nominal interval for the INTERVAL line.
        progress: called now and then with the fraction of epochs written.
    """
    if version not in RINEX_VERSIONS:
        raise ValueError(f"RINEX version must be one of {RINEX_VERSIONS}, not {version}")
    v3 = version == "3.04"
    rows = _kept_epochs(obs)
    dropped = int(np.unique(obs.epoch).size - rows.size)
    types3 = _obs_types(obs)
    skipped: tuple[str, ...] = ()
    if v3:
        types_by_sys = {s: [k + c for c in codes for k in "CLDS"] for s, codes in types3.items()}
    else:
        # RINEX 2.11 knows G, R, S, E; one observation per band: C1 L1 D1 S1, C2 ..., C7 ...
        allowed = "GRSE"
        skipped = tuple(s for s in types3 if s not in allowed)
        bands = sorted({c[0] for s, codes in types3.items() if s in allowed for c in codes})
        types2 = [k + b for b in bands for k in "CLDS"]
        types_by_sys = {s: types2 for s in types3 if s in allowed}
    # Measurement → (row, column) in the per-system type table.
    sel = np.isin(obs.sys, list(types_by_sys))
    t_rows = obs.t_gps_ns[rows]
    row_pos = np.full(obs.t_gps_ns.size, -1, dtype=np.int64)
    row_pos[rows] = np.arange(rows.size)
    mpos = row_pos[obs.epoch]
    sel &= mpos >= 0
    idx = np.flatnonzero(sel)
    if not v3:
        # One signal per band and satellite: the first in code order wins.
        band_key = [
            (int(mpos[i]), obs.sys[i], int(obs.prn[i]), obs.code[i][0], CODE_INDEX[obs.code[i]])
            for i in idx.tolist()
        ]
        best: dict[tuple[int, str, int, str], tuple[int, int]] = {}
        for i, (r, s, p, b, ci) in zip(idx.tolist(), band_key, strict=True):
            bk = (r, s, p, b)
            if bk not in best or ci < best[bk][0]:
                best[bk] = (ci, i)
        idx = np.asarray(sorted(i for _, i in best.values()), dtype=np.int64)
    # Order: epoch, system, prn, code.
    rank_table = np.zeros(256, dtype=np.int64)
    rank_table[np.frombuffer(SYSTEMS.encode(), dtype=np.uint8)] = np.arange(len(SYSTEMS))
    sys_rank = rank_table[obs.sys[idx].astype("S1").view(np.uint8)]
    order = np.lexsort((obs.prn[idx], sys_rank, mpos[idx]))
    idx = idx[order]
    matrix = _format_matrix(obs, idx)
    rec_row_arr = mpos[idx]
    rec_sys = obs.sys[idx].tolist()
    rec_prn = obs.prn[idx].tolist()
    rec_row = rec_row_arr.tolist()
    blank = " " * 64
    ev = sorted(events_t_gps_ns)
    ev_i = 0
    n_ev = 0
    lines: list[str] = []
    k = 0
    total = len(rec_row)
    with path.open("w", encoding="ascii", newline="\n") as f:
        f.write(_obs_header(obs, info, types_by_sys, v3, t_rows, interval_ns))
        label_prn = obs.prn[idx] - np.where(obs.sys[idx] == "S", 100, 0)
        fast = (v3 and all(len(t) == 4 for t in types_by_sys.values())
                and bool(((label_prn >= 0) & (label_prn <= 99)).all()))
        if fast:
            # One signal per system (the common single-frequency case): a line per measurement,
            # all built as one byte matrix (label, 64 field characters, newline).
            sat_text = _sat_lines(obs, idx, matrix)
            width = 3 + 64 + 1
            bounds = np.searchsorted(rec_row_arr, np.arange(t_rows.size + 1)).tolist()
            ev_arr = np.asarray(ev, dtype=np.int64)
            ev_bounds = np.searchsorted(ev_arr, t_rows, side="right").tolist()
            prev_ev = 0
            for r, t in enumerate(t_rows.tolist()):
                for e in ev[prev_ev : ev_bounds[r]]:
                    lines.append(_epoch_line(e, 5, 0, True, []))
                n_ev += ev_bounds[r] - prev_ev
                prev_ev = ev_bounds[r]
                k0, k1 = bounds[r], bounds[r + 1]
                if k1 > k0:
                    lines.append(_epoch_line(t, 0, k1 - k0, True, []))
                    lines.append(sat_text[k0 * width : k1 * width])
            ev_i = prev_ev
        else:
            chunks = _matrix_rows(matrix)
            # Column (in units of one signal's four fields) of each measurement in its table.
            band_of = {s: [t[1:] for t in types[::4]] for s, types in types_by_sys.items()}
            rec_code = obs.code[idx].tolist()
            rec_col = [band_of[s].index(c if v3 else c[0])
                       for s, c in zip(rec_sys, rec_code, strict=True)]
        for r, t in enumerate([] if fast else t_rows.tolist()):
            while ev_i < len(ev) and ev[ev_i] <= t:
                lines.append(_epoch_line(ev[ev_i], 5, 0, v3, []))
                ev_i += 1
                n_ev += 1
            sats: list[str] = []
            body: list[str] = []
            while k < total and rec_row[k] == r:
                s_, p_ = rec_sys[k], rec_prn[k]
                label = f"{s_}{(p_ - 100 if s_ == 'S' else p_):02d}"
                parts = [chunks[k]] if rec_col[k] == 0 else [blank] * rec_col[k] + [chunks[k]]
                k += 1
                while k < total and rec_row[k] == r and rec_prn[k] == p_ and rec_sys[k] == s_:
                    parts.extend([blank] * (rec_col[k] - len(parts)))
                    parts.append(chunks[k])
                    k += 1
                sats.append(label)
                if v3:
                    body.append(label + "".join(parts) + "\n")
                else:
                    cells = "".join(parts)
                    body.extend(
                        cells[c0 : c0 + 80].rstrip() + "\n" for c0 in range(0, len(cells), 80)
                    )
            if not sats:
                continue
            lines.append(_epoch_line(t, 0, len(sats), v3, sats))
            lines.extend(body)
            if len(lines) > 50000:
                f.write("".join(lines))
                lines.clear()
                if progress is not None:
                    progress("write", r / max(1, len(t_rows)))
        while ev_i < len(ev):
            lines.append(_epoch_line(ev[ev_i], 5, 0, v3, []))
            ev_i += 1
            n_ev += 1
        f.write("".join(lines))
    return ObsWriteResult(
        epochs=int(t_rows.size),
        events=n_ev,
        dropped_epochs=dropped,
        first_t_gps_ns=int(t_rows[0]) if t_rows.size else None,
        last_t_gps_ns=int(t_rows[-1]) if t_rows.size else None,
        skipped_systems=skipped,
    )


_SPACE, _DOT, _MINUS, _ZERO = 32, 46, 45, 48
_POW10 = [10**k for k in range(13)]


def _f14_3(values: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
    """``%14.3f`` of every value as an (N, 14) byte matrix, vectorised.

    Exactness: the decimal rounding is decided on ``|v| * 1000``, which can be off by about one
    unit in the last place; rows whose fraction lies within 1e-3 of a rounding tie are returned
    in the second array so the caller formats them with Python's exact formatter. Only values
    with ``|v| < 1e9`` are meant to be printed (14 columns).
    """
    a = np.abs(values)
    scaled = a * 1000.0
    fl = np.floor(scaled)
    frac = scaled - fl
    unsure = np.abs(frac - 0.5) < 1e-3
    ints = (fl + (frac > 0.5)).astype(np.int64)
    n = values.size
    out = np.empty((n, 14), dtype=np.uint8)
    # Columns 0-9: the integer part right-aligned (9 digits at most), leading zeros blank.
    # (Division by a scalar, column by column: numpy divides by a constant much faster than
    # by an array of powers of ten.)
    whole = (ints // 1000).astype(np.int32)
    digits = np.empty((n, 10), dtype=np.uint8)
    x = whole
    for c in range(9, -1, -1):
        q = x // 10
        digits[:, c] = _ZERO + (x - q * 10)
        x = q
    n_int = np.ones(n, dtype=np.int64)
    for k in range(1, 10):
        n_int += whole >= _POW10[k]
    col = np.arange(10, dtype=np.int64)
    shown = col[None, :] >= (10 - n_int)[:, None]
    out[:, :10] = np.where(shown, digits, np.uint8(_SPACE))
    out[:, 10] = _DOT
    f = ints % 1000
    out[:, 11] = _ZERO + f // 100
    out[:, 12] = _ZERO + (f // 10) % 10
    out[:, 13] = _ZERO + f % 10
    neg = np.flatnonzero(values < 0)
    out[neg, 9 - n_int[neg]] = _MINUS
    return out, unsure


def _format_matrix(obs: ObsSet, idx: npt.NDArray[np.int64]) -> npt.NDArray[np.uint8]:
    """The C, L, D, S fields (16 characters each: F14.3, LLI, signal strength) of each
    selected measurement, as an (N, 64) byte matrix. Zero or out-of-range values are blank
    (as RTKLIB writes them); the LLI is written even on a blank phase.

    Vectorised; the few values near a decimal rounding tie, and LLIs above 9, go through
    :func:`_format_chunk_exact`, the reference implementation.
    """
    n = int(idx.size)
    if n == 0:
        return np.zeros((0, 64), dtype=np.uint8)
    cols = (obs.pr_m[idx], obs.cp_cyc[idx], obs.do_hz[idx], obs.cno_dbhz[idx].astype(np.float64))
    lli = obs.lli[idx].astype(np.int64)
    ssi = np.clip(obs.cno_dbhz[idx] // 6, 1, 9).astype(np.int64)
    out = np.full((n, 64), _SPACE, dtype=np.uint8)
    exact = lli > 9
    for j, v in enumerate(cols):
        v = np.asarray(v, dtype=np.float64)
        valid = (v != 0) & (v > -1e9) & (v < 1e9)
        digits, unsure = _f14_3(np.where(valid, v, 0.0))
        exact |= unsure & valid
        block = out[:, 16 * j : 16 * j + 16]
        block[valid, :14] = digits[valid]
        if j == 0:
            block[valid, 15] = (_ZERO + ssi[valid]).astype(np.uint8)
        elif j == 1:
            block[valid, 15] = (_ZERO + ssi[valid]).astype(np.uint8)
            has = lli > 0
            block[has, 14] = (_ZERO + np.minimum(lli[has], 9)).astype(np.uint8)
    if exact.any():
        pr, cp, do = (np.asarray(c, dtype=np.float64) for c in cols[:3])
        sn = obs.cno_dbhz[idx]
        for i in np.flatnonzero(exact).tolist():
            text = _format_chunk_exact(
                float(pr[i]), float(cp[i]), float(do[i]), float(sn[i]), int(lli[i]), int(ssi[i])
            )
            out[i] = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
    return out


def _matrix_rows(matrix: npt.NDArray[np.uint8]) -> list[str]:
    """Each row of a byte matrix as a string."""
    w = matrix.shape[1]
    text = matrix.tobytes().decode("ascii")
    return [text[i : i + w] for i in range(0, len(text), w)]


def _sat_lines(obs: ObsSet, idx: npt.NDArray[np.int64], matrix: npt.NDArray[np.uint8]) -> str:
    """RINEX 3 satellite lines (``G05`` + fields + newline) of every measurement, one string."""
    n = int(idx.size)
    lines = np.empty((n, 68), dtype=np.uint8)
    sys_b = obs.sys[idx].astype("S1").view(np.uint8)
    prn = obs.prn[idx] - np.where(sys_b == ord("S"), 100, 0)
    lines[:, 0] = sys_b
    lines[:, 1] = _ZERO + prn // 10
    lines[:, 2] = _ZERO + prn % 10
    lines[:, 3:67] = matrix
    lines[:, 67] = ord("\n")
    return lines.tobytes().decode("ascii")


def _format_chunk_exact(a: float, b: float, c: float, d: float, ll: int, q: int) -> str:
    """One measurement's 64 characters with Python's exact formatting (reference rules)."""
    fmt = "{:14.3f}".format
    b14 = " " * 14
    lc = str(ll) if ll else " "
    fa = fmt(a) + " " + str(q) if a and -1e9 < a < 1e9 else b14 + "  "
    fb = fmt(b) + lc + str(q) if b and -1e9 < b < 1e9 else b14 + lc + " "
    fc = fmt(c) + "  " if c and -1e9 < c < 1e9 else b14 + "  "
    fd = fmt(d) + "  " if d and -1e9 < d < 1e9 else b14 + "  "
    return fa + fb + fc + fd


@functools.lru_cache(maxsize=1024)
def _minute_prefix_v3(minute: int) -> str:
    """``> YYYY MM DD hh mm `` of a minute counted from the GPS epoch (GPS time scale)."""
    d = gpstime.GPS_EPOCH + dt.timedelta(minutes=minute)
    return f"> {d.year:04d} {d.month:02d} {d.day:02d} {d.hour:02d} {d.minute:02d} "


def _epoch_line(t_gps_ns: int, flag: int, n: int, v3: bool, sats: list[str]) -> str:
    if v3:
        minute, s100 = divmod((t_gps_ns + 50) // 100, 60 * 10_000_000)
        return f"{_minute_prefix_v3(minute)}{_fmt_sec(s100)}  {flag:d}{n:3d}\n"
    y, mo, d, h, mi, _s, s100 = _epoch_fields(t_gps_ns)
    head = f" {y % 100:02d} {mo:2d} {d:2d} {h:2d} {mi:2d}{s100 / 1e7:11.7f}  {flag:d}{n:3d}"
    if not sats:
        return head + "\n"
    out = [head + "".join(sats[:12]) + "\n"]
    for i in range(12, len(sats), 12):
        out.append(" " * 32 + "".join(sats[i : i + 12]) + "\n")
    return "".join(out)


def _obs_header(
    obs: ObsSet,
    info: HeaderInfo,
    types_by_sys: dict[str, list[str]],
    v3: bool,
    t_rows: npt.NDArray[np.int64],
    interval_ns: int | None,
) -> str:
    systems = list(types_by_sys)
    sysc = systems[0] if len(systems) == 1 else "M"
    sys_names = {"G": "GPS", "R": "GLONASS", "E": "Galileo", "C": "BeiDou", "J": "QZSS",
                 "S": "SBAS payload", "M": "Mixed"}  # fmt: skip
    h: list[str] = []
    ver = "3.04" if v3 else "2.11"
    h.append(_hl(f"{ver:>9s}{'':11s}{'OBSERVATION DATA':<20s}{sysc}: {sys_names[sysc]}",
                 "RINEX VERSION / TYPE"))
    h.append(_hl(f"{'groundstation ' + __version__:<20.20s}{'':<20s}{_utc_now():<20s}",
                 "PGM / RUN BY / DATE"))
    for c in info.comments:
        h.append(_hl(c, "COMMENT"))
    h.append(_hl(info.marker, "MARKER NAME"))
    if v3:
        h.append(_hl(info.marker_type, "MARKER TYPE"))
    h.append(_hl(f"{info.observer:<20.20s}{info.agency:<40.40s}", "OBSERVER / AGENCY"))
    h.append(_hl(f"{info.receiver_number:<20.20s}{info.receiver_type:<20.20s}"
                 f"{info.receiver_version:<20.20s}", "REC # / TYPE / VERS"))
    h.append(_hl(f"{info.antenna_number:<20.20s}{info.antenna_type:<20.20s}", "ANT # / TYPE"))
    x, y, z = info.approx_ecef_m
    h.append(_hl(f"{x:14.4f}{y:14.4f}{z:14.4f}", "APPROX POSITION XYZ"))
    h.append(_hl(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N"))
    if v3:
        for s, types in types_by_sys.items():
            for i in range(0, len(types), 13):
                chunk = "".join(f" {t}" for t in types[i : i + 13])
                lead = f"{s}  {len(types):3d}" if i == 0 else " " * 6
                h.append(_hl(f"{lead}{chunk}", "SYS / # / OBS TYPES"))
        h.append(_hl("DBHZ", "SIGNAL STRENGTH UNIT"))
    else:
        h.append(_hl(f"{1:6d}{1:6d}", "WAVELENGTH FACT L1/2"))
        types = next(iter(types_by_sys.values()), [])
        for i in range(0, max(len(types), 1), 9):
            chunk = "".join(f"{t:>6s}" for t in types[i : i + 9])
            lead = f"{len(types):6d}" if i == 0 else " " * 6
            h.append(_hl(f"{lead}{chunk}", "# / TYPES OF OBSERV"))
    if interval_ns:
        h.append(_hl(f"{interval_ns / 1e9:10.3f}", "INTERVAL"))
    for label, tt in (("TIME OF FIRST OBS", t_rows[:1]), ("TIME OF LAST OBS", t_rows[-1:])):
        if tt.size:
            y, mo, d, hh, mi, _s, s100 = _epoch_fields(int(tt[0]))
            sec = f"{s100 / 1e7:13.7f}"
            h.append(_hl(f"{y:6d}{mo:6d}{d:6d}{hh:6d}{mi:6d}{sec}{'':5s}GPS", label))
    if v3:
        for s, types in types_by_sys.items():
            for t in types:
                if t[0] == "L":
                    h.append(_hl(f"{s} {t}", "SYS / PHASE SHIFT"))
        if "R" in types_by_sys:
            slots = sorted(obs.glo_fcn.items())
            for i in range(0, max(len(slots), 1), 8):
                chunk = "".join(f" R{p:02d} {f:2d}" for p, f in slots[i : i + 8])
                lead = f"{len(slots):3d}" if i == 0 else "   "
                h.append(_hl(f"{lead}{chunk}", "GLONASS SLOT / FRQ #"))
            h.append(_hl(" C1C    0.000 C1P    0.000 C2C    0.000 C2P    0.000",
                         "GLONASS COD/PHS/BIS"))
    if info.leap_s is not None:
        h.append(_hl(f"{info.leap_s:6d}", "LEAP SECONDS"))
    h.append(_hl("", "END OF HEADER"))
    return "".join(h)


# -- navigation file --------------------------------------------------------------------------


def _d19(v: float) -> str:
    return f"{v:19.12E}"


def write_nav(
    path: Path,
    ephemerides: Sequence[BroadcastEphemeris],
    version: str = "3.04",
    leap_s: int | None = None,
    nav: NavResult | None = None,
    multi: MultiNav | None = None,
) -> int:
    """Write a navigation file (RINEX 3: GPS, GLONASS, Galileo; 2.11: GPS only); returns the
    number of GPS ephemerides written."""
    v3 = version == "3.04"
    h: list[str] = []
    if v3:
        sys_field = rinexnav_multi.header_system(bool(ephemerides), multi)
        h.append(_hl(f"{version:>9s}{'':11s}{'N: GNSS NAV DATA':<20s}{sys_field:<20s}",
                     "RINEX VERSION / TYPE"))
    else:
        h.append(_hl(f"{version:>9s}{'':11s}{'N: GPS NAV DATA':<20s}", "RINEX VERSION / TYPE"))
    h.append(_hl(f"{'groundstation ' + __version__:<20.20s}{'':<20s}{_utc_now():<20s}",
                 "PGM / RUN BY / DATE"))
    iono = nav.iono_utc if nav is not None else None
    if iono is not None:
        if v3:
            h.append(_hl("GPSA" + " " + "".join(f"{a:12.4E}" for a in iono.alpha),
                         "IONOSPHERIC CORR"))
            h.append(_hl("GPSB" + " " + "".join(f"{b:12.4E}" for b in iono.beta),
                         "IONOSPHERIC CORR"))
            h.append(_hl(f"GPUT {iono.a0_s:17.10E}{iono.a1_s_s:16.9E}{iono.tot_s:7d}"
                         f"{iono.wnt:5d}", "TIME SYSTEM CORR"))
        else:
            h.append(_hl("  " + "".join(f"{a:12.4E}" for a in iono.alpha), "ION ALPHA"))
            h.append(_hl("  " + "".join(f"{b:12.4E}" for b in iono.beta), "ION BETA"))
    if leap_s is not None:
        h.append(_hl(f"{leap_s:6d}", "LEAP SECONDS"))
    h.append(_hl("", "END OF HEADER"))
    body: list[str] = []
    for e in sorted(ephemerides, key=lambda e: (e.week * 604800 + e.toc_s, e.sv)):
        toc_ns = round((e.week * 604800 + e.toc_s) * 1e9)
        # toc is in the week of toe give or take a half week
        d = gpstime.gps_as_datetime(toc_ns)
        ura = URA_M[min(max(e.ura_index, 0), 15)]
        tx = e.tow_s if e.tow_s is not None else e.toe_s
        fit_h = 4.0 if e.fit_interval_flag == 0 else 6.0
        if v3:
            body.append(f"G{e.sv:02d} {d.year:04d} {d.month:02d} {d.day:02d} {d.hour:02d} "
                        f"{d.minute:02d} {d.second:02d}"
                        f"{_d19(e.af0_s)}{_d19(e.af1_s_s)}{_d19(e.af2_s_s2)}\n")
            ind = "    "
        else:
            sec = f"{d.second + d.microsecond / 1e6:5.1f}"
            body.append(f"{e.sv:2d} {d.year % 100:02d} {d.month:2d} {d.day:2d} {d.hour:2d} "
                        f"{d.minute:2d}{sec}"
                        f"{_d19(e.af0_s)}{_d19(e.af1_s_s)}{_d19(e.af2_s_s2)}\n")
            ind = "   "
        rows = (
            (e.iode, e.crs_m, e.delta_n_rad_s, e.m0_rad),
            (e.cuc_rad, e.e, e.cus_rad, e.sqrt_a_sqrt_m),
            (e.toe_s, e.cic_rad, e.omega0_rad, e.cis_rad),
            (e.i0_rad, e.crc_m, e.omega_rad, e.omega_dot_rad_s),
            (e.idot_rad_s, e.code_on_l2, e.week, e.l2p_data_flag),
            (ura, e.health, e.tgd_s, e.iodc),
        )
        for r in rows:
            body.append(ind + "".join(_d19(float(v)) for v in r) + "\n")
        body.append(ind + _d19(float(tx)) + _d19(fit_h) + "\n")
    if v3:
        body.extend(rinexnav_multi.records(multi, _d19))
    with path.open("w", encoding="ascii", newline="\n") as f:
        f.write("".join(h))
        f.write("".join(body))
    return len(ephemerides)


# -- the whole conversion ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RinexOptions:
    """Options of :func:`convert` (see ``groundstation rinex --help``)."""

    version: str = "3.04"
    marks: marks_mod.MarkEdge = "falling"
    shutter_delay_ns: int = 0
    marker: str | None = None


@dataclass(frozen=True, slots=True)
class RinexResult:
    """What a conversion produced."""

    obs_path: Path
    nav_path: Path
    marks_path: Path
    source: str
    epochs: int
    events: int
    marks: int
    marks_in_dropout: int
    ephemerides: int
    dropped_epochs: int
    damaged_frames: int
    frames: int
    rejected_messages: int
    nav_parity_errors: int
    skipped_systems: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    other_ephemerides: tuple[tuple[str, int], ...] = ()
    """(system letter, count) of the GLONASS, Galileo ... records in the nav file."""
    obs_written: bool = True
    """False for a recording without raw measurements (navigation file only)."""


def read_recording(path: Path, progress: ProgressFn | None = None) -> bytes:
    """All bytes of a recording (``.ubx``, ``.ubx.gz``, log, MCAP ``/ubx/raw``; a session's
    later parts too)."""
    recording = Recording(path)
    parts: list[bytes] = []
    for chunk, _t in recording.chunks(chunk_bytes=1 << 20):
        parts.append(chunk)
        if progress is not None:
            progress("read", recording.progress)
    return b"".join(parts)


def _time_marks(
    data: bytes, index: FrameIndex, leap_by_offset: list[tuple[int, int]]
) -> list[TimeMark]:
    """TIM-TM2 records, UTC-based edges put on GPS time with the leap seconds the receiver
    declared last before each record (as :class:`~groundstation.ubx.decode.Decoder` does)."""
    sel, rows = decode_timtm2(data, index)
    offsets = [o for o, _ in leap_by_offset]
    out: list[TimeMark] = []
    for i, r in zip(sel.tolist(), rows.tolist(), strict=True):
        ch, flags, count, wn_r, wn_f, ms_r, sub_r, ms_f, sub_f, acc = r
        j = bisect.bisect_right(offsets, int(index.start[i])) - 1
        leap = leap_by_offset[j][1] if j >= 0 else None
        out.append(timemark_from_fields(
            ch, flags, count, wn_r, ms_r, sub_r, wn_f, ms_f, sub_f, acc, leap_s=leap, t_host_ns=0
        ))
    return out


def _approx_position(data: bytes, index: FrameIndex) -> tuple[float, float, float] | None:
    """The receiver's first good 3D fix (NAV-SOL or NAV-PVT), ECEF metres."""
    import struct

    from groundstation.geodesy import llh_to_ecef

    mv = memoryview(data)
    for key in ((0x01, 0x06), (0x01, 0x07)):
        for i in index.select(key).tolist():
            s = int(index.start[i]) + 6
            p = bytes(mv[s : s + int(index.length[i])])
            if key == (0x01, 0x06) and len(p) >= 52:
                fix, flags = p[10], p[11]
                x, y, z = struct.unpack_from("<iii", p, 12)
                if fix >= 3 and flags & 1 and (x or y or z):
                    return x / 100.0, y / 100.0, z / 100.0
            elif key == (0x01, 0x07) and len(p) >= 92:
                fix, flags = p[20], p[21]
                lon, lat, h_mm = struct.unpack_from("<iii", p, 24)
                if fix >= 3 and flags & 1:
                    return llh_to_ecef(lat * 1e-7, lon * 1e-7, h_mm / 1000.0)
    return None


def _receiver(data: bytes, index: FrameIndex, source: str) -> tuple[str, str]:
    """Receiver type and version from MON-VER if recorded, else from the message set."""
    sel = index.select((0x0A, 0x04))
    if sel.size:
        s = int(index.start[sel[0]]) + 6
        p = data[s : s + int(index.length[sel[0]])]
        sw = p[:30].split(b"\0")[0].decode("ascii", "replace").strip()
        hw = p[30:40].split(b"\0")[0].decode("ascii", "replace").strip()
        model = ""
        for k in range(40, len(p), 30):
            ext = p[k : k + 30].split(b"\0")[0].decode("ascii", "replace")
            if ext.startswith("MOD="):
                model = ext[4:]
        return f"u-blox {model or hw}".strip(), sw
    family = {"RXM-RAWX": "u-blox M8/F9 (RAWX)", "RXM-RAW": "u-blox 4/5/6 (RAW)"}
    return family.get(source, "u-blox"), ""


def convert(
    input_path: str | Path,
    out_dir: str | Path,
    options: RinexOptions | None = None,
    progress: ProgressFn | None = None,
) -> RinexResult:
    """Convert one recording to ``<stem>.obs``, ``<stem>.nav`` and ``<stem>.marks.csv``.

    A recording with navigation data but no raw measurements gives the ``.nav`` file alone
    (``RinexResult.obs_written`` is false).

    Args:
        input_path: ``.ubx``, ``.ubx.gz``, raw log or MCAP.
        out_dir: output directory (created if missing).
        options: version, mark edge, shutter delay, marker name.
        progress: optional progress callback.

    Raises:
        InputError: unreadable input, or neither raw measurements nor navigation data in it.
    """
    opt = options or RinexOptions()
    src = Path(input_path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = src.name
    for suffix in (".gz", ".ubx", ".mcap", ".log"):
        if stem.endswith(suffix):
            stem = stem[: -len(suffix)]
    data = read_recording(src, progress)
    index = index_frames(data)
    if progress is not None:
        progress("index", 1.0)
    rawx = decode_rawx(data, index)
    raw = decode_raw(data, index)
    if rawx.frame.size >= raw.frame.size:
        block, obs = rawx, obs_from_rawx(rawx)
    else:
        block, obs = raw, obs_from_raw(raw)
    if obs.t_gps_ns.size == 0:
        return _convert_nav_only(src, data, index, out, stem, opt)
    rejected = int(rawx.rejected.size + raw.rejected.size)
    # Leap seconds the receiver declared, by stream position (for UTC-based time marks).
    leap_by_offset: list[tuple[int, int]] = []
    if block.source == "RXM-RAWX":
        valid = (block.header["recStat"] & 1) != 0
        leap_by_offset = list(
            zip(
                index.start[block.frame[valid]].tolist(),
                block.header["leapS"][valid].astype(np.int64).tolist(),
                strict=True,
            )
        )
    leap = leap_by_offset[-1][1] if leap_by_offset else gpstime.leap_seconds_at_gps(
        int(obs.t_gps_ns[0]))
    tms = _time_marks(data, index, leap_by_offset)
    mark_list = marks_mod.build_marks(tms)
    events = marks_mod.event_times_ns(mark_list, opt.marks, opt.shutter_delay_ns)
    rec_type, rec_vers = _receiver(data, index, obs.source)
    approx = _approx_position(data, index) or (0.0, 0.0, 0.0)
    week_hint = int(obs.t_gps_ns[0] // gpstime.NS_PER_WEEK)
    nav = collect_ephemerides(data, index, week_hint)
    multi = collect_multi(data, index, receiver_times(data, index), int(obs.t_gps_ns[0]))
    epochs_sorted = np.sort(obs.t_gps_ns).tolist()
    interval = marks_mod.nominal_interval_ns(epochs_sorted)
    comments = (
        f"converted from {src.name}",
        f"observations: {obs.source}; LLI bit 0 slip, bit 1 half cycle unresolved",
        f"events (flag 5): {opt.marks} edge + shutter delay {opt.shutter_delay_ns / 1e6:g} ms",
    )
    info = HeaderInfo(
        marker=opt.marker or stem,
        receiver_type=rec_type,
        receiver_version=rec_vers,
        approx_ecef_m=approx,
        leap_s=leap,
        comments=comments,
    )
    obs_path = out / f"{stem}.obs"
    nav_path = out / f"{stem}.nav"
    marks_path = out / f"{stem}.marks.csv"
    wr = write_obs(obs_path, obs, events, info, opt.version, interval, progress)
    n_eph = write_nav(nav_path, nav.ephemerides, opt.version, leap, nav, multi)
    written = np.sort(obs.t_gps_ns[_kept_epochs(obs)]).tolist()
    marks_path.write_text(
        marks_mod.marks_csv(mark_list, written, opt.marks, opt.shutter_delay_ns), encoding="ascii"
    )
    in_gap = 0
    for m in mark_list:
        t = marks_mod.mark_time_ns(m, opt.marks, opt.shutter_delay_ns)
        if t is not None and marks_mod.locate(t, written, interval).in_dropout:
            in_gap += 1
    notes: list[str] = []
    if block.source == "RXM-RAWX" and block.meas.size:
        pairs = block.meas["gnssId"].astype(np.int64) * 256 + block.meas["sigId"]
        v1 = block.header["version"][block.epoch] >= 1
        uniq, counts = np.unique(pairs[v1], return_counts=True)
        unknown = [
            f"gnssId {g // 256} sigId {g % 256} ({n})"
            for g, n in zip(uniq.tolist(), counts.tolist(), strict=True)
            if (g // 256, g % 256) not in SIGNAL_CODES
        ]
        if unknown:
            notes.append("signals without a RINEX 3.04 code here, left out: " + ", ".join(unknown))
    if math.isfinite(approx[0]) and approx == (0.0, 0.0, 0.0):
        notes.append("no NAV-SOL/NAV-PVT fix: APPROX POSITION XYZ is zero")
    if not nav.ephemerides:
        notes.append("no GPS ephemeris found (RXM-SFRB, RXM-SFRBX, AID-EPH): empty nav file")
    if opt.version != "3.04" and _other_counts(multi):
        notes.append("RINEX 2.11 navigation file holds GPS only: GLONASS/Galileo left out")
    return RinexResult(
        obs_path=obs_path,
        nav_path=nav_path,
        marks_path=marks_path,
        source=obs.source,
        epochs=wr.epochs,
        events=wr.events,
        marks=len(mark_list),
        marks_in_dropout=in_gap,
        ephemerides=n_eph,
        dropped_epochs=wr.dropped_epochs,
        damaged_frames=index.damaged,
        frames=len(index),
        rejected_messages=rejected,
        nav_parity_errors=nav.parity_errors,
        skipped_systems=wr.skipped_systems,
        notes=tuple(notes),
        other_ephemerides=_other_counts(multi),
    )


def _other_counts(multi: MultiNav) -> tuple[tuple[str, int], ...]:
    counts = {"R": len(multi.glonass)}
    for e in multi.kepler:
        counts[e.system] = counts.get(e.system, 0) + 1
    return tuple((s, n) for s, n in counts.items() if n)


def _convert_nav_only(
    src: Path, data: bytes, index: FrameIndex, out: Path, stem: str, opt: RinexOptions
) -> RinexResult:
    """A recording without raw measurements: the navigation file alone (no obs, no marks).

    Raises:
        InputError: no navigation data either.
    """
    times = receiver_times(data, index)
    week_hint = (times[0][1] // gpstime.NS_PER_WEEK) if times else today_gps_week()
    nav = collect_ephemerides(data, index, week_hint)
    # GLONASS needs the day: a receiver time if any, else the first GPS ephemeris's.
    first = nav.ephemerides[0] if nav.ephemerides else None
    approx = (round((first.week * 604_800 + (first.tow_s or first.toe_s)) * 1e9)
              if first is not None else None)
    multi = collect_multi(data, index, times, approx)
    others = _other_counts(multi)
    if not nav.ephemerides and not others:
        raise InputError(
            f"{src}: no raw measurements (RXM-RAW / RXM-RAWX) and no navigation data"
        )
    nav_path = out / f"{stem}.nav"
    known = times[0][1] if times else approx
    leap = gpstime.leap_seconds_at_gps(known) if known is not None else None
    n_eph = write_nav(nav_path, nav.ephemerides, opt.version, leap, nav, multi)
    return RinexResult(
        obs_path=out / f"{stem}.obs",
        nav_path=nav_path,
        marks_path=out / f"{stem}.marks.csv",
        source="none",
        epochs=0,
        events=0,
        marks=0,
        marks_in_dropout=0,
        ephemerides=n_eph,
        dropped_epochs=0,
        damaged_frames=index.damaged,
        frames=len(index),
        rejected_messages=0,
        nav_parity_errors=nav.parity_errors,
        notes=("no raw measurements (RXM-RAW / RXM-RAWX): navigation file only",),
        other_ephemerides=others,
        obs_written=False,
    )


# -- reading back (tests, comparisons with other converters) -----------------------------------


@dataclass(frozen=True, slots=True)
class ObsEpoch:
    """One epoch record of a RINEX 3 observation file, as text-exact values."""

    time: str
    flag: int
    sats: dict[str, dict[str, tuple[str, str]]]


def read_obs3(path: str | Path) -> tuple[dict[str, list[str]], list[ObsEpoch]]:
    """Parse a RINEX 3 observation file (``.gz`` too): obs types per system, and epochs.

    Values are kept as the 14-character text and the LLI character, so comparisons are exact.
    """
    import gzip

    p = Path(path)
    opener = gzip.open if p.suffix == ".gz" else open
    types: dict[str, list[str]] = {}
    epochs: list[ObsEpoch] = []
    with opener(p, "rt", encoding="ascii") as f:
        last_sys = ""
        for line in f:
            label = line[60:].strip()
            if label == "SYS / # / OBS TYPES":
                if line[0] != " ":
                    last_sys = line[0]
                    types[last_sys] = []
                types[last_sys].extend(line[7:60].split())
            elif label == "END OF HEADER":
                break
        cur: ObsEpoch | None = None
        for line in f:
            if line.startswith(">"):
                y, mo, d, hh, mi, sec = line[2:29].split()
                whole, frac = sec.split(".")
                t = f"{int(y):04d} {int(mo):02d} {int(d):02d} {int(hh):02d} {int(mi):02d} "
                cur = ObsEpoch(t + f"{int(whole):02d}.{frac}", int(line[31]), {})
                epochs.append(cur)
                continue
            if cur is None or len(line) < 3:
                continue
            sat = line[:3]
            tl = types.get(sat[0], [])
            rec: dict[str, tuple[str, str]] = {}
            body = line[3:].rstrip("\n")
            for j, t in enumerate(tl):
                fld = body[16 * j : 16 * j + 16].ljust(16)
                rec[t] = (fld[:14].strip(), fld[14].strip())
            cur.sats[sat] = rec
    return types, epochs
