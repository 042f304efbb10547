"""The report's figures, drawn with matplotlib (Agg) and returned as inline SVG text.

One function per figure; each takes plain arrays (no solver objects) so that the report owns
what is shown and the figures only how. Times are GPS ns; the time axes are labelled in UTC at
the bottom and GPS time of week at the top. Map axes are in the output CRS with a grid, a scale
bar and a (grid) north arrow. Text stays text in the SVG (``svg.fonttype = none``), so labels
are searchable and print sharply; dense point clouds are rasterised inside the SVG to keep the
page light.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")  # no display; must precede pyplot

import matplotlib.dates as mdates  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import numpy.typing as npt  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch, Rectangle  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402

from groundstation import gpstime  # noqa: E402
from groundstation.solve.flight import Span  # noqa: E402
from groundstation.solve.palette import GRADE_COLOURS, QUALITY_COLOURS  # noqa: E402
from groundstation.solve.trajectory import QUALITY_NAMES  # noqa: E402

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

WIDTH_IN = 7.2
"""Figure width: fits an A4 page between 12 mm margins at 100 %."""
_RC: dict[Any, Any] = {
    "svg.fonttype": "none",
    "font.family": "sans-serif",
    "font.sans-serif": ["DejaVu Sans", "Liberation Sans", "Arial", "Helvetica"],
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.labelsize": 9.0,
    "legend.fontsize": 8.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "axes.grid": True,
    "grid.color": "#d0d0d0",
    "grid.linewidth": 0.6,
    "date.epoch": "1970-01-01T00:00:00",
}


def to_svg(fig: Figure, name: str) -> str:
    """The figure as an ``<svg>`` element for inline use (no XML prolog, scalable width)."""
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": name}):  # ids unique across the page
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
    plt.close(fig)
    text = buf.getvalue()
    text = text[text.index("<svg"):]
    # Inline in HTML: no namespace declarations or RDF metadata (URLs a reviewer might take
    # for links). The root keeps its natural size (type as designed, readable on screen and
    # on A4); the page's CSS only shrinks it when the window is narrower.
    text = re.sub(r"<metadata>.*?</metadata>", "", text, count=1, flags=re.S)
    text = re.sub(r'\s+xmlns(:\w+)?="[^"]*"', "", text[:2000]) + text[2000:]
    return text.replace("<svg", f'<svg class="fig" role="img" aria-label="{name}"', 1)


def _dates(t_gps_ns: npt.ArrayLike) -> FloatArray:
    """GPS ns -> matplotlib date numbers of UTC (leap seconds of the first instant)."""
    t = np.asarray(t_gps_ns, dtype=np.int64)
    if t.size == 0:
        return np.zeros(0)
    leap = gpstime.leap_seconds_at_gps(int(t.flat[0]))
    unix_s = (t - leap * gpstime.NS_PER_S) / 1e9 + gpstime.GPS_EPOCH_UNIX_S
    return np.asarray(unix_s / 86400.0, dtype=np.float64)  # date.epoch is 1970-01-01


def _time_axes(ax: Axes, t0_gps_ns: int) -> None:
    """UTC (HH:MM:SS) below, GPS seconds of week above."""
    loc = mdates.AutoDateLocator(minticks=4, maxticks=9)  # type: ignore[no-untyped-call]
    ax.xaxis.set_major_locator(loc)
    ax.xaxis.set_major_formatter(mdates.DateFormatter("%H:%M:%S"))  # type: ignore[no-untyped-call]
    ax.set_xlabel("UTC (" + gpstime.gps_to_datetime(t0_gps_ns).strftime("%Y-%m-%d") + ")")
    d0 = float(_dates([t0_gps_ns])[0])
    week, tow0_ns = gpstime.week_tow(t0_gps_ns)
    tow0 = tow0_ns / 1e9

    def fwd(x: Any) -> Any:
        return np.asarray((np.asarray(x) - d0) * 86400.0 + tow0)

    def inv(x: Any) -> Any:
        return np.asarray((np.asarray(x) - tow0) / 86400.0 + d0)

    top = ax.secondary_xaxis("top", functions=(fwd, inv))
    top.set_xlabel(f"GPS week {week}, seconds of week", fontsize=8)
    top.tick_params(labelsize=7)
    top.xaxis.get_major_formatter().set_useOffset(False)  # type: ignore[attr-defined]


def _nice(x: float) -> float:
    """1, 2 or 5 times a power of ten, at most ``x``."""
    if not x > 0:
        return 1.0
    p = 10 ** math.floor(math.log10(x))
    return float(max(m * p for m in (1, 2, 5) if m * p <= x))


def _track_lines(pts: FloatArray, quality: IntArray, seg_ok: npt.NDArray[np.bool_],
                 ) -> tuple[list[FloatArray], list[str]]:
    """The track as polylines, one per run of drawn segments of one quality (segment k joins
    epochs k and k+1 and takes epoch k+1's quality), with their colours: a few paths instead of
    one per epoch (an hour at 5 Hz: 18 000), the same picture."""
    key = np.where(seg_ok, quality[1:], -1).astype(np.int64)
    lines, cols = [], []
    for a, b in _runs(key):
        if key[a] >= 0:
            lines.append(pts[a:b + 1])
            cols.append(QUALITY_COLOURS.get(int(key[a]), "#7f7f7f"))
    return lines, cols


def trajectory(
    x_m: FloatArray, y_m: FloatArray, quality: IntArray, t_gps_ns: IntArray,
    cam_x_m: FloatArray, cam_y_m: FloatArray, *, max_gap_s: float, crs: str, projected: bool,
    cam_grade: Sequence[str] | None = None, origin: tuple[float, float] | None = None,
) -> str:
    """Trajectory coloured by quality with the camera positions (outlined in their grade's
    colour when ``cam_grade`` is given), in the output CRS; in metres from ``origin`` (the
    base, drawn as a triangle where it falls in the frame) when it is given."""
    if origin is not None:
        x_m, y_m = x_m - origin[0], y_m - origin[1]
        cam_x_m, cam_y_m = cam_x_m - origin[0], cam_y_m - origin[1]
    ok = np.isfinite(x_m) & np.isfinite(y_m)
    cam_ok = np.isfinite(cam_x_m) & np.isfinite(cam_y_m)
    xs = np.concatenate([x_m[ok], cam_x_m[cam_ok]])
    ys = np.concatenate([y_m[ok], cam_y_m[cam_ok]])
    with matplotlib.rc_context(_RC):
        if xs.size == 0:
            fig, ax = plt.subplots(figsize=(WIDTH_IN, 2.0))
            ax.text(0.5, 0.5, "no positions", ha="center", va="center", transform=ax.transAxes)
            return to_svg(fig, "trajectory")
        dx = max(float(np.ptp(xs)), 1e-9)
        dy = max(float(np.ptp(ys)), 1e-9)
        # The frame follows the flight's shape within limits; equal scale on both axes.
        height = min(max(WIDTH_IN * dy / dx, 4.0), 6.6) + 0.9  # fits a 768 px screen
        fig, ax = plt.subplots(figsize=(WIDTH_IN, height), layout="constrained")
        seg_ok = ok[1:] & ok[:-1] & (np.diff(t_gps_ns) <= max_gap_s * 1e9)
        lines, cols = _track_lines(np.column_stack([x_m, y_m]), quality, seg_ok)
        ax.add_collection(LineCollection(lines, colors=cols, linewidths=1.4, zorder=2,
                                         joinstyle="round", capstyle="butt"))
        lone = ok & ~np.concatenate([seg_ok, [False]]) & ~np.concatenate([[False], seg_ok])
        if lone.any():
            ax.scatter(x_m[lone], y_m[lone], s=4,
                       c=[QUALITY_COLOURS.get(int(q), "#7f7f7f") for q in quality[lone]],
                       zorder=2)
        edge: list[str] | str = "black"
        if cam_grade is not None:
            edge = [GRADE_COLOURS.get(g, "#7f7f7f")
                    for g, k in zip(cam_grade, cam_ok.tolist(), strict=True) if k]
        ax.scatter(cam_x_m[cam_ok], cam_y_m[cam_ok], s=14, facecolors="none",
                   edgecolors=edge, linewidths=0.9, zorder=3)
        ax.set_aspect("equal", adjustable="datalim")
        ax.autoscale_view()
        ax.apply_aspect()  # the final limits, which the scale bar and the corners depend on
        ax.ticklabel_format(useOffset=False, style="plain")
        if origin is not None:
            # an artist outside the data limits: the frame stays the flight's, a base far
            # off is not drawn
            ax.add_artist(Line2D([0.0], [0.0], ls="", marker="^", ms=8, mfc="white",
                                 mec="black", mew=1.2, zorder=4))
            if _inside(ax, 0.0, 0.0):
                ax.annotate("base", (0.0, 0.0), xytext=(6, -4), textcoords="offset points",
                            fontsize=8, va="top", zorder=4,
                            bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8,
                                  "pad": 0.5})
            ax.set_xlabel("Easting from the base (m)" if projected
                          else "Longitude from the base (deg)")
            ax.set_ylabel("Northing from the base (m)" if projected
                          else "Latitude from the base (deg)")
        else:
            ax.set_xlabel("Easting (m)" if projected else "Longitude (deg)")
            ax.set_ylabel("Northing (m)" if projected else "Latitude (deg)")
        ax.set_title(crs, fontsize=9, loc="left")
        ax.tick_params(labelsize=9)
        ax.tick_params(axis="y", labelrotation=90)
        for lab in ax.get_yticklabels():
            lab.set_verticalalignment("center")
        present = sorted(set(quality[ok].tolist()))
        handles: list[Line2D | Patch] = [
            Line2D([], [], color=QUALITY_COLOURS.get(q, "#7f7f7f"), lw=2,
                   label=QUALITY_NAMES.get(q, str(q))) for q in present
        ]
        if cam_grade is None:
            handles.append(Line2D([], [], ls="", marker="o", mfc="none", mec="black",
                                  label="camera positions"))
        else:
            for g in [g for g in GRADE_COLOURS if g in set(cam_grade)]:
                handles.append(Line2D([], [], ls="", marker="o", mfc="none",
                                      mec=GRADE_COLOURS[g], label=f"camera: {g}"))
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.0, -0.09 * 4.9 / height),
                  ncols=len(handles), frameon=False)
        corners = _free_corners(ax, xs, ys)
        if projected:
            _scale_bar(ax, corners[0])
        _north_arrow(ax, projected, corners[1])
        return to_svg(fig, "trajectory")


def _inside(ax: Axes, x: float, y: float) -> bool:
    """The point falls within the axes' limits."""
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    return x0 <= x <= x1 and y0 <= y <= y1


_CORNERS = {"ll": (0.04, 0.05), "lr": (0.76, 0.05), "ul": (0.04, 0.83), "ur": (0.76, 0.83)}
"""Lower-left anchor (axes fraction) of each corner box where the decorations may go."""


def _free_corners(ax: Axes, xs: FloatArray, ys: FloatArray) -> list[str]:
    """Corners ordered by how few trajectory points fall in them (decorations go there)."""
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    fx = (xs - x0) / (x1 - x0)
    fy = (ys - y0) / (y1 - y0)

    def load(c: str) -> int:
        ax0, ay0 = _CORNERS[c]
        return int(np.sum((fx >= ax0 - 0.03) & (fx <= ax0 + 0.23) & (fy >= ay0 - 0.04)
                          & (fy <= ay0 + 0.16)))

    return sorted(_CORNERS, key=lambda c: (load(c), c))


def _scale_bar(ax: Axes, corner: str) -> None:
    x0, x1 = ax.get_xlim()
    length = _nice((x1 - x0) / 5.0)
    fx, fy = _CORNERS[corner]
    bx = x0 + fx * (x1 - x0)
    tr = ax.get_xaxis_transform()  # x in metres, y in axes fraction: the box keeps its height
    ax.add_patch(Rectangle((bx - 0.015 * (x1 - x0), fy), length + 0.03 * (x1 - x0), 0.075,
                           transform=tr, facecolor="white", edgecolor="#999", alpha=0.9,
                           zorder=4))
    ax.plot([bx, bx + length], [fy + 0.022, fy + 0.022], transform=tr, color="black", lw=3,
            solid_capstyle="butt", zorder=5)
    ax.text(bx + length / 2, fy + 0.035, f"{length:g} m", transform=tr, ha="center",
            va="bottom", fontsize=8, zorder=5)


def _north_arrow(ax: Axes, projected: bool, corner: str) -> None:
    fx, fy = _CORNERS[corner]
    x = fx + 0.19 if corner.endswith("r") else fx + 0.02
    ax.annotate("", xy=(x, fy + 0.10), xytext=(x, fy), xycoords="axes fraction",
                arrowprops={"arrowstyle": "-|>", "color": "black", "lw": 1.5}, zorder=5)
    ax.text(x, fy + 0.11, "N (grid)" if projected else "N", transform=ax.transAxes,
            ha="center", va="bottom", fontsize=8, fontweight="bold", zorder=5,
            bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1})


def _runs(values: IntArray) -> list[tuple[int, int]]:
    """(start, end) index pairs of runs of equal values (end exclusive)."""
    if values.size == 0:
        return []
    cut = np.flatnonzero(np.diff(values) != 0) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [values.size]])
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def quality_timeline(
    t_gps_ns: IntArray, quality: IntArray, *, max_gap_s: float, radio_gaps: Sequence[Span],
    outages: Sequence[Span], mark_t_gps_ns: IntArray, events_recorded: bool = True,
    mark_grade: Sequence[str] | None = None,
) -> str:
    """Solution quality per epoch, solution gaps, radio gaps, source outages and the marks
    (in their grade's colour when ``mark_grade`` is given)."""
    with matplotlib.rc_context(_RC):
        fig, ax = plt.subplots(figsize=(WIDTH_IN, 2.9), layout="constrained")
        if t_gps_ns.size == 0:
            return to_svg(fig, "quality")
        d = _dates(t_gps_ns)
        step = float(np.median(np.diff(d))) if d.size > 1 else 1 / 86400
        rows = {"marks": 3, "solution": 2, "radio gaps": 1, "source outages": 0}
        # A new run also starts after a gap, so that a gap is never painted over.
        gap_after = np.concatenate([np.diff(t_gps_ns) > max_gap_s * 1e9, [False]])
        key = quality * 2 + np.cumsum(np.concatenate([[0], gap_after[:-1]])) * 16
        for a, b in _runs(key.astype(np.int64)):
            q = int(quality[a])
            ax.broken_barh([(d[a], d[b - 1] - d[a] + step)], (rows["solution"] - 0.35, 0.7),
                           color=QUALITY_COLOURS.get(q, "#7f7f7f"), linewidth=0)
        for i in np.flatnonzero(gap_after).tolist():
            ax.broken_barh([(d[i] + step, d[i + 1] - d[i] - step)],
                           (rows["solution"] - 0.35, 0.7), facecolor="white",
                           edgecolor="black", hatch="////", linewidth=0.5)
        for sp, row, colour in (*((s, "radio gaps", "black") for s in radio_gaps),
                                *((s, "source outages", "#6a1b9a") for s in outages)):
            a, b = _dates([sp.start_gps_ns, sp.end_gps_ns])
            ax.broken_barh([(a, max(b - a, step))], (rows[row] - 0.35, 0.7), color=colour)
        if not events_recorded:
            for row in ("radio gaps", "source outages"):
                ax.text(0.5, rows[row], "not recorded in this file (plain UBX, not a station "
                        "session)", transform=ax.get_yaxis_transform(), ha="center",
                        va="center", fontsize=8, color="#666")
        has_t = mark_t_gps_ns >= 0
        md = _dates(mark_t_gps_ns[has_t])
        colours: list[str] | str = "#333"
        if mark_grade is not None:
            colours = [GRADE_COLOURS.get(g, "#7f7f7f")
                       for g, k in zip(mark_grade, has_t.tolist(), strict=True) if k]
        ax.vlines(md, rows["marks"] - 0.35, rows["marks"] + 0.35, color=colours, lw=0.6)
        ax.set_yticks(list(rows.values()), list(rows))
        ax.set_ylim(-0.6, 3.6)
        ax.grid(axis="y", visible=False)
        _time_axes(ax, int(t_gps_ns[0]))
        present = sorted(set(quality.tolist()))
        handles: list[Line2D | Patch] = [
            Patch(color=QUALITY_COLOURS.get(q, "#7f7f7f"), label=QUALITY_NAMES.get(q, str(q)))
            for q in present]
        handles.append(Patch(facecolor="white", edgecolor="black", hatch="////",
                             label=f"no epoch for > {max_gap_s:g} s"))
        if mark_grade is not None:
            handles += [Line2D([], [], color=GRADE_COLOURS[g], lw=2, label=f"mark: {g}")
                        for g in GRADE_COLOURS if g in set(mark_grade)]
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
        return to_svg(fig, "quality")


def satellites(
    sat: Sequence[str], t_gps_ns: IntArray, cno_dbhz: FloatArray, slip: npt.NDArray[np.bool_],
    half: npt.NDArray[np.bool_], repaired: npt.NDArray[np.bool_] | None = None,
) -> str:
    """One row per satellite: C/N0 over time, cycle slips, unresolved half cycles, repairs."""
    names = sorted(set(sat), key=lambda s: (s[0], int(s[1:]) if s[1:].isdigit() else 0))
    row = {s: i for i, s in enumerate(names)}
    y = np.array([row[s] for s in sat], dtype=np.float64)
    with matplotlib.rc_context(_RC):
        height = 1.3 + 0.16 * max(len(names), 4)
        fig, ax = plt.subplots(figsize=(WIDTH_IN, height), layout="constrained")
        if t_gps_ns.size == 0:
            ax.text(0.5, 0.5, "no raw measurements in the recording", ha="center",
                    va="center", transform=ax.transAxes)
            return to_svg(fig, "satellites")
        d = _dates(t_gps_ns)
        sc = ax.scatter(d, y, c=cno_dbhz, cmap="viridis", vmin=20, vmax=50, s=3, marker="s",
                        linewidths=0, rasterized=True)
        if half.any():
            ax.scatter(d[half], y[half] + 0.3, s=2, c="#f39c12", marker="s", linewidths=0,
                       rasterized=True)
        if slip.any():
            ax.scatter(d[slip], y[slip], s=16, marker="|", c="#d73027", linewidths=0.8)
        if repaired is not None and repaired.any():
            ax.scatter(d[repaired], y[repaired], s=18, marker="x", c="#1f77b4", linewidths=1.0)
        ax.set_yticks(range(len(names)), names, fontsize=7 if len(names) > 20 else 8)
        ax.set_ylim(-0.7, len(names) - 0.3)
        ax.invert_yaxis()
        ax.grid(axis="y", visible=False)
        _time_axes(ax, int(t_gps_ns.min()))
        cb = fig.colorbar(sc, ax=ax, pad=0.01, fraction=0.04)
        cb.set_label("C/N0 (dB-Hz)")
        handles = [
            Line2D([], [], ls="", marker="|", color="#d73027", ms=8, mew=1.2,
                   label=f"cycle slip ({int(slip.sum())})"),
            Line2D([], [], ls="", marker="s", color="#f39c12", ms=4,
                   label="half cycle unresolved"),
        ]
        if repaired is not None:
            handles.append(Line2D([], [], ls="", marker="x", color="#1f77b4", ms=5,
                                  label=f"repaired ({int(repaired.sum())})"))
        fig.legend(handles=handles, loc="outside lower left", ncols=3, frameon=False)
        return to_svg(fig, "satellites")


def sigmas(t_gps_ns: IntArray, sd_enu_m: FloatArray, quality: IntArray) -> str:
    """σ east/north/up at the camera positions over time (log scale), quality below."""
    ok = np.isfinite(sd_enu_m).all(axis=1) & (t_gps_ns >= 0)
    with matplotlib.rc_context(_RC):
        fig, ax = plt.subplots(figsize=(WIDTH_IN, 2.8), layout="constrained")
        if not ok.any():
            ax.text(0.5, 0.5, "no standard deviations", ha="center", va="center",
                    transform=ax.transAxes)
            return to_svg(fig, "sigmas")
        d = _dates(t_gps_ns[ok])
        for j, (label, colour, marker) in enumerate(
            (("σ east", "#1f77b4", "o"), ("σ north", "#2ca02c", "s"), ("σ up", "#9467bd", "^"))
        ):
            ax.scatter(d, sd_enu_m[ok, j], s=9, marker=marker, facecolors="none",
                       edgecolors=colour, linewidths=0.7, label=label)
        bad = ok & (quality != 1)
        if bad.any():
            ax.scatter(_dates(t_gps_ns[bad]), np.nanmax(sd_enu_m[bad], axis=1), s=40,
                       facecolors="none", edgecolors="#d73027", linewidths=1.0,
                       label="not fixed")
        vals = sd_enu_m[ok]
        if float(vals.max()) > 20 * max(float(vals.min()), 1e-4):
            # Fixed (cm) and float/single (dm-m) together: a log axis shows both.
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
            ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _pos: ""))
            ax.set_ylabel("standard deviation (m, log scale)")
        else:
            ax.set_ylim(0.0, float(vals.max()) * 1.15)
            ax.set_ylabel("standard deviation (m)")
        _time_axes(ax, int(t_gps_ns[ok].min()))
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
        return to_svg(fig, "sigmas")


def timing_residuals(
    t_gps_ns: IntArray, residual_s: FloatArray, window_s: float, sigma_s: float
) -> str:
    """Photo-to-mark residuals (after the camera clock offset) over time, in milliseconds."""
    with matplotlib.rc_context(_RC):
        fig, ax = plt.subplots(figsize=(WIDTH_IN, 2.6), layout="constrained")
        if t_gps_ns.size == 0:
            return to_svg(fig, "timing")
        d = _dates(t_gps_ns)
        ax.scatter(d, residual_s * 1e3, s=8, color="#225ea8", linewidths=0, label="photo")
        ax.axhline(0.0, color="#555", lw=0.8)
        if math.isfinite(window_s):
            for v in (-window_s, window_s):
                ax.axhline(v * 1e3, color="#d73027", lw=0.8, ls="--")
        ax.set_ylabel("mark − photo (ms)")
        ax.set_title(f"pairing window ±{window_s * 1e3:.0f} ms (dashed), residual σ "
                     f"{sigma_s * 1e3:.0f} ms", fontsize=8, loc="left")
        _time_axes(ax, int(t_gps_ns.min()))
        return to_svg(fig, "timing")


def lever_residuals(residual_m: FloatArray, outlier: npt.NDArray[np.bool_]) -> str:
    """Lever-arm residual per image with exterior orientation (outliers red)."""
    with matplotlib.rc_context(_RC):
        fig, ax = plt.subplots(figsize=(WIDTH_IN, 2.4), layout="constrained")
        i = np.arange(residual_m.size)
        ax.scatter(i[~outlier], residual_m[~outlier], s=10, color="#225ea8", label="image")
        if outlier.any():
            ax.scatter(i[outlier], residual_m[outlier], s=14, color="#d73027", label="outlier")
        ax.set_xlabel("image (order of the EO file)")
        ax.set_ylabel("residual (m)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
        return to_svg(fig, "lever")
