"""The RINEX 2.11 / 3.04 observation file: header, epochs, event epochs (flag 5)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from groundstation import __version__
from groundstation.offline.rinex.format import (
    epoch_fields,
    epoch_line,
    epoch_line_matrix_v3,
    format_matrix,
    hl,
    letter_bytes,
    matrix_rows,
    sat_line_matrix,
    utc_now,
    wrap_comment,
)
from groundstation.offline.rinex.observations import CODE_INDEX, SYSTEMS, ObsSet

ProgressFn = Callable[[str, float], None]
"""Progress callback: (stage name, fraction done 0..1)."""

RINEX_VERSIONS = ("2.11", "3.04")
FORMAT_BLOCK = 1 << 16
"""Measurements formatted at a time (the fixed-width formatter's arrays stay in the cache)."""


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


def _obs_types(obs: ObsSet) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    pairs = _system_code_pairs(obs)
    for s in SYSTEMS:
        codes = sorted((c for (ss, c) in pairs if ss == s), key=lambda c: CODE_INDEX[c])
        if codes:
            out[s] = codes
    return out


def _system_code_pairs(obs: ObsSet) -> set[tuple[str, str]]:
    """The distinct (system, code) pairs of the measurements.

    One-letter systems and two-letter ASCII codes (all of them today) are counted from their
    code points (``bincount`` of a 21-bit key) instead of two Python lists of millions of
    strings; anything else takes the plain way.
    """
    sys_a, code_a = obs.sys, obs.code
    if sys_a.size and sys_a.dtype.itemsize == 4 and code_a.dtype.itemsize == 8:
        s = np.ascontiguousarray(sys_a).view(np.uint32).astype(np.int64)
        c = np.ascontiguousarray(code_a).view(np.uint32).reshape(-1, 2).astype(np.int64)
        if int(s.max()) < 128 and int(c.max()) < 128:
            keys = np.flatnonzero(np.bincount((s << 14) | (c[:, 0] << 7) | c[:, 1])).tolist()
            return {(chr(k >> 14).rstrip("\0"), (chr(k >> 7 & 127) + chr(k & 127)).rstrip("\0"))
                    for k in keys}
    return set(zip(sys_a.tolist(), code_a.tolist(), strict=True))


@dataclass(frozen=True, slots=True)
class ObsWriteResult:
    """What was written to the observation file."""

    epochs: int
    events: int
    dropped_epochs: int
    first_t_gps_ns: int | None
    last_t_gps_ns: int | None
    skipped_systems: tuple[str, ...]


def kept_epochs(obs: ObsSet) -> npt.NDArray[np.int64]:
    """Epoch rows to write: with at least one satellite, strictly later than the one before."""
    has = np.zeros(obs.t_gps_ns.size, dtype=bool)
    has[obs.epoch] = True
    rows = np.flatnonzero(has).astype(np.int64)
    t = obs.t_gps_ns[rows]
    # The last kept time is the largest time so far (a row is kept exactly when it is later
    # than every row before it), so the rule is a running maximum.
    keep = np.ones(rows.size, dtype=bool)
    if rows.size > 1:
        keep[1:] = t[1:] > np.maximum.accumulate(t)[:-1]
    return rows[keep]


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
    rows = kept_epochs(obs)
    # epochs with measurements, counted without np.unique (whose plain form imports numpy.ma,
    # ~10 ms of start-up)
    dropped = int(np.count_nonzero(np.bincount(obs.epoch.astype(np.int64))) - rows.size)
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
    sys_rank = rank_table[letter_bytes(obs.sys[idx])]
    order = np.lexsort((obs.prn[idx], sys_rank, mpos[idx]))
    idx = idx[order]
    rec_row_arr = mpos[idx]
    blank = " " * 64
    ev = sorted(int(e) for e in events_t_gps_ns)
    ev_i = 0
    n_ev = 0
    lines: list[str] = []
    k = 0
    with path.open("w", encoding="ascii", newline="\n") as f:
        f.write(_obs_header(obs, info, types_by_sys, v3, t_rows, interval_ns))
        label_prn = obs.prn[idx] - np.where(obs.sys[idx] == "S", 100, 0)
        fast = (v3 and all(len(t) == 4 for t in types_by_sys.values())
                and bool(((label_prn >= 0) & (label_prn <= 99)).all()))
        counts = np.diff(np.searchsorted(rec_row_arr, np.arange(t_rows.size + 1)))
        # (an epoch of 1 000 satellites or more would take more columns for its count)
        fast = fast and bool((counts <= 999).all())
        if fast:
            f.flush()  # the text before, then the epochs as bytes on the same buffer
            ev_i = n_ev = _write_v3_single(f.buffer.write, obs, idx, counts, t_rows, ev)
        else:
            chunks = matrix_rows(format_matrix(obs, idx))
            rec_sys = obs.sys[idx].tolist()
            rec_prn = obs.prn[idx].tolist()
            rec_row = rec_row_arr.tolist()
            total = len(rec_row)
            # Column (in units of one signal's four fields) of each measurement in its table.
            band_of = {s: [t[1:] for t in types[::4]] for s, types in types_by_sys.items()}
            rec_code = obs.code[idx].tolist()
            rec_col = [band_of[s].index(c if v3 else c[0])
                       for s, c in zip(rec_sys, rec_code, strict=True)]
        for r, t in enumerate([] if fast else t_rows.tolist()):
            while ev_i < len(ev) and ev[ev_i] <= t:
                lines.append(epoch_line(ev[ev_i], 5, 0, v3, []))
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
            lines.append(epoch_line(t, 0, len(sats), v3, sats))
            lines.extend(body)
            if len(lines) > 50000:
                f.write("".join(lines))
                lines.clear()
                if progress is not None:
                    progress("write", r / max(1, len(t_rows)))
        while ev_i < len(ev):
            lines.append(epoch_line(ev[ev_i], 5, 0, v3, []))
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


def _write_v3_single(
    write: Callable[[bytes], object],
    obs: ObsSet,
    idx: npt.NDArray[np.int64],
    counts: npt.NDArray[np.int64],
    t_rows: npt.NDArray[np.int64],
    ev: list[int],
) -> int:
    """The epochs of a RINEX 3 file with one signal per system (a line per measurement), as
    bytes assembled with numpy; returns how many of the sorted events ``ev`` were written
    (those up to the last epoch; the caller writes the rest).

    Epoch and event lines (36 bytes) and satellite lines (68 bytes) are all whole 4-byte
    words, so a block's text is assembled as words: the epoch and event lines at their places,
    the satellite lines (in measurement order) in all the others.
    """
    bounds = np.concatenate(([0], np.cumsum(counts)))
    ev_arr = np.asarray(ev, dtype=np.int64)
    ev_bounds = np.searchsorted(ev_arr, t_rows, side="right")  # events at or before each row
    ev_row = np.searchsorted(ev_bounds, np.arange(ev_arr.size), side="right")  # row it precedes
    # blocks of rows of about FORMAT_BLOCK measurements
    cuts = np.searchsorted(bounds, np.arange(0, int(bounds[-1]), FORMAT_BLOCK), side="right") - 1
    edges = sorted({0, int(t_rows.size), *cuts.tolist()})
    for a, b in zip(edges, edges[1:], strict=False):
        k0, k1 = int(bounds[a]), int(bounds[b])
        rows = a + np.flatnonzero(counts[a:b])
        j0, j1 = np.searchsorted(ev_row, [a, b], side="left").tolist()
        if rows.size == 0 and j1 == j0:
            continue
        # an event goes before the epoch it precedes: keys 2r (event) and 2r + 1 (epoch r)
        order = np.argsort(np.concatenate((2 * ev_row[j0:j1], 2 * rows + 1)), kind="stable")
        n_ev = j1 - j0
        t_items = np.concatenate((ev_arr[j0:j1], t_rows[rows]))[order]
        n_items = np.concatenate((np.zeros(n_ev, dtype=np.int64), counts[rows]))[order]
        flags = np.concatenate((np.full(n_ev, 5, dtype=np.int64),
                                np.zeros(rows.size, dtype=np.int64)))[order]
        head = epoch_line_matrix_v3(t_items, n_items, flags).view("<u4")
        sats = sat_line_matrix(obs, idx[k0:k1], format_matrix(obs, idx[k0:k1])).view("<u4")
        hw, sw = head.shape[1], sats.shape[1]
        size = hw + n_items * sw
        start = np.cumsum(size) - size
        words = np.empty(int(size.sum()), dtype="<u4")
        is_head = np.zeros(words.size, dtype=bool)
        pos = (start[:, None] + np.arange(hw)).reshape(-1)
        is_head[pos] = True
        words[pos] = head.reshape(-1)
        words[~is_head] = sats.reshape(-1)
        write(words.tobytes())
    return int(ev_bounds[-1]) if t_rows.size else 0


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
    h.append(hl(f"{ver:>9s}{'':11s}{'OBSERVATION DATA':<20s}{sysc}: {sys_names[sysc]}",
                 "RINEX VERSION / TYPE"))
    h.append(hl(f"{'groundstation ' + __version__:<20.20s}{'':<20s}{utc_now():<20s}",
                 "PGM / RUN BY / DATE"))
    for c in info.comments:  # a long comment goes on over several COMMENT lines
        for part in wrap_comment(c):
            h.append(hl(part, "COMMENT"))
    h.append(hl(info.marker, "MARKER NAME"))
    if v3:
        h.append(hl(info.marker_type, "MARKER TYPE"))
    h.append(hl(f"{info.observer:<20.20s}{info.agency:<40.40s}", "OBSERVER / AGENCY"))
    h.append(hl(f"{info.receiver_number:<20.20s}{info.receiver_type:<20.20s}"
                 f"{info.receiver_version:<20.20s}", "REC # / TYPE / VERS"))
    h.append(hl(f"{info.antenna_number:<20.20s}{info.antenna_type:<20.20s}", "ANT # / TYPE"))
    x, y, z = info.approx_ecef_m
    h.append(hl(f"{x:14.4f}{y:14.4f}{z:14.4f}", "APPROX POSITION XYZ"))
    h.append(hl(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N"))
    if v3:
        for s, types in types_by_sys.items():
            for i in range(0, len(types), 13):
                chunk = "".join(f" {t}" for t in types[i : i + 13])
                lead = f"{s}  {len(types):3d}" if i == 0 else " " * 6
                h.append(hl(f"{lead}{chunk}", "SYS / # / OBS TYPES"))
        h.append(hl("DBHZ", "SIGNAL STRENGTH UNIT"))
    else:
        h.append(hl(f"{1:6d}{1:6d}", "WAVELENGTH FACT L1/2"))
        types = next(iter(types_by_sys.values()), [])
        for i in range(0, max(len(types), 1), 9):
            chunk = "".join(f"{t:>6s}" for t in types[i : i + 9])
            lead = f"{len(types):6d}" if i == 0 else " " * 6
            h.append(hl(f"{lead}{chunk}", "# / TYPES OF OBSERV"))
    if interval_ns:
        h.append(hl(f"{interval_ns / 1e9:10.3f}", "INTERVAL"))
    for label, tt in (("TIME OF FIRST OBS", t_rows[:1]), ("TIME OF LAST OBS", t_rows[-1:])):
        if tt.size:
            y, mo, d, hh, mi, _s, s100 = epoch_fields(int(tt[0]))
            sec = f"{s100 / 1e7:13.7f}"
            h.append(hl(f"{y:6d}{mo:6d}{d:6d}{hh:6d}{mi:6d}{sec}{'':5s}GPS", label))
    if v3:
        for s, types in types_by_sys.items():
            for t in types:
                if t[0] == "L":
                    h.append(hl(f"{s} {t}", "SYS / PHASE SHIFT"))
        if "R" in types_by_sys:
            slots = sorted(obs.glo_fcn.items())
            for i in range(0, max(len(slots), 1), 8):
                chunk = "".join(f" R{p:02d} {f:2d}" for p, f in slots[i : i + 8])
                lead = f"{len(slots):3d}" if i == 0 else "   "
                h.append(hl(f"{lead}{chunk}", "GLONASS SLOT / FRQ #"))
            h.append(hl(" C1C    0.000 C1P    0.000 C2C    0.000 C2P    0.000",
                         "GLONASS COD/PHS/BIS"))
    if info.leap_s is not None:
        h.append(hl(f"{info.leap_s:6d}", "LEAP SECONDS"))
    h.append(hl("", "END OF HEADER"))
    return "".join(h)
