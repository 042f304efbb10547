"""``report.html``: a self-contained page with inline SVG plots of a solve (no scripts, no CDN)."""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from groundstation.solve.positions import QUALITY_NAMES

FloatArray = npt.NDArray[np.float64]

QUALITY_COLOURS = {1: "#1a9850", 2: "#fdae61", 3: "#74add1", 4: "#4575b4", 5: "#d73027",
                   6: "#8073ac"}
W, H, PAD = 720, 420, 40


@dataclass(frozen=True, slots=True)
class ReportData:
    """What the report shows; every array may be empty."""

    title: str
    summary: Sequence[tuple[str, str]]
    track_en_m: FloatArray  # (n, 2) east, north of every epoch (local or projected)
    track_quality: npt.NDArray[np.int64]
    track_t_s: FloatArray  # seconds from the first epoch
    marks_en_m: FloatArray  # (m, 2) camera positions
    gaps: Sequence[tuple[float, float]]  # (start s, length s) of data gaps
    match_residual_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    match_t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    lever_residual_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    lever_outlier: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    notes: Sequence[str] = ()
    reconciliation: Sequence[str] = ()


def _scale(vals: FloatArray, lo_px: float, hi_px: float) -> tuple[float, float]:
    finite = vals[np.isfinite(vals)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = float(finite.min()), float(finite.max())
    if hi - lo < 1e-9:
        lo, hi = lo - 1.0, hi + 1.0
    k = (hi_px - lo_px) / (hi - lo)
    return lo, k


def _svg(body: str, title: str) -> str:
    return (
        f'<figure><svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" '
        f'viewBox="0 0 {W} {H}" role="img" aria-label="{html.escape(title)}">'
        f'<rect width="{W}" height="{H}" fill="#fff" stroke="#ccc"/>{body}</svg>'
        f"<figcaption>{html.escape(title)}</figcaption></figure>"
    )


def track_svg(d: ReportData) -> str:
    """Map of the trajectory, coloured by fix status, with the camera positions."""
    en = d.track_en_m
    if en.shape[0] < 2:
        return "<p>No trajectory.</p>"
    allpts = np.vstack([en, d.marks_en_m]) if d.marks_en_m.size else en
    ex0, kx = _scale(allpts[:, 0], PAD, W - PAD)
    ny0, ky = _scale(allpts[:, 1], PAD, H - PAD)
    k = min(kx, ky)

    def px(e: float, n: float) -> tuple[float, float]:
        return PAD + (e - ex0) * k, H - PAD - (n - ny0) * k

    parts = []
    for i in range(1, en.shape[0]):
        if not (np.all(np.isfinite(en[i - 1])) and np.all(np.isfinite(en[i]))):
            continue
        x1, y1 = px(*en[i - 1])
        x2, y2 = px(*en[i])
        c = QUALITY_COLOURS.get(int(d.track_quality[i]), "#999")
        parts.append(f'<line x1="{x1:.1f}" y1="{y1:.1f}" x2="{x2:.1f}" y2="{y2:.1f}" '
                     f'stroke="{c}" stroke-width="1.5"/>')
    for e, n in d.marks_en_m.tolist():
        if math.isfinite(e) and math.isfinite(n):
            x, y = px(e, n)
            parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="2.2" fill="none" stroke="#000"/>')
    legend = "".join(
        f'<rect x="{PAD + 80 * i}" y="8" width="10" height="10" fill="{c}"/>'
        f'<text x="{PAD + 14 + 80 * i}" y="17" font-size="11">{QUALITY_NAMES.get(q, q)}</text>'
        for i, (q, c) in enumerate(QUALITY_COLOURS.items())
    )
    scale_m = 10 ** math.floor(math.log10(max((W - 2 * PAD) / k / 4, 1e-3)))
    bar = (f'<line x1="{PAD}" y1="{H - 12}" x2="{PAD + scale_m * k:.1f}" y2="{H - 12}" '
           f'stroke="#000" stroke-width="2"/><text x="{PAD + scale_m * k + 6:.1f}" '
           f'y="{H - 8}" font-size="11">{scale_m:g} m</text>')
    return _svg("".join(parts) + legend + bar,
                "Trajectory coloured by fix status (circles: camera positions)")


def _series_svg(
    t: FloatArray, v: FloatArray, title: str, unit: str, red: npt.NDArray[np.bool_] | None = None
) -> str:
    if t.size == 0:
        return ""
    t0, kt = _scale(t, PAD, W - PAD)
    vv = np.append(v, 0.0)
    v0, kv = _scale(vv, PAD, H - PAD)
    parts = []
    y0 = H - PAD - (0.0 - v0) * kv
    parts.append(f'<line x1="{PAD}" y1="{y0:.1f}" x2="{W - PAD}" y2="{y0:.1f}" stroke="#aaa"/>')
    for i, (a, b) in enumerate(zip(t.tolist(), v.tolist(), strict=True)):
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        c = "#d73027" if red is not None and red[i] else "#225ea8"
        parts.append(f'<circle cx="{PAD + (a - t0) * kt:.1f}" '
                     f'cy="{H - PAD - (b - v0) * kv:.1f}" r="2" fill="{c}"/>')
    lo, hi = float(np.nanmin(vv)), float(np.nanmax(vv))
    parts.append(f'<text x="4" y="{PAD}" font-size="11">{hi:.3g} {unit}</text>')
    parts.append(f'<text x="4" y="{H - PAD}" font-size="11">{lo:.3g} {unit}</text>')
    return _svg("".join(parts), title)


def gaps_svg(d: ReportData) -> str:
    """Timeline of the solution: fix status per epoch and the data gaps."""
    if d.track_t_s.size < 2:
        return ""
    t0, kt = _scale(d.track_t_s, PAD, W - PAD)
    parts = []
    for t, q in zip(d.track_t_s.tolist(), d.track_quality.tolist(), strict=True):
        x = PAD + (t - t0) * kt
        parts.append(f'<line x1="{x:.1f}" y1="{H / 2 - 30}" x2="{x:.1f}" y2="{H / 2 + 30}" '
                     f'stroke="{QUALITY_COLOURS.get(int(q), "#999")}"/>')
    for start, length in d.gaps:
        x = PAD + (start - t0) * kt
        wd = max(length * kt, 1.5)
        parts.append(f'<rect x="{x:.1f}" y="{H / 2 + 40}" width="{wd:.1f}" height="20" '
                     f'fill="#000"/>')
    span = float(d.track_t_s[-1] - d.track_t_s[0])
    parts.append(f'<text x="{PAD}" y="{H - 10}" font-size="11">0 s</text>'
                 f'<text x="{W - PAD - 40}" y="{H - 10}" font-size="11">{span:.0f} s</text>')
    return _svg("".join(parts),
                f"Fix status per epoch (top) and data gaps (black, {len(d.gaps)} gaps)")


def render(d: ReportData) -> str:
    """The whole page."""
    rows = "".join(
        f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in d.summary
    )
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in d.notes)
    recon = html.escape("\n".join(d.reconciliation))
    plots = [track_svg(d), gaps_svg(d)]
    if d.match_residual_s.size:
        plots.append(_series_svg(d.match_t_s, d.match_residual_s,
                                 "Photo-to-mark residuals after the clock offset", "s"))
    if d.lever_residual_m.size:
        plots.append(_series_svg(np.arange(d.lever_residual_m.size, dtype=float),
                                 d.lever_residual_m,
                                 "Lever-arm residual per image (red: outlier)", "m",
                                 d.lever_outlier))
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{html.escape(d.title)}</title><style>body{{font-family:sans-serif;"
        "max-width:760px;margin:1em auto}}th{{text-align:left;padding-right:1em}}"
        "pre{{background:#f6f6f6;padding:.5em;overflow:auto;max-height:20em}}</style></head>"
        f"<body><h1>{html.escape(d.title)}</h1><table>{rows}</table>"
        f"<ul>{notes}</ul>{''.join(plots)}"
        f"<h2>Photo reconciliation</h2><pre>{recon or 'no photos'}</pre></body></html>\n"
    )
