"""Solver outputs: cameras.csv, ODM geo.txt, Metashape/Pix4D CSV, GeoJSON, EXIF GPS copies.

Rows are built by the pipeline (:class:`CameraRow`); the writers only format them. Writers are
registered in :data:`WRITERS` by file name. Coordinates in the chosen EPSG come from pyproj
(:class:`Projector`, the one place that imports it). Heights are WGS84 ellipsoidal, or above a
geoid when the CRS is compound with a vertical CRS (``--epsg 9707``, ``--epsg 32629+5773``) or
a geoid grid is given (``--geoid``); every file says which.
"""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from groundstation import gpstime, jsonio, outpaths
from groundstation.errors import ConfigError, InputError
from groundstation.solve.interpolate import flag_names
from groundstation.solve.trajectory import QUALITY_NAMES

FloatArray = npt.NDArray[np.float64]


ELLIPSOIDAL = "WGS84 ellipsoidal height"
SYSTEM_GRID_DIRS = (Path("/usr/share/proj"),)
"""Where Debian's ``proj-data`` puts its grids (EGM96 among them): searched after pyproj's own
data directory and ``PROJ_DATA``."""


def _user_grid_dir() -> str:
    """Where PROJ looks for grids a user installs (``~/.local/share/proj`` on Linux)."""
    from pyproj import datadir

    return str(datadir.get_user_data_dir())  # type: ignore[attr-defined]  # not in its stubs


class Projector:
    """WGS84 (lat, lon, ellipsoidal h) -> a target CRS through pyproj.

    The target is an EPSG code, or two joined by ``+`` (horizontal + vertical, as PROJ writes
    them). Heights stay ellipsoidal unless the CRS has a vertical part (heights above its geoid,
    through the PROJ transformation and its grid) or ``geoid`` names a grid file (heights above
    that grid's geoid). A vertical CRS whose transformation cannot run here (its grid is not
    installed) is refused: PROJ would otherwise fall back to a "ballpark" transformation that
    leaves ellipsoidal heights under the vertical CRS's label.
    """

    def __init__(self, epsg: int | str, geoid: Path | None = None) -> None:
        from pyproj import CRS, Transformer, datadir
        from pyproj.exceptions import CRSError, ProjError
        from pyproj.transformer import TransformerGroup

        for d in SYSTEM_GRID_DIRS:
            if d.is_dir() and str(d) not in datadir.get_data_dir().split(os.pathsep):
                datadir.append_data_dir(str(d))
        try:
            self.crs = CRS.from_user_input(f"EPSG:{epsg}")
        except CRSError as err:
            raise ConfigError("--epsg", f"unknown EPSG code {epsg}: {err}") from err
        self.epsg = epsg
        self.name = self.crs.name
        parts = self.crs.sub_crs_list if self.crs.is_compound else [self.crs]
        horizontal = parts[0]
        if horizontal.is_vertical or len(parts) > 2:
            raise ConfigError("--epsg", (
                f"EPSG:{epsg} ({self.name}) has no horizontal coordinates: give a horizontal CRS, "
                "or a compound one such as 32629+5773 (UTM 29N + EGM96 height)"))
        vertical = parts[1] if len(parts) == 2 else None
        if vertical is not None and geoid is not None:
            raise ConfigError("--geoid", (
                f"EPSG:{epsg} already names its heights ({vertical.name}): give --geoid with a "
                "horizontal CRS only"))
        self.projected = bool(horizontal.is_projected)
        with warnings.catch_warnings():  # a missing grid is said below, in one line
            warnings.simplefilter("ignore", UserWarning)
            self._fwd = Transformer.from_crs("EPSG:4979", self.crs, always_xy=True)
            self._inv = Transformer.from_crs(self.crs, "EPSG:4979", always_xy=True)
        self._geoid: Any = None
        self.height_datum = ELLIPSOIDAL
        self.vertical = vertical is not None or geoid is not None
        if vertical is not None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                group = TransformerGroup("EPSG:4979", self.crs, always_xy=True)
            ok = [t for t in group.transformers if "ballpark" not in t.description.lower()]
            if not group.best_available or not ok:
                missing = sorted({g.short_name for op in group.unavailable_operations
                                  for g in op.grids if not g.available})
                # PROJ's CDN holds GeoTIFF grids
                cdn = next((g for g in missing if g.endswith(".tif")), "NAME")
                raise ConfigError("--epsg", (
                    f"EPSG:{epsg} has heights above {vertical.name}, but the geoid grid PROJ "
                    f"needs for them ({', '.join(missing) or 'none found'}) is not installed: "
                    "Debian's proj-data has EGM96; PROJ's own tool fetches the others "
                    f"(apt install proj-bin; projsync --file {cdn}"
                    f"); or copy the grid into {_user_grid_dir()}; or give --geoid FILE with "
                    "a horizontal CRS "
                    "(ellipsoidal heights are never written under a vertical CRS's label)"))
            self._fwd = ok[0]
            grids = sorted({g.short_name for op in self._fwd.operations or () for g in op.grids})
            self.height_datum = (f"{vertical.name}, orthometric (geoid grid "
                                 f"{', '.join(grids) or 'none'} through PROJ)")
        elif geoid is not None:
            if not geoid.is_file():
                raise ConfigError("--geoid", f"{geoid}: no such file")
            try:
                self._geoid = Transformer.from_pipeline(
                    "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
                    f"+step +proj=vgridshift +grids={geoid.resolve()} +multiplier=1")
            except ProjError as err:
                raise ConfigError("--geoid", (
                    f"{geoid}: PROJ cannot read it as a geoid grid (.gtx, GeoTIFF): "
                    f"{str(err).split('(Internal Proj Error: ')[-1].rstrip(')')}")) from err
            self.height_datum = f"orthometric height above the geoid grid {geoid.name}"
        self.geoid = geoid

    def forward(self, lat_deg: FloatArray, lon_deg: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(x, y) in the target CRS (easting, northing for a projected CRS; lon, lat else)."""
        x, y = self._fwd.transform(np.asarray(lon_deg), np.asarray(lat_deg))[:2]
        return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)

    def inverse(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(lat, lon) in degrees from target-CRS (x, y)."""
        lon, lat = self._inv.transform(np.asarray(x), np.asarray(y))[:2]
        return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)

    def to_wgs84(self, x: float, y: float, h: float) -> tuple[float, float, float]:
        """WGS84 (lat, lon, ellipsoidal h) of a point given in the target CRS: (x, y) as it
        orders them (easting, northing for a projected CRS) and its height (above the geoid
        when the CRS has a vertical part or ``geoid`` was given, else ellipsoidal): the exact
        inverse of :meth:`forward` and :meth:`heights`.

        Raises:
            ConfigError: naming ``--epsg``/``--geoid``: PROJ cannot do it, or the geoid grid
                does not cover the point.
        """
        from pyproj.enums import TransformDirection
        from pyproj.exceptions import ProjError

        try:
            if self.vertical and self._geoid is None:
                lon, lat, he = self._fwd.transform(x, y, h, direction=TransformDirection.INVERSE)
            else:
                lon, lat = self._inv.transform(x, y)[:2]
                he = h
                if self._geoid is not None:
                    he = h + float(self._geoid.transform(lon, lat, 0.0)[2])
        except ProjError as err:
            raise ConfigError("--geoid" if self._geoid is not None else "--epsg", (
                f"PROJ cannot convert {x:.3f}, {y:.3f}, {h:.3f}: {err}")) from err
        out = (float(lat), float(lon), float(he))
        if not all(np.isfinite(out)) or abs(out[2] - h) > 200.0:
            raise ConfigError("--geoid" if self._geoid is not None else "--epsg", (
                f"{x:.3f}, {y:.3f}, {h:.3f} is outside {self.name} (or its geoid grid)"))
        return out

    def heights(self, lat_deg: FloatArray, lon_deg: FloatArray, h_m: FloatArray) -> FloatArray:
        """The heights to write for WGS84 (lat, lon, ellipsoidal h): h itself, or h less the
        geoid's height there.

        Raises:
            ConfigError: naming ``--geoid`` or ``--epsg``: the grid does not cover a point, or
                PROJ cannot read it.
        """
        from pyproj.exceptions import ProjError

        lat, lon, h = (np.asarray(v, dtype=np.float64) for v in (lat_deg, lon_deg, h_m))
        if not self.vertical:
            return h.copy()
        ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
        out = np.full(h.shape, np.nan)
        if not ok.any():
            return out
        try:
            if self._geoid is not None:
                n = cast(FloatArray, self._geoid.transform(
                    lon[ok], lat[ok], np.zeros(int(ok.sum())))[2])
                out[ok] = h[ok] - np.asarray(n, dtype=np.float64)
            else:
                out[ok] = np.asarray(self._fwd.transform(lon[ok], lat[ok], h[ok])[2])
        except ProjError as err:
            raise ConfigError("--geoid" if self._geoid is not None else "--epsg", (
                f"PROJ cannot compute heights above the geoid: {err}")) from err
        bad = ok & ~(np.isfinite(out) & (np.abs(out - h) < 200.0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ConfigError("--geoid" if self._geoid is not None else "--epsg", (
                f"the geoid grid does not cover {lat[i]:.5f}, {lon[i]:.5f} (the flight): "
                "give a grid that covers it"))
        return out


def absolute_sd(
    sd_enu_m: npt.NDArray[np.float64], base_sd_enu_m: tuple[float, float, float] | None,
) -> npt.NDArray[np.float64]:
    """Camera sigmas (n, 3: east, north, up) with the base's own sigma added: the camera's
    absolute uncertainty. The base's error is the same for every camera (a shift of the whole
    block), so it adds in quadrature to each one's relative sigma; ``None``: the base is taken
    as exact."""
    sd = np.asarray(sd_enu_m, dtype=np.float64)
    if base_sd_enu_m is None:
        return sd.copy()
    return np.hypot(sd, np.asarray(base_sd_enu_m, dtype=np.float64))


def utm_epsg(lat_deg: float, lon_deg: float) -> int:
    """EPSG code of the WGS84 UTM zone containing a point (326xx north, 327xx south)."""
    zone = int((lon_deg + 180.0) // 6.0) % 60 + 1
    return (32600 if lat_deg >= 0 else 32700) + zone


@dataclass(frozen=True, slots=True)
class CameraRow:
    """One photo's (or one mark's) camera position, ready to write.

    Attributes:
        photo: image file name ("" for a mark without photo).
        mark: index of the mark in the flight (0-based), -1 for a photo without mark.
        mark_count: the receiver's count of that mark (``Mark.number``: its falling-edge
            record's, as in ``mark_NNNN``).
        t_gps_ns: instant used (edge + shutter delay), -1 when none.
        lat_deg, lon_deg, h_m: projection centre, WGS84 latitude and longitude, height as the
            output says (:attr:`Projector.height_datum`).
        x_m, y_m: projection centre in the output CRS.
        sd_e_m, sd_n_m, sd_u_m: σ east, north, up.
        quality: RTKLIB Q (0 = no position).
        flags: ``FLAG_*`` mask from interpolation.
        omega_deg, phi_deg, kappa_deg: attitude used for the lever arm (NaN if none).
        attitude: ``eo`` (from the EO file), ``nadir-track`` (assumed) or ``none``.
        antenna_x_m, antenna_y_m, antenna_h_m: antenna position before the lever arm.
        ellipsoidal_h_m: the projection centre's WGS84 ellipsoidal height (= ``h_m`` unless
            the heights are above a geoid).
        mark_name: without photos, the name the mark's row carries in the photogrammetry
            exports (:func:`mark_names`); "" otherwise.
        grade: what the position may be called (``fixed``, ``fixed-unchecked``, ``float``,
            ``single``, ``none``: :data:`groundstation.solve.integrity.grade.GRADE_MEANING`).
        check: the check that decided the grade (``arcs``, ``both-directions``, ...).
    """

    photo: str
    mark: int
    mark_count: int
    t_gps_ns: int
    lat_deg: float
    lon_deg: float
    h_m: float
    x_m: float
    y_m: float
    sd_e_m: float
    sd_n_m: float
    sd_u_m: float
    quality: int
    flags: int
    omega_deg: float = math.nan
    phi_deg: float = math.nan
    kappa_deg: float = math.nan
    attitude: str = "none"
    antenna_x_m: float = math.nan
    antenna_y_m: float = math.nan
    antenna_h_m: float = math.nan
    ellipsoidal_h_m: float = math.nan
    mark_name: str = ""
    grade: str = "none"
    check: str = ""

    @property
    def positioned(self) -> bool:
        return math.isfinite(self.x_m) and math.isfinite(self.lat_deg)

    @property
    def label(self) -> str:
        """The image name in the photogrammetry exports: the photo, or the mark's name."""
        return self.photo or self.mark_name

    @property
    def flag_text(self) -> str:
        return ";".join(flag_names(self.flags))


MARK_NAME_PREFIX = "mark_"


def mark_names(numbers: Sequence[int]) -> list[str]:
    """Names of marks exported without photos: ``mark_`` and the receiver's pulse number
    (``mark_0031``), so that a mark the receiver missed leaves a gap in the names instead of
    shifting every later one against the camera's image numbers. A number seen again (the
    receiver restarted and counts from 0 again) gets ``_2``, ``_3``, ... so names stay unique.
    """
    seen: dict[str, int] = {}
    out = []
    for n in numbers:
        name = f"{MARK_NAME_PREFIX}{n:04d}"
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 else f"{name}_{seen[name]}")
    return out


@dataclass(frozen=True, slots=True)
class SolveOutput:
    """What the writers get: rows, CRS, trajectory for maps, notes for headers."""

    rows: tuple[CameraRow, ...]
    epsg: int | str
    crs_name: str
    projected: bool
    trajectory_llh: FloatArray  # (n, 3) lat, lon, h of every epoch
    trajectory_quality: npt.NDArray[np.int64]
    trajectory_t_gps_ns: npt.NDArray[np.int64]
    mark_llh: FloatArray  # (m, 3) antenna at every mark (NaN where none)
    mark_t_gps_ns: npt.NDArray[np.int64]
    notes: tuple[str, ...] = ()
    height_datum: str = ELLIPSOIDAL
    """What the rows' heights are (:attr:`Projector.height_datum`)."""
    base_sd_enu_m: tuple[float, float, float] | None = None
    """The base position's sigma (east, north, up); None: taken as exact."""


def _f(v: float, nd: int) -> str:
    return "" if not math.isfinite(v) else f"{v:.{nd}f}"


def _utc(t_gps_ns: int) -> str:
    if t_gps_ns < 0:
        return ""
    unix_ns = gpstime.gps_to_unix_ns(t_gps_ns)
    base = gpstime.gps_to_datetime(t_gps_ns).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{base}.{unix_ns % 10**9:09d}Z"


CAMERAS_COLUMNS = (
    "photo", "mark", "mark_count", "gps_week", "gps_tow_s", "utc",
    "x_m", "y_m", "h_m", "lat_deg", "lon_deg", "sd_e_m", "sd_n_m", "sd_u_m",
    "quality", "quality_name", "grade", "check", "flags", "omega_deg", "phi_deg", "kappa_deg",
    "attitude", "antenna_x_m", "antenna_y_m", "antenna_h_m", "ellipsoidal_h_m",
    "abs_sd_e_m", "abs_sd_n_m", "abs_sd_u_m",
)
"""Columns of ``cameras.csv``; x/y are in the output EPSG, h as its first line says (WGS84
ellipsoidal, or above a geoid). ``sd_*`` are relative to the base, ``abs_sd_*`` include the base
position's own sigma (equal to ``sd_*`` when the base is taken as exact: the second line says)."""


def mark_numbers_text(count_column: str = "mark_count") -> str:
    """What the ``mark`` and ``mark_count`` columns are and why they differ, in the same words
    in ``cameras.csv``'s header and the report (whose column is ``count``)."""
    return ("mark is the row's index among the marks received in the flight (0, 1, 2, ...; "
            f"empty for a photo without one); {count_column} is the receiver's own number of "
            "the pulse (its TIM-TM2 count: the number in mark_NNNN, inspect and marks.csv). "
            "They differ after a mark that never arrived (not reported by the receiver, or "
            "lost on the radio link): the receiver counted it, the index has no row for it.")


FORMULA_PREFIXES = ("=", "+", "-", "@", "\t", "\r")
"""A spreadsheet reads a cell starting with one of these as a formula (CSV injection)."""


def text_cell(text: str) -> str:
    """A text field (a photo name) for a CSV export: a leading formula character is
    neutralised with an apostrophe (the OWASP rule) and line breaks become spaces, so a photo
    named ``=HYPERLINK(...)`` stays text in a spreadsheet. Numbers are never passed here."""
    if text.startswith(FORMULA_PREFIXES):
        text = "'" + text
    return text.replace("\r", " ").replace("\n", " ")


def _comment(text: str) -> str:
    """One comment line's text (a line break would start a data row)."""
    return " ".join(text.splitlines())


def cameras_csv(out: SolveOutput) -> str:
    """``cameras.csv``: one row per photo (and per orphan mark), every field the solver knows."""
    buf = io.StringIO()
    buf.write(f"# crs EPSG:{out.epsg} ({out.crs_name}); h = {_comment(out.height_datum)}\n")
    base = out.base_sd_enu_m
    buf.write("# sd_*: relative to the base; abs_sd_*: with the base position's sigma "
              + ("(" + "/".join(f"{v:.3f}" for v in base) + " m east/north/up)\n" if base
                 else "(none given: the base is taken as exact)\n"))
    buf.write(f"# {mark_numbers_text()}\n")
    for note in out.notes:
        buf.write(f"# {_comment(note)}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CAMERAS_COLUMNS)
    nd_xy = 3 if out.projected else 9
    absolute = absolute_sd(
        np.array([(r.sd_e_m, r.sd_n_m, r.sd_u_m) for r in out.rows], dtype=np.float64
                 ).reshape(-1, 3), base)
    for r, ab in zip(out.rows, absolute.tolist(), strict=True):
        week, tow = ("", "")
        if r.t_gps_ns >= 0:
            wk, tow_ns = gpstime.week_tow(r.t_gps_ns)
            week, tow = str(wk), f"{tow_ns // 10**9}.{tow_ns % 10**9:09d}"
        w.writerow([
            text_cell(r.photo), r.mark if r.mark >= 0 else "",
            r.mark_count if r.mark_count >= 0 else "",
            week, tow, _utc(r.t_gps_ns),
            _f(r.x_m, nd_xy), _f(r.y_m, nd_xy), _f(r.h_m, 3),
            _f(r.lat_deg, 9), _f(r.lon_deg, 9),
            _f(r.sd_e_m, 3), _f(r.sd_n_m, 3), _f(r.sd_u_m, 3),
            r.quality, QUALITY_NAMES.get(r.quality, str(r.quality)), r.grade, r.check,
            r.flag_text,
            _f(r.omega_deg, 4), _f(r.phi_deg, 4), _f(r.kappa_deg, 4), r.attitude,
            _f(r.antenna_x_m, nd_xy), _f(r.antenna_y_m, nd_xy), _f(r.antenna_h_m, 3),
            _f(r.ellipsoidal_h_m, 3), _f(ab[0], 3), _f(ab[1], 3), _f(ab[2], 3),
        ])
    return buf.getvalue()


def _photo_rows(out: SolveOutput) -> list[CameraRow]:
    """The rows of the photogrammetry exports: positioned photos, or (without photos)
    positioned marks by their names."""
    return [r for r in out.rows if r.label and r.positioned]


def geo_txt(out: SolveOutput) -> str:
    """OpenDroneMap ``geo.txt``: ``EPSG:N`` then ``image x y z yaw pitch roll horz vert``.

    Yaw is the compass direction of the image x axis from κ (90 - κ: κ counts
    counter-clockwise from east), pitch and roll 0 for the nadir camera (ODM uses the angles
    for radiometric calibration only, and reads 0 as unknown); horizontal accuracy is the
    larger of σ east and north. z is the height of every export (ellipsoidal or above a geoid:
    the ``EPSG:`` line names a compound CRS for the latter; with ``--geoid`` it cannot). ODM
    splits a line on whitespace, so a photo whose name holds any cannot be listed: it is named
    in a ``#`` comment line (which ODM skips) instead, and keeps its row in the CSV exports.
    """
    lines = [f"EPSG:{out.epsg}"]
    nd = 3 if out.projected else 9
    for r in _photo_rows(out):
        if any(c.isspace() for c in r.label) or r.label.startswith("#"):
            lines.append(f"# not listed (whitespace or '#' in the name): {r.label!r}")
            continue
        horz = max(r.sd_e_m, r.sd_n_m)
        yaw = (90.0 - r.kappa_deg) % 360.0 if math.isfinite(r.kappa_deg) else 0.0
        lines.append(
            f"{r.label} {r.x_m:.{nd}f} {r.y_m:.{nd}f} {r.h_m:.3f} {yaw:.2f} 0 0 "
            f"{_f(horz, 3) or '0'} {_f(r.sd_u_m, 3) or '0'}"
        )
    return "\n".join(lines) + "\n"


REFERENCE_COLUMNS = (
    "label", "x_east", "y_north", "z_height", "sd_x_m", "sd_y_m", "sd_z_m",
    "omega_deg", "phi_deg", "kappa_deg", "grade",
)


def reference_csv(out: SolveOutput) -> str:
    """Metashape "Import Reference" CSV (comma, header row, ``#`` comment with the CRS)."""
    buf = io.StringIO()
    buf.write(f"# EPSG:{out.epsg} {_comment(out.crs_name)}; z = {_comment(out.height_datum)}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(REFERENCE_COLUMNS)
    nd = 3 if out.projected else 9
    for r in _photo_rows(out):
        w.writerow([
            text_cell(r.label), _f(r.x_m, nd), _f(r.y_m, nd), _f(r.h_m, 3),
            _f(r.sd_e_m, 3), _f(r.sd_n_m, 3), _f(r.sd_u_m, 3),
            _f(r.omega_deg, 4), _f(r.phi_deg, 4), _f(r.kappa_deg, 4), r.grade,
        ])
    return buf.getvalue()


PIX4D_COLUMNS = ("imagename", "Y", "X", "Z", "accuracy_horz", "accuracy_vert")


def pix4d_csv(out: SolveOutput) -> str:
    """Pix4D image geolocation CSV: name, Y (northing/lat), X (easting/lon), Z, accuracies.

    PIX4Dmatic reads no header row, only a comment on the first line: the column names are
    that comment, with the CRS and the height datum after them.
    """
    buf = io.StringIO()
    buf.write(f"#{','.join(PIX4D_COLUMNS)} ; EPSG:{out.epsg} {out.crs_name}; "
              f"Z = {_comment(out.height_datum)}\n")
    w = csv.writer(buf, lineterminator="\n")
    nd = 3 if out.projected else 9
    for r in _photo_rows(out):
        w.writerow([
            text_cell(r.label), _f(r.y_m, nd), _f(r.x_m, nd), _f(r.h_m, 3),
            _f(max(r.sd_e_m, r.sd_n_m), 3), _f(r.sd_u_m, 3),
        ])
    return buf.getvalue()


def _clean(v: float) -> float | None:
    return v if math.isfinite(v) else None


def geojson(out: SolveOutput) -> str:
    """GeoJSON (RFC 7946, WGS84 lon/lat/h): trajectory segments by quality, marks, photos."""
    feats: list[dict[str, Any]] = []
    llh, q = out.trajectory_llh, out.trajectory_quality
    start = 0
    for i in range(1, len(q) + 1):
        if i == len(q) or q[i] != q[start]:
            seg = llh[max(start - 1, 0) : i]  # joined to the previous run's last epoch
            if len(seg) >= 2:
                feats.append({
                    "type": "Feature",
                    "geometry": {
                        "type": "LineString",
                        "coordinates": [[round(b, 9), round(a, 9), round(h, 3)] for a, b, h in
                                        seg.tolist()],
                    },
                    "properties": {
                        "kind": "trajectory", "quality": int(q[start]),
                        "quality_name": QUALITY_NAMES.get(int(q[start]), str(q[start])),
                        "start_utc": _utc(int(out.trajectory_t_gps_ns[start])),
                    },
                })
            start = i
    grade_of_mark = {r.mark: r.grade for r in out.rows if r.mark >= 0}
    for k, (a, b, h) in enumerate(out.mark_llh.tolist()):
        if not math.isfinite(a):
            continue
        feats.append({
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [round(b, 9), round(a, 9), round(h, 3)]},
            "properties": {"kind": "mark", "mark": k, "utc": _utc(int(out.mark_t_gps_ns[k])),
                           "grade": grade_of_mark.get(k, "")},
        })
    for r in out.rows:
        if not r.photo or not r.positioned:
            continue
        feats.append({
            "type": "Feature",
            "geometry": {
                "type": "Point",
                "coordinates": [round(r.lon_deg, 9), round(r.lat_deg, 9),
                                round(r.ellipsoidal_h_m if math.isfinite(r.ellipsoidal_h_m)
                                      else r.h_m, 3)],
            },
            "properties": {
                "kind": "photo", "photo": r.photo, "mark": r.mark, "utc": _utc(r.t_gps_ns),
                "quality": r.quality, "grade": r.grade, "check": r.check,
                "flags": r.flag_text, "sd_e_m": _clean(r.sd_e_m),
                "sd_n_m": _clean(r.sd_n_m), "sd_u_m": _clean(r.sd_u_m), "attitude": r.attitude,
            },
        })
    # RFC 7946 positions are WGS84 lon, lat, height: ellipsoidal here whatever the other
    # exports' heights (said as a foreign member, as in every other export).
    return jsonio.dumps({"type": "FeatureCollection", "height_datum": "WGS84 ellipsoidal",
                         "features": feats}).decode()


WRITERS: dict[str, Callable[[SolveOutput], str]] = {
    "cameras.csv": cameras_csv,
    "geo.txt": geo_txt,
    "reference.csv": reference_csv,
    "pix4d.csv": pix4d_csv,
    "cameras.geojson": geojson,
}
"""Output file name -> writer (text)."""


def write_all(out: SolveOutput, directory: Path) -> list[Path]:
    """Write every registered output into ``directory``; returns the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, writer in WRITERS.items():
        p = directory / name
        p.write_text(writer(out), encoding="utf-8")
        paths.append(p)
    return paths


OUTPUT_NAMES: tuple[str, ...] = (*WRITERS, "report.html", "rtklib/", "photos/")
"""What ``solve`` writes into its output directory (:mod:`groundstation.outpaths`)."""


def check_output_dir(out_dir: Path, inputs: Sequence[Path | None]) -> None:
    """Refuse an output directory that is or is inside an input directory, or where solve's
    outputs would replace an input or a recording (:func:`groundstation.outpaths.check_output_dir`).

    Raises:
        ConfigError: naming ``--out``.
    """
    outpaths.check_output_dir(out_dir, inputs, key="--out", writes=OUTPUT_NAMES)


def write_exif_copies(
    rows: Sequence[CameraRow], photo_dir: Path, out_dir: Path
) -> list[Path]:
    """Copies of the photos with EXIF GPS tags from their camera positions (originals untouched).

    Raises:
        ConfigError: ``out_dir`` is the photo directory or inside it.
    """
    from groundstation.solve.exif import write_gps_copy

    check_output_dir(out_dir, [photo_dir])
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for r in rows:
        if not r.photo or not r.positioned:
            continue
        src = photo_dir / r.photo
        if not src.is_file():
            raise InputError(f"{src}: photo vanished")
        dst = out_dir / r.photo
        # the accuracy as pix4d.csv gives it: the larger horizontal sigma, the vertical one
        if write_gps_copy(src, dst, r.lat_deg, r.lon_deg, r.h_m, max(r.sd_e_m, r.sd_n_m),
                          r.sd_u_m):  # else a warning, skipped
            written.append(dst)
    return written
