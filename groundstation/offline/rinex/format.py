"""RINEX text: header and epoch lines, the F14.3 + LLI + strength fields (vectorised, exact)."""

from __future__ import annotations

import datetime as dt
import functools
import textwrap
import unicodedata

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.offline.rinex.observations import ObsSet


def ascii_text(text: str) -> str:
    """Text as a RINEX header may hold it (ASCII, RINEX 2.11 and 3.04 section 5): accents
    taken off (``Görlitz`` -> ``Gorlitz``), anything else not ASCII or not printable (a tab, a
    CJK name) as ``?``."""
    folded = unicodedata.normalize("NFKD", text)
    folded = "".join(c for c in folded if not unicodedata.combining(c))
    return "".join(c if " " <= c <= "~" else "?" for c in folded)


def hl(content: str, label: str) -> str:
    return f"{ascii_text(content):<60.60s}{label:<20s}\n"


def wrap_comment(text: str) -> list[str]:
    """A COMMENT's text as lines of at most 60 characters (a header line's content field):
    unchanged when it fits, else wrapped at spaces (``hl`` cut it off mid-word)."""
    if len(text) <= 60:
        return [text]
    return textwrap.wrap(text, 60, break_on_hyphens=False) or [text[:60]]


def utc_now() -> str:
    return dt.datetime.now(dt.UTC).strftime("%Y%m%d %H%M%S UTC")


def epoch_fields(t_gps_ns: int) -> tuple[int, int, int, int, int, float, int]:
    """(y, m, d, h, min, s, 100ns-units) on the GPS time scale, seconds rounded to 100 ns."""
    t100 = (t_gps_ns + 50) // 100
    day_ns = t100 * 100
    d = gpstime.GPS_EPOCH + dt.timedelta(microseconds=day_ns // 1000)
    sec_100ns = (t100 % (60 * 10_000_000))
    return d.year, d.month, d.day, d.hour, d.minute, sec_100ns / 1e7, sec_100ns


def fmt_sec(sec_100ns: int) -> str:
    return f"{sec_100ns // 10_000_000:02d}.{sec_100ns % 10_000_000:07d}"


_SPACE, _DOT, _MINUS, _ZERO = 32, 46, 45, 48
_POW10 = [10**k for k in range(13)]


def f14_3(values: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
    """``%14.3f`` of every value as an (N, 14) byte matrix, vectorised.

    Exactness: the decimal rounding is decided on ``|v| * 1000`` as computed, which is off the
    exact product by at most half a unit in its last place (``|v| * 1000 * 2**-53``); the
    floor and the fraction are exact. So the decision can be wrong only for a fraction within
    that distance of one half: those rows (with a margin of 3.6x) are returned in the second
    array so the caller formats them with Python's exact formatter. Only values with
    ``|v| < 1e9`` are meant to be printed (14 columns).
    """
    a = np.abs(values)
    scaled = a * 1000.0
    fl = np.floor(scaled)
    frac = scaled - fl
    unsure = np.abs(frac - 0.5) <= np.maximum(scaled, 1.0) * 4e-16
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


def format_matrix(obs: ObsSet, idx: npt.NDArray[np.int64]) -> npt.NDArray[np.uint8]:
    """The C, L, D, S fields (16 characters each: F14.3, LLI, signal strength) of each
    selected measurement, as an (N, 64) byte matrix. Zero or out-of-range values are blank
    (as RTKLIB writes them); the LLI is written even on a blank phase.

    Vectorised; the few values near a decimal rounding tie, and LLIs above 9, go through
    :func:`format_chunk_exact`, the reference implementation.
    """
    n = int(idx.size)
    if n == 0:
        return np.zeros((0, 64), dtype=np.uint8)
    cols = (obs.pr_m[idx], obs.cp_cyc[idx], obs.do_hz[idx], obs.cno_dbhz[idx].astype(np.float64))
    lli = obs.lli[idx].astype(np.int64)
    ssi = np.clip(obs.cno_dbhz[idx] // 6, 1, 9).astype(np.int64)
    out = np.full((n, 64), _SPACE, dtype=np.uint8)
    exact = lli > 9
    ssi_char = (_ZERO + ssi).astype(np.uint8)
    # (copyto with a mask: no index arrays gathered and scattered per field)
    for j, v in enumerate(cols):
        v = np.asarray(v, dtype=np.float64)
        valid = (v != 0) & (v > -1e9) & (v < 1e9)
        digits, unsure = f14_3(np.where(valid, v, 0.0))
        exact |= unsure & valid
        block = out[:, 16 * j : 16 * j + 16]
        np.copyto(block[:, :14], digits, where=valid[:, None])
        if j in (0, 1):
            np.copyto(block[:, 15], ssi_char, where=valid)
        if j == 1:
            lli_char = (_ZERO + np.minimum(lli, 9)).astype(np.uint8)
            np.copyto(block[:, 14], lli_char, where=lli > 0)
    if exact.any():
        pr, cp, do = (np.asarray(c, dtype=np.float64) for c in cols[:3])
        sn = obs.cno_dbhz[idx]
        for i in np.flatnonzero(exact).tolist():
            text = format_chunk_exact(
                float(pr[i]), float(cp[i]), float(do[i]), float(sn[i]), int(lli[i]), int(ssi[i])
            )
            out[i] = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
    return out


def matrix_rows(matrix: npt.NDArray[np.uint8]) -> list[str]:
    """Each row of a byte matrix as a string."""
    w = matrix.shape[1]
    text = matrix.tobytes().decode("ascii")
    return [text[i : i + w] for i in range(0, len(text), w)]


def letter_bytes(a: npt.NDArray[np.str_]) -> npt.NDArray[np.uint8]:
    """The (ASCII) letter of each one-letter string as a byte, 0 for an empty string.

    A view of the code points: ``astype("S1")`` encodes every string and took 0.4 s of a
    10-hour flight's export.
    """
    if a.dtype.itemsize == 4:
        return np.ascontiguousarray(a).view(np.uint32).astype(np.uint8)
    return a.astype("S1").view(np.uint8)


def sat_lines(obs: ObsSet, idx: npt.NDArray[np.int64], matrix: npt.NDArray[np.uint8]) -> str:
    """RINEX 3 satellite lines (``G05`` + fields + newline) of every measurement, one string."""
    return sat_line_matrix(obs, idx, matrix).tobytes().decode("ascii")


SAT_LINE_WIDTH = 68
EPOCH_LINE_WIDTH_V3 = 36


def sat_line_matrix(
    obs: ObsSet, idx: npt.NDArray[np.int64], matrix: npt.NDArray[np.uint8]
) -> npt.NDArray[np.uint8]:
    """:func:`sat_lines` as an (N, 68) byte matrix."""
    n = int(idx.size)
    lines = np.empty((n, 68), dtype=np.uint8)
    sys_b = letter_bytes(obs.sys[idx])
    prn = obs.prn[idx] - np.where(sys_b == ord("S"), 100, 0)
    lines[:, 0] = sys_b
    lines[:, 1] = _ZERO + prn // 10
    lines[:, 2] = _ZERO + prn % 10
    lines[:, 3:67] = matrix
    lines[:, 67] = ord("\n")
    return lines


def epoch_line_matrix_v3(
    t_gps_ns: npt.NDArray[np.int64], n: npt.NDArray[np.int64], flag: npt.NDArray[np.int64]
) -> npt.NDArray[np.uint8]:
    """``epoch_line(t, flag, n, True, [])`` of every row as an (N, 36) byte matrix (``n`` at
    most 999, ``flag`` one digit)."""
    t100 = (t_gps_ns + 50) // 100
    minute = t100 // 600_000_000
    s100 = t100 % 600_000_000
    uniq, inv = np.unique(minute, return_inverse=True)
    prefixes = np.frombuffer(
        "".join(minute_prefix_v3(m) for m in uniq.tolist()).encode("ascii"), dtype=np.uint8
    ).reshape(-1, 19)
    out = np.empty((t_gps_ns.size, EPOCH_LINE_WIDTH_V3), dtype=np.uint8)
    out[:, :19] = prefixes[inv.reshape(-1)]
    x = s100
    for c in (28, 27, 26, 25, 24, 23, 22, 20, 19):  # SS.fffffff, last digit first
        q = x // 10
        out[:, c] = _ZERO + (x - q * 10)
        x = q
    out[:, 21] = _DOT
    out[:, 29:31] = _SPACE
    out[:, 31] = _ZERO + flag
    out[:, 32] = np.where(n >= 100, _ZERO + n // 100, _SPACE)
    out[:, 33] = np.where(n >= 10, _ZERO + n // 10 % 10, _SPACE)
    out[:, 34] = _ZERO + n % 10
    out[:, 35] = ord("\n")
    return out


def format_chunk_exact(a: float, b: float, c: float, d: float, ll: int, q: int) -> str:
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
def minute_prefix_v3(minute: int) -> str:
    """``> YYYY MM DD hh mm `` of a minute counted from the GPS epoch (GPS time scale)."""
    d = gpstime.GPS_EPOCH + dt.timedelta(minutes=minute)
    return f"> {d.year:04d} {d.month:02d} {d.day:02d} {d.hour:02d} {d.minute:02d} "


def epoch_line(t_gps_ns: int, flag: int, n: int, v3: bool, sats: list[str]) -> str:
    if v3:
        minute, s100 = divmod((t_gps_ns + 50) // 100, 60 * 10_000_000)
        return f"{minute_prefix_v3(minute)}{fmt_sec(s100)}  {flag:d}{n:3d}\n"
    y, mo, d, h, mi, _s, s100 = epoch_fields(t_gps_ns)
    head = f" {y % 100:02d} {mo:2d} {d:2d} {h:2d} {mi:2d}{s100 / 1e7:11.7f}  {flag:d}{n:3d}"
    if not sats:
        return head + "\n"
    out = [head + "".join(sats[:12]) + "\n"]
    for i in range(12, len(sats), 12):
        out.append(" " * 32 + "".join(sats[i : i + 12]) + "\n")
    return "".join(out)


def d19(v: float) -> str:
    return f"{v:19.12E}"
