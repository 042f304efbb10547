"""RTKLIB ``.pos`` solution files: their layouts (xyz, llh, enu; GPST, UTC, JST; calendar or
week and seconds), parsed to a :class:`~groundstation.solve.trajectory.Trajectory`; the checks
made before reading one; what its ``%`` header says about the solution.
"""

from __future__ import annotations

import gzip
import math
import re
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.errors import InputError
from groundstation.geodesy import ecef_to_llh, enu_rotation, llh_to_ecef
from groundstation.solve.trajectory import Trajectory, make_trajectory

FloatArray = npt.NDArray[np.float64]


class EmptySolutionError(InputError):
    """A solution file without a single solution row."""


POS_LAYOUT_NOTE = "RTKLIB .pos (xyz, GPST, calendar)"
"""The layout note of an engine's solution (our engines always write it so: options.py)."""

_TIME_SYSTEMS = ("GPST", "UTC", "JST")
_JST_OFFSET_NS = 9 * 3600 * gpstime.NS_PER_S


@dataclass(frozen=True, slots=True)
class PosLayout:
    """How the rows of a ``.pos`` file are laid out (from its header or guessed)."""

    time_system: str = "GPST"
    time_form: str = "calendar"  # "calendar" (yyyy/mm/dd hh:mm:ss) or "tow" (week tow)
    coords: str = "xyz"  # "xyz", "llh" or "enu"
    dms: bool = False
    columns: tuple[str, ...] = ()
    ref_ecef_m: tuple[float, float, float] | None = None


_DEFAULT_COLUMNS = {
    "xyz": ("x", "y", "z", "q", "ns", "sdx", "sdy", "sdz", "sdxy", "sdyz", "sdzx", "age", "ratio"),
    "llh": ("lat", "lon", "h", "q", "ns", "sdn", "sde", "sdu", "sdne", "sdeu", "sdun", "age",
            "ratio"),
    "enu": ("e", "n", "u", "q", "ns", "sde", "sdn", "sdu", "sden", "sdnu", "sdue", "age", "ratio"),
}
_HEADER_NAMES = {
    "x-ecef": "x", "y-ecef": "y", "z-ecef": "z",
    "latitude": "lat", "longitude": "lon", "height": "h",
    "e-baseline": "e", "n-baseline": "n", "u-baseline": "u",
}


def _header_column(token: str) -> str:
    base = token.split("(")[0].strip().lower()
    return _HEADER_NAMES.get(base, base)


def _parse_ref(text: str) -> tuple[float, float, float] | None:
    vals = [float(v) for v in text.split()]
    if len(vals) == 6:  # dms latitude and longitude
        lat = math.copysign(abs(vals[0]) + vals[1] / 60 + vals[2] / 3600, vals[0] or 1.0)
        lon = math.copysign(abs(vals[3]) + vals[4] / 60 + vals[5] / 3600, vals[3] or 1.0)
        return llh_to_ecef(lat, lon, 0.0)
    if len(vals) != 3:
        return None
    if max(abs(v) for v in vals) > 1000.0 and abs(vals[0]) > 180.0:
        return vals[0], vals[1], vals[2]
    return llh_to_ecef(*vals)


def _layout_from_header(header: list[str], first_row: list[str] | None) -> PosLayout:
    time_system, time_form, coords, dms = "GPST", "calendar", "", False
    columns: tuple[str, ...] = ()
    ref: tuple[float, float, float] | None = None
    for line in header:
        body = line.lstrip("%").strip()
        m = re.match(r"ref pos\s*:\s*(.*)$", body)
        if m:
            ref = _parse_ref(m.group(1))
            continue
        tokens = body.split()
        if tokens and tokens[0] in _TIME_SYSTEMS and len(tokens) > 3:
            time_system = tokens[0]
            rest = tokens[1:]
            dms = any("d'" in t for t in rest)
            columns = tuple(_header_column(t) for t in rest)
            if columns and columns[0] in ("x", "lat", "e"):
                coords = {"x": "xyz", "lat": "llh", "e": "enu"}[columns[0]]
    if first_row is not None:
        time_form = "calendar" if "/" in first_row[0] else "tow"
        if not coords:
            coords, dms = _guess_coords(first_row)
    if not coords:
        coords = "xyz"
    if not columns:
        columns = _DEFAULT_COLUMNS[coords]
    return PosLayout(time_system, time_form, coords, dms, columns, ref)


def _guess_coords(row: list[str]) -> tuple[str, bool]:
    """xyz / llh (decimal or dms) from the values of a header-less row."""
    vals = [float(v) for v in row[2:8]]
    if all(abs(v) > 1e5 for v in vals[:3]):
        return "xyz", False
    # dms rows: deg min sec deg min sec -> the 2nd and 5th values are whole minutes < 60.
    if (
        len(vals) >= 6
        and vals[1] == int(vals[1]) and 0 <= vals[1] < 60
        and vals[4] == int(vals[4]) and 0 <= vals[4] < 60
        and 0 <= vals[2] < 60 and 0 <= vals[5] < 60 and abs(vals[3]) <= 180
    ):
        return "llh", True
    if abs(vals[0]) <= 90 and abs(vals[1]) <= 180:
        return "llh", False
    return "enu", False


def _row_time_ns(tokens: list[str], layout: PosLayout) -> int:
    if layout.time_form == "calendar":
        d = tokens[0].split("/")
        hh, mm, ss = tokens[1].split(":")
        sec, _, frac = ss.partition(".")
        frac_ns = int((frac + "000000000")[:9]) if frac else 0
        import datetime as dt

        day = dt.datetime(int(d[0]), int(d[1]), int(d[2]), tzinfo=dt.UTC)
        base_s = int((day - gpstime.GPS_EPOCH).total_seconds())
        t = (base_s + int(hh) * 3600 + int(mm) * 60 + int(sec)) * gpstime.NS_PER_S + frac_ns
    else:
        week = int(tokens[0])
        sec, _, frac = tokens[1].partition(".")
        frac_ns = int((frac + "000000000")[:9]) if frac else 0
        t = week * gpstime.NS_PER_WEEK + int(sec) * gpstime.NS_PER_S + frac_ns
    if layout.time_system == "GPST":
        return t
    if layout.time_system == "JST":
        t -= _JST_OFFSET_NS
    return t + gpstime.leap_seconds_at_utc(t) * gpstime.NS_PER_S


def _signed_sq(v: FloatArray) -> FloatArray:
    """RTKLIB writes covariances as sign(c)·sqrt(|c|); undo it."""
    return np.sign(v) * v * v


def parse_pos(
    text: str | Iterable[str],
    *,
    source: str = "",
    ref_ecef_m: tuple[float, float, float] | None = None,
) -> Trajectory:
    """Parse RTKLIB solution text (``out-solformat`` xyz, llh or enu; any time form/system).

    Handles: GPST, UTC and JST times, as ``yyyy/mm/dd hh:mm:ss.sss`` or ``week tow``; latitude
    and longitude in degrees or d m s; Q and ns as integers or floats; covariance columns; extra
    columns (age, ratio, velocities). Without a header the layout is guessed from the values.

    Args:
        text: the file content, or its lines.
        source: name recorded in the trajectory.
        ref_ecef_m: base position for ``enu`` files whose header lacks ``ref pos``.

    Raises:
        InputError: no solution rows, or an ``enu`` file without a reference position.
    """
    lines = text.splitlines() if isinstance(text, str) else list(text)
    header = [ln for ln in lines if ln.startswith("%")]
    rows = [ln.split() for ln in lines if ln.strip() and not ln.startswith(("%", "#"))]
    if not rows:
        raise EmptySolutionError(f"{source or 'pos'}: no solution rows")
    try:
        layout = _layout_from_header(header, rows[0])
    except (ValueError, IndexError) as err:
        raise InputError(f"{source or 'pos'}: cannot parse {' '.join(rows[0])!r}") from err
    ref = layout.ref_ecef_m or ref_ecef_m
    ncoord = 6 if layout.dms else 3
    # Map every named column to its token index (the time takes two tokens).
    names = list(layout.columns)
    index: dict[str, int] = {}
    pos = 2
    for i, name in enumerate(names):
        index[name] = pos
        pos += 3 if (layout.dms and i < 2) else 1
    n = len(rows)
    t = np.empty(n, np.int64)
    vals = np.full((n, pos - 2 if pos > 2 else 0), np.nan)
    try:
        for k, r in enumerate(rows):
            t[k] = _row_time_ns(r, layout)
            m = min(len(r) - 2, vals.shape[1])
            vals[k, :m] = [float(v) for v in r[2 : 2 + m]]
    except (ValueError, IndexError) as err:
        raise InputError(f"{source or 'pos'}: row {k + 1}: cannot parse {' '.join(r)!r}") from err

    def col(name: str) -> FloatArray:
        i = index.get(name)
        return vals[:, i - 2] if i is not None and i - 2 < vals.shape[1] else np.full(n, np.nan)

    if layout.coords == "xyz":
        xyz = np.column_stack([col("x"), col("y"), col("z")])
    else:
        if layout.coords == "llh":
            if layout.dms:
                c = vals[:, :ncoord]
                lat = np.sign(c[:, 0] + 0.0) * (np.abs(c[:, 0]) + c[:, 1] / 60 + c[:, 2] / 3600)
                lon = np.sign(c[:, 3] + 0.0) * (np.abs(c[:, 3]) + c[:, 4] / 60 + c[:, 5] / 3600)
                lat = np.where(c[:, 0] == 0, np.abs(lat), lat)
                lon = np.where(c[:, 3] == 0, np.abs(lon), lon)
                h = vals[:, ncoord]
            else:
                lat, lon, h = col("lat"), col("lon"), col("h")
            xyz = np.array([llh_to_ecef(a, b, c) for a, b, c in zip(lat, lon, h, strict=True)])
        else:
            if ref is None:
                raise InputError(
                    f"{source or 'pos'}: enu (baseline) solution without a reference position"
                )
            rot = np.array(enu_rotation(*ecef_to_llh(*ref)[:2]))
            enu = np.column_stack([col("e"), col("n"), col("u")])
            xyz = np.asarray(ref) + enu @ rot
    q = np.nan_to_num(col("q"), nan=0.0).astype(np.int64)
    nsv = np.nan_to_num(col("ns"), nan=0.0).astype(np.int64)
    if layout.coords == "xyz":
        sd = _sd_enu_from_xyz(
            xyz, col("sdx"), col("sdy"), col("sdz"), col("sdxy"), col("sdyz"), col("sdzx")
        )
    else:
        sd = np.column_stack([col("sde"), col("sdn"), col("sdu")])
    return make_trajectory(
        t, xyz, q, sd_enu_m=sd, ns=nsv, ratio=col("ratio"), source=source,
        notes=(f"RTKLIB .pos ({layout.coords}, {layout.time_system}, {layout.time_form})",),
    )


def _sd_enu_from_xyz(
    xyz: FloatArray, sdx: FloatArray, sdy: FloatArray, sdz: FloatArray,
    sdxy: FloatArray, sdyz: FloatArray, sdzx: FloatArray,
) -> FloatArray:
    n = xyz.shape[0]
    cov = np.zeros((n, 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = sdx**2, sdy**2, sdz**2
    off = [(0, 1, sdxy), (1, 2, sdyz), (2, 0, sdzx)]
    for i, j, v in off:
        c = _signed_sq(np.nan_to_num(v))
        cov[:, i, j] = c
        cov[:, j, i] = c
    if n == 0:
        return np.zeros((0, 3))
    lat, lon, _ = ecef_to_llh(*np.mean(xyz, axis=0))
    rot = np.array(enu_rotation(lat, lon))
    enu_cov = rot @ cov @ rot.T
    diag = np.einsum("nii->ni", enu_cov)
    return np.asarray(np.sqrt(np.clip(diag, 0.0, None)), dtype=np.float64)


def read_pos(path: str | Path, ref_ecef_m: tuple[float, float, float] | None = None) -> Trajectory:
    """Read an RTKLIB ``.pos`` file (plain or ``.gz``)."""
    p = Path(path)
    try:
        data = p.read_bytes()
        if data[:2] == b"\x1f\x8b":
            data = gzip.decompress(data)
    except FileNotFoundError as err:
        raise InputError(f"{p}: no such file") from err
    except OSError as err:
        raise InputError(f"{p}: cannot read: {err}") from err
    except (EOFError, gzip.BadGzipFile, zlib.error) as err:
        raise InputError(f"{p}: damaged gzip: {err}") from err
    _check_text(p, data[:POS_HEAD_BYTES])
    return parse_pos(data.decode("ascii", "replace"), source=p.name, ref_ecef_m=ref_ecef_m)


POS_HEAD_BYTES = 4096


def _check_text(p: Path, head: bytes) -> None:
    # A photo or a recording given by mistake: say so in one line rather than echo its bytes.
    if b"\x00" in head or head.startswith(b"\xff\xd8") or not _is_text(head):
        raise InputError(f"{p}: not an RTKLIB .pos text file (binary data)")


def check_pos_file(path: Path) -> None:
    """The checks :func:`read_pos` makes before parsing, on the file's head only: what
    ``solve`` runs before it creates anything.

    Raises:
        InputError: unreadable, damaged gzip, or not text (a photo, a recording).
    """
    try:
        with path.open("rb") as f:
            gz = f.read(2) == b"\x1f\x8b"
        with (gzip.open(path, "rb") if gz else path.open("rb")) as f:
            head = f.read(POS_HEAD_BYTES)
    except FileNotFoundError as err:
        raise InputError(f"{path}: no such file") from err
    except OSError as err:  # gzip.BadGzipFile is an OSError
        if isinstance(err, gzip.BadGzipFile):
            raise InputError(f"{path}: damaged gzip: {err}") from err
        raise InputError(f"{path}: cannot read: {err}") from err
    except (EOFError, zlib.error) as err:
        raise InputError(f"{path}: damaged gzip: {err}") from err
    _check_text(path, head)


def _is_text(head: bytes) -> bool:
    """UTF-8 text, allowing a character cut at the end of ``head``."""
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as err:
        return err.start >= len(head) - 3
    return True


@dataclass(frozen=True, slots=True)
class PosHeader:
    """What an imported RTKLIB ``.pos`` file says about itself."""

    program: str = ""
    ref_ecef_m: tuple[float, float, float] | None = None
    lines: tuple[str, ...] = ()


def pos_header(path: Path | None) -> PosHeader:
    """The ``%`` header of a ``.pos`` file (plain or gzip); empty when none or unreadable."""
    if path is None:
        return PosHeader()
    lines: list[str] = []
    try:
        opener = gzip.open if path.suffix == ".gz" else open
        with opener(path, "rt", encoding="ascii", errors="replace") as f:
            for line in f:
                if not line.startswith("%"):
                    break
                lines.append(line.rstrip("\n"))
    except OSError:
        return PosHeader()
    program = ""
    for line in lines:
        body = line.lstrip("%").strip()
        if body.startswith("program"):
            program = body.split(":", 1)[-1].strip()
    return PosHeader(program, _layout_from_header(lines, None).ref_ecef_m, tuple(lines))
