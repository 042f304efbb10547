"""The flight report: ``report.html`` (self-contained, printable) and ``report.pdf`` beside it.

The page is rendered from one :class:`~groundstation.solve.report_data.ReportInput` alone (the
pipeline fills it from the solve's results; the counts, warnings and texts derived from it are
:mod:`groundstation.solve.report_data`), so the counts and the per-mark table agree with the
exports by construction; nothing here reads a recording or any other file. Figures come from
:mod:`groundstation.solve.figures` as inline SVG; the page has no scripts and fetches nothing.

One rendering path: the PDF is the same HTML printed by headless Chromium
(:mod:`groundstation.solve.pdf`), so the paper copy is exactly the page. Without Chromium,
``report.pdf`` is not written and the solve says so (print ``report.html`` from any browser
instead).
"""

from __future__ import annotations

import hashlib
import html
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from groundstation import gpstime
from groundstation.solve import clockoffset
from groundstation.solve.base import PCO_APPLIED
from groundstation.solve.integrity.grade import CHECK_TEXT, GRADE_MEANING
from groundstation.solve.interpolate import flag_names
from groundstation.solve.outputs import mark_numbers_text
from groundstation.solve.palette import QUALITY_COLOURS
from groundstation.solve.pdf import find_chromium, print_pdf
from groundstation.solve.report_data import (
    QUALITY_KEYS,
    ReportInput,
    accuracy_text,
    counts,
    gps_text,
    grades_text,
    lost_marks_text,
    nearest_epoch_s,
    not_counted_text,
    utc_text,
    warnings,
)
from groundstation.solve.trajectory import Q_FIX, Q_FLOAT, Q_SINGLE, QUALITY_NAMES

LEVER_ARM_CONVENTION = (
    "The lever arm L = (x, y, z) is given in the camera frame, from the projection centre to the "
    "antenna phase centre: x along the image x axis (right), y along the image y axis (up), z "
    "along the camera axis away from the scene (up for a nadir camera). With the rotation "
    "M = R(kappa) R(phi) R(omega) from object to image (omega, phi, kappa in the output CRS), "
    "camera = antenna - M^T L. Example: a nadir camera 0.57 m below the antenna has z = +0.57."
)


def _num(v: float, nd: int) -> str:
    return f"{v:.{nd}f}" if math.isfinite(v) else ""



# -- HTML -------------------------------------------------------------------------------------

_CSS = """
:root{--fix:#1a9850;--float:#f39c12;--single:#d73027}
body{font-family:"DejaVu Sans","Liberation Sans",Arial,sans-serif;font-size:14px;color:#111;
max-width:1080px;margin:1em auto;padding:0 1em;line-height:1.35}
h1{font-size:1.5em;margin:.2em 0}h2{font-size:1.2em;border-bottom:1px solid #999;margin-top:1.4em}
h3{font-size:1em;margin:1em 0 .3em}
table{border-collapse:collapse}
table.kv th{text-align:left;vertical-align:top;padding:2px 1em 2px 0;font-weight:600;
white-space:nowrap}
table.kv td{padding:2px 0}
.cols{display:flex;gap:2em;flex-wrap:wrap}.cols>div{flex:1 1 320px}
table.counts td,table.counts th{padding:2px .6em;border-bottom:1px solid #ddd;text-align:right}
table.counts th{text-align:left;font-weight:normal}
table.marks{font-size:12px;width:100%}
table.marks th,table.marks td{padding:1px 5px;border-bottom:1px solid #e3e3e3;white-space:nowrap}
table.marks th{background:#eee;position:sticky;top:0;text-align:left}
table.marks td.n{text-align:right;font-variant-numeric:tabular-nums}
table.marks td.w{white-space:normal;min-width:7em}
tr.q-float td{background:#fff3df}tr.q-single td,tr.q-none td{background:#fde2e0}
.q{display:inline-block;width:.8em;height:.8em;border-radius:50%;vertical-align:-1px;
margin-right:3px}
ul.warn li{margin:.2em 0}ul.warn{border-left:4px solid #d73027;padding:.3em 1em .3em 1.8em;
background:#fff6f5}
p.ok{border-left:4px solid #1a9850;padding:.3em 1em;background:#f3fbf5}
figure{margin:1em 0;break-inside:avoid}figcaption{font-size:.9em;color:#333;margin-top:.2em}
svg.fig{width:100%;max-width:900px;height:auto;display:block}
svg.fig[aria-label=trajectory]{width:auto;max-height:92vh}
table.counts{width:100%}
.opts{columns:3 15em;font-size:12px;margin:.3em 0}code,pre{font-size:12px}
caption{text-align:left}
pre{background:#f6f6f6;padding:.5em;white-space:pre-wrap}
.muted{color:#666}
table.result th{font-size:1.05em}table.result td{font-size:1.05em}.big{font-size:1.3em}
@page{size:A4;margin:12mm 10mm}
@media print{body{max-width:none;margin:0;padding:0;font-size:10pt}
 table.marks{font-size:7.5pt}table.marks th{position:static}
 h2{break-after:avoid}section.figs h3{break-after:avoid}
 .opts,code{font-size:7.5pt}
 tr{break-inside:avoid}thead{display:table-header-group}
 section.positions{break-before:page}}
"""


def _e(s: object) -> str:
    return html.escape(str(s))


def _kv(rows: Sequence[tuple[str, str]], cls: str = "kv") -> str:
    body = "".join(f"<tr><th>{_e(k)}</th><td>{v}</td></tr>" for k, v in rows)
    return f'<table class="{cls}">{body}</table>'


def _quality_dot(q: int) -> str:
    return (f'<span class="q" style="background:{QUALITY_COLOURS.get(q, "#7f7f7f")}"></span>'
            f"{_e(QUALITY_NAMES.get(q, str(q)))}")


def _summary(inp: ReportInput) -> str:
    t = inp.track_t_gps_ns
    span = ""
    if t.size:
        dur = (int(t[-1]) - int(t[0])) / 1e9
        span = (f"{_e(utc_text(int(t[0]), 0))} – {_e(utc_text(int(t[-1]), 0))} UTC "
                f"({dur / 60:.1f} min)<br>GPS week/seconds {_e(gps_text(int(t[0]), 1))} – "
                f"{_e(gps_text(int(t[-1]), 1))} (GPS − UTC = "
                f"{gpstime.leap_seconds_at_gps(int(t[0]))} s)")
    if inp.base_ecef_m is not None:
        from groundstation.geodesy import ecef_to_llh

        la, lo, h = ecef_to_llh(*inp.base_ecef_m)
        name = f"{_e(inp.base_name)}<br>" if inp.base_name else ""
        base = (f"{name}ECEF X {inp.base_ecef_m[0]:.4f}, "
                f"Y {inp.base_ecef_m[1]:.4f}, Z {inp.base_ecef_m[2]:.4f} m<br>"
                f"lat {la:.9f}°, lon {lo:.9f}°, h {h:.3f} m (WGS84)<br>"
                f"checked: {_e(inp.base_check)}<br>σ east/north/up " + _e(
                    "/".join(f"{v:.3f}" for v in inp.base_sd_enu_m) + " m: in the cameras' "
                    "absolute sigmas (cameras.csv abs_sd_*); the photogrammetry exports carry "
                    "the relative sigmas, which a bundle adjustment should weight the cameras by "
                    "(the base's error shifts the whole block alike)"
                    if inp.base_sd_enu_m is not None else
                    "not given: the base is taken as exact (--base-sigma gives it)"))
        if PCO_APPLIED not in inp.base_check:
            base += ("<br>antenna: no phase-centre offset applied (no --antex): the position "
                     "given is taken as the antenna's L1 phase centre")
        if inp.base_before:  # solve --rebase: the bases before, oldest (the engine's) first
            base += "<br>re-based (solve --rebase); solved with " + _e(inp.base_before[0]) + (
                "".join(f"<br>then re-based to {_e(b)}" for b in inp.base_before[1:]))
    else:
        base = _e(inp.base_check or "none")
    opts = ""
    if inp.engine_options:
        opts = (f'<br><span class="muted">its {len(inp.engine_options)} options: '
                '<a href="#engine-options">Engine options</a>, at the end</span>')
    lever = (", ".join(f"{v:+.3f}" for v in inp.lever_arm_m) + " m (x, y, z)"
             if inp.lever_arm_m is not None else "not applied")
    rows = [
        ("Flight", _e(inp.flight)),
        ("Span", span or "no epochs"),
        ("Positions", _e(inp.position_source)),
        ("Engine", f"{_e(inp.engine_name)} {_e(inp.engine_version or '(version not recorded)')}"
         + opts),
        ("Base station", base),
        ("Output CRS", f"EPSG:{inp.epsg} {_e(inp.crs_name)}" + _coordinate_epoch(inp)),
        ("Heights", _e(inp.height_datum)),
        ("Lever arm", _e(lever) + f'<br><span class="muted">{_e(LEVER_ARM_CONVENTION)}</span>'),
        ("Shutter", (f"{inp.shutter_delay_ms:g} ms after the {_e(inp.edge)} edge of the camera "
                    "pulse")),
        ("Interpolation", f"{_e(inp.interp)}; gaps longer than {inp.max_gap_s:g} s are flagged"),
    ]
    if inp.clock_offset_s is not None:
        sigma = clockoffset.residual_sigma_text(clockoffset.residual_sigma_s(inp.pair_residual_s))
        clock = (f"GPS − camera {inp.clock_offset_s:+.3f} s = {inp.clock_leap_s} s leap seconds "
                 f"(GPS − UTC) {inp.clock_offset_s - inp.clock_leap_s:+.3f} s (UTC − camera)")
        rows.append(("Camera clock", (f"{clock}; pairing window "
                     f"±{(inp.pair_window_s or 0) * 1e3:.0f} ms; timing residual σ {sigma}")))
    return _kv(rows)


def _coordinate_epoch(inp: ReportInput) -> str:
    """The epoch the coordinates hold at: the flight's, as a decimal year (plates move
    centimetres a year, so a frame's coordinates name their epoch)."""
    if inp.track_t_gps_ns.size == 0:
        return ""
    when = gpstime.gps_to_datetime(int(np.median(inp.track_t_gps_ns)))
    start = when.replace(month=1, day=1, hour=0, minute=0, second=0, microsecond=0)
    year = when.year + (when - start) / (start.replace(year=when.year + 1) - start)
    return (f'<br><span class="muted">coordinate epoch {year:.2f} (the flight\'s): the '
            "cameras are in the frame of the base's coordinates at that epoch</span>")


def _result(inp: ReportInput) -> str:
    """What a surveyor looks for first: fixed share, marks positioned and missed, accuracy."""
    c = counts(inp)
    # The share is over the positions computed: a photo without a mark has no position to fix
    # (it has its own line below), and counting it would pull a fully fixed flight down.
    n_pos = c["rows"] - c["not_positioned"]
    fixed = c["fixed"]
    share = f" ({fixed / n_pos:.0%})" if n_pos else ""
    marks = [r for r in inp.rows if r.mark >= 0]
    positioned = sum(1 for r in marks if r.positioned)
    missed = c["marks_missed"]
    missed_text = ("none" if not missed else
                   f"{missed}: {c['marks_lost_on_link']} lost on the radio link, "
                   f"{c['marks_not_reported']} not reported by the receiver")
    unmatched = c["photos_unmatched"]
    lines = [
        ("Fixed", (f'<b class="big">{fixed} of {n_pos}</b> computed camera positions '
                   f"fixed and checked{share}")),
        ("Grades", _e(grades_text(inp.rows))),
        ("Marks positioned", f"<b>{positioned} of {len(marks)}</b> marks in the flight"
         + (f"; {c['not_positioned']} camera position(s) not computed"
            if c["not_positioned"] else "")),
        ("Missed marks", _e(missed_text)),
    ]
    if inp.photos_given:
        timed = c["photos_by_camera_clock"]
        lines.append(("Photos without a mark", (
            f"{unmatched} ({timed} positioned by the camera clock)" if timed else str(unmatched))
            if unmatched else "none"))
    lines.append(("Accuracy", _e(accuracy_text(inp))))
    return _kv(lines, "kv result")


INTEGRITY_TEXT = (
    "A camera position is called fixed only when its integer carrier-phase solution passed a "
    "check that does not rest on the engine's ratio test: our own solution over whole arcs of "
    "phase (every arc's ambiguity from the whole flight, integer combinations fixed only when "
    "sure to 5 sigma, at least six satellites on fixed ambiguities and their residuals "
    "passing a chi-square test), or the engine's forward and backward runs agreeing (both "
    "fixed within their covariances, or one fixed and the other's float agreeing within its "
    "calibrated covariance). A fix that fails is demoted to float. Every sigma is meant to "
    "cover the error (|error| <= 3 sigma for 99 % of camera positions): float sigmas are the "
    "engine's multiplied by a factor measured on this flight's own checked fixes. A mark "
    "between two fixed epochs takes a smoother's sigma across the time between them (the "
    "default interpolation; never below the epochs' own), any other mark adds what a "
    "straight line may miss (a h^2/8). A position whose sigma is over 3.3 cm on any axis is "
    "not called fixed.")
"""The rule, as the report states it (docs/integrity.md has the details)."""


def _whole_arcs(arcs: dict[str, Any]) -> str:
    """On a half-cycle lattice: how many arcs were checked whole (no decision of the
    conditioning they rest on left untested: their pairs on whole cycles), or nothing."""
    n = arcs.get("arcs_on_whole_cycles")
    if n is None:
        return ""
    return f", 1 cycle between the {n} arcs checked whole"


def _gap_splits(gaps: dict[str, Any]) -> str:
    """The radio gaps across which arcs were split, in words."""
    found = int(gaps.get("steps_found", 0))
    hidden = int(gaps.get("steps_could_hide", 0))
    if found + hidden == 0:
        return "every arc's continuity across the radio gaps checked"
    cut = int(gaps.get("arcs_split_where_steps_could_hide", 0))
    parts = [f"{n} {what}" for n, what in (
        (found, "with a step of several satellites at once: every arc split there"),
        (hidden, ("where such a step could have passed unseen: "
                  f"{cut} arc(s) whose continuity the others could not check split there")))
             if n]
    return (f"arcs split at {found + hidden} radio gap(s) ({'; '.join(parts)}): "
            "their phase is not carried across")


def _judged_again(arcs: dict[str, Any]) -> str:
    """The gaps judged again because the integers contradicted the model, in words ("" when
    they were judged once)."""
    n = int(arcs.get("gap_judgements", 1))
    if n <= 1:
        return ""
    left = int(arcs.get("contradictions", 0))
    return (f"; the radio gaps checked {n} times: the whole-cycle (integer) differences "
            "between satellites did not all fit, a sign of a slip a check had missed"
            + (f" ({left} misfit(s) left after the last)" if left else ""))


def _integrity(inp: ReportInput) -> str:
    """The integrity section: the rule, and what it found on this flight."""
    ig = inp.integrity
    head = f"<p>{_e(INTEGRITY_TEXT)}</p>"
    meaning = _kv([(name, _e(text)) for name, text in GRADE_MEANING.items()])
    if not ig:
        return (head + meaning + '<p class="muted">The integrity stage did not run for this '
                "solution (an imported .pos file, RINEX inputs or the receiver's own fix): "
                "fixes are graded fixed-unchecked.</p>")
    arcs = ig.get("arcs") or {}
    fac = ig.get("float_sigma_factor") or {}
    sm = arcs.get("smoothing") or {}
    steps = arcs.get("slips_found_as_steps", [])
    gaps = arcs.get("gaps_split") or {}
    rows = [
        ("Epochs", _e(", ".join(f"{k} {v}" for k, v in ig.get("grades", {}).items()))),
        ("Decided by (epochs)", _e(", ".join(f"{k} {v}" for k, v in ig.get("checks", {}).items()))),
        ("What the checks mean", _e("; ".join(f"{k}: {CHECK_TEXT[k]}" for k in ig.get("checks", {})
                                              if k in CHECK_TEXT))),
        ("Whole-arc solution", _e(
            f"{arcs.get('arcs')} arcs of GPS phase; {arcs.get('fixed_combinations')} of "
            f"{arcs.get('integer_combinations')} integer combinations fixed (lattice "
            f"{arcs.get('lattice_cycles')} cycle{_whole_arcs(arcs)}; stopped: "
            f"{arcs.get('stopped_by')}); "
            f"{arcs.get('epochs_fixed_precise')} epochs fixed by it; {len(steps)} slip(s) "
            f"nobody flagged found and split off; {_gap_splits(gaps)}"
            + _judged_again(arcs))),
        ("Smoothing", _e(
            f"jerk density {sm.get('jerk_density_h_m2_s5')} / {sm.get('jerk_density_v_m2_s5')} "
            f"m^2/s^5 horizontal / vertical (the most likely for the flight's quickest "
            f"20 s); {sm.get('epochs_left_unsmoothed')} epochs left unsmoothed where the "
            "model did not fit")),
        ("Float sigma factor", _e(
            f"{fac.get('horizontal')} horizontal, {fac.get('vertical')} vertical, from "
            f"{fac.get('from')}")),
    ]
    return head + _kv(rows) + meaning


def _options(inp: ReportInput) -> str:
    """The full option set the engine ran with (issue 13: in every output and the report)."""
    if not inp.engine_options:
        return ('<p class="muted">No option set recorded for this solution (an imported '
                "solution file or the receiver's own fix).</p>")
    return (f'<p class="muted">{_e(inp.engine_name)} '
            f"{_e(inp.engine_version or '(version not recorded)')}: the full option set it ran "
            f"with ({len(inp.engine_options)} options).</p>"
            '<div class="opts">'
            + "".join(f"<div><code>{_e(k)} = {_e(v)}</code></div>"
                      for k, v in inp.engine_options.items()) + "</div>")


def _counts_table(inp: ReportInput) -> str:
    c = counts(inp)

    def row(label: str, key: str, value: int | None = None) -> str:
        v = c[key] if value is None else value
        return f'<tr><th>{_e(label)}</th><td data-count="{key}">{v}</td></tr>'

    slips_found = "not available" if inp.slips_found is None else str(inp.slips_found)
    slips_rep = ("no conditioning ran" if inp.slips_repaired is None
                 else str(inp.slips_repaired))
    left = (
        '<table class="counts"><caption><b>Camera positions</b> (rows of cameras.csv)</caption>'
        + row("rows", "rows")
        + "".join(row(k, k) for k in QUALITY_KEYS.values()
                  if c[k] or k in ("fixed", "float", "single"))
        + row("not positioned", "not_positioned")
        + row("bridging a gap > " + f"{inp.max_gap_s:g} s", "marks_bridging_gap")
        + row("inside radio dropouts", "marks_in_radio_gap")
        + row("attitude assumed (nadir)", "nadir_assumed")
        + "</table>"
    )
    right = (
        '<table class="counts"><caption><b>Photos and marks</b></caption>'
         f'<tr><th>marks in the flight</th><td data-count="marks_total">{inp.marks_total}</td>'
        "</tr>"
         f'<tr><th>duplicate marks set aside</th><td data-count="marks_duplicate">'
        f"{inp.marks_duplicate}</td></tr>"
        + row("photos", "photos") + row("photos matched to a mark", "photos_matched")
        + row("photos without mark", "photos_unmatched")
        + row("of them positioned by the camera clock", "photos_by_camera_clock")
        + row("marks lost on the radio link (count jumps across link losses)",
              "marks_lost_on_link")
        + row("marks not reported by the receiver (count jumps, link intact)",
              "marks_not_reported")
        + (row("photos not counted by the receiver (no mark, no count jump)",
               "photos_not_counted") if inp.photos_given else "")
        + (row("marks without photo (orphans)", "orphan_marks") if inp.photos_given
           else row("marks named mark_NNNN (no photos given)", "orphan_marks"))
        + "<tr><th>cycle slips "
        + ("found (receiver flags + hidden where the phase was missing)"
           if inp.slips_repaired is not None
           else "flagged (rover, first band)") + "</th>"
        f'<td data-count="slips_found">{_e(slips_found)}</td></tr>'
        + "<tr><th>" + ("phase jumps repaired (slips and resolved half cycles)"
                        if inp.slips_repaired is not None else "slips repaired") + "</th>"
        + f'<td data-count="slips_repaired">{_e(slips_rep)}</td>'
        "</tr>"
        + "<tr><th>radio dropouts / source outages</th><td>"
        + (f"{len(inp.radio_gaps)} / {len(inp.source_outages)}" if inp.station_events
           else "not recorded (plain UBX file)") + "</td></tr>"
        + "</table>"
    )
    return f'<div class="cols"><div>{left}</div><div>{right}</div></div>'


MARK_COLUMNS = ("photo", "mark", "count", "UTC", "GPS week s", "E (m)", "N (m)", "h (m)",
                "σE (m)", "σN (m)", "σU (m)", "quality", "grade", "Δt epoch (s)", "flags")
"""Header of the per-mark table (the test reads the table back by these names)."""


def _marks_notes(inp: ReportInput) -> str:
    """What the marks section must say before its table: no photos given (the marks' names in
    the exports), and the marks the receiver missed."""
    out = []
    if not inp.photos_given:
        out.append(
            f'<p class="marks-names">{NO_PHOTOS_TEXT}</p>')
    for cause, text in zip((c for c, j in inp.lost_marks.items() if j),
                           lost_marks_text(inp.lost_marks), strict=True):
        out.append(f'<p class="marks-missed" data-cause="{cause}">{_e(text)}</p>')
    if inp.photos_not_counted:
        out.append(f'<p class="marks-missed" data-cause="not-counted">'
                   f"{_e(not_counted_text(inp.photos_not_counted))}</p>")
    return "".join(out)


NO_PHOTOS_TEXT = ("No photos given: marks named mark_NNNN (the receiver's mark count) in "
                  "geo.txt, reference.csv and pix4d.csv; pair them with the images in the "
                  "photogrammetry tool.")
"""Said in the report's marks section when ``solve`` ran without ``--photos``."""


def _marks_table(inp: ReportInput) -> str:
    near = nearest_epoch_s(inp)
    nd = 3 if inp.projected else 9
    cols = list(MARK_COLUMNS)
    if not inp.projected:
        cols[5:7] = ["lon (deg)", "lat (deg)"]
    head = "".join(f"<th>{_e(c)}</th>" for c in cols)
    body = []
    for r, dt_s in zip(inp.rows, near.tolist(), strict=True):
        q = r.quality if r.positioned else 0
        cls = {Q_FIX: "q-fix", Q_FLOAT: "q-float", Q_SINGLE: "q-single"}.get(q, "q-none")
        cells = [
            _e(r.photo), str(r.mark) if r.mark >= 0 else "",
            str(r.mark_count) if r.mark_count >= 0 else "",
            _e(utc_text(r.t_gps_ns)), _e(gps_text(r.t_gps_ns)),
            _num(r.x_m, nd), _num(r.y_m, nd), _num(r.h_m, 3),
            _num(r.sd_e_m, 3), _num(r.sd_n_m, 3), _num(r.sd_u_m, 3),
        ]
        tds = "".join(f'<td class="n">{c}</td>' if i > 0 else f"<td>{c}</td>"
                      for i, c in enumerate(cells))
        check = (f'<br><span class="muted">'
                 f'{_e(r.check.replace(":", ": ")).replace("-", "-<wbr>")}</span>'
                 if r.check else "")
        tds += f'<td>{_quality_dot(q)}</td><td class="w">{_e(r.grade)}{check}</td>'
        flags = "<br>".join(map(_e, flag_names(r.flags)))  # one a line: the table fits
        tds += f'<td class="n">{_num(dt_s, 3)}</td><td>{flags}</td>'
        body.append(f'<tr class="{cls}">{tds}</tr>')
    return (f'<table class="marks" id="marks"><thead><tr>{head}</tr></thead>'
            f"<tbody>{''.join(body)}</tbody></table>")


HTML_NAME = "report.html"
MOVES_WITH_BASE = frozenset({"trajectory"})
"""Figures never kept by a re-base: the map in the CRS's own coordinates moves with the base
(the other keys: ``trajectory-from-base``, ``quality``, ``satellites``, ``sigmas``, ``timing``,
``lever``)."""
_FIGURE_RE = re.compile(
    r'<figure data-fig="([a-z-]+)" data-inputs="([0-9a-f]+)"><h3>[^<]*</h3>(<svg.*?</svg>\s*)'
    r"<figcaption>", re.S)


def figures_in(page: str) -> dict[str, str]:
    """The figures a re-base may keep from a report this module rendered, as
    ``key@digest of their inputs`` -> SVG (none from a page of another layout)."""
    return {f"{k}@{d}": svg for k, d, svg in _FIGURE_RE.findall(page)
            if k not in MOVES_WITH_BASE}


DIGEST_DECIMALS = 4
"""Floats enter a figure's digest rounded to this many decimals (a tenth of a millimetre, of a
millisecond: below what any figure shows; above what a re-base's arithmetic changes, such as
the sigma of a photo timed by the camera clock, widened by the velocity along directions taken
at the moved position: 1e-8 m for a base moved 1 m)."""


def _digest(*values: Any) -> str:
    """A digest of a figure's inputs (arrays by dtype, shape and bytes; the rest by repr)."""
    h = hashlib.sha256()
    for v in values:
        if isinstance(v, np.ndarray):
            if v.dtype.kind == "f":
                v = np.round(v, DIGEST_DECIMALS) + 0.0  # (+0.0: no negative zero)
            h.update(f"{v.dtype}{v.shape}".encode())
            h.update(np.ascontiguousarray(v).tobytes())
        else:
            h.update(repr(round(v, DIGEST_DECIMALS) if isinstance(v, float) else v).encode())
        h.update(b"|")
    return h.hexdigest()[:20]


def _figures(inp: ReportInput) -> list[tuple[str, str, str, str, str]]:
    """(key, digest of its inputs, title, svg, caption) of every figure; one whose key and
    digest are in ``inp.kept_figures`` is taken from there, not drawn again.

    What a re-base may keep: a figure whose every input is as it was, but for the positions
    of the map drawn from the base (a re-base moves them rigidly with the base: the picture
    is the same)."""
    rows = inp.rows
    cam_x = np.array([r.x_m for r in rows], dtype=np.float64)
    cam_y = np.array([r.y_m for r in rows], dtype=np.float64)
    t_rows = np.array([r.t_gps_ns for r in rows], dtype=np.int64)
    sd = np.array([(r.sd_e_m, r.sd_n_m, r.sd_u_m) for r in rows], dtype=np.float64).reshape(-1, 3)
    qual = np.array([r.quality for r in rows], dtype=np.int64)
    grades = [r.grade for r in rows]
    # where the lever arm put each camera: an EO file's attitude as given; one taken from the
    # track moves with it (a re-base changes its grid bearing by micro-degrees: not an input)
    attitude = [(r.attitude, (r.omega_deg, r.phi_deg, r.kappa_deg) if r.attitude == "eo"
                 else None) for r in rows]
    sats = inp.satellites
    origin = inp.map_origin
    crs = f"EPSG:{inp.epsg} {inp.crs_name}"
    # key, inputs, title, how to draw it (figures: matplotlib, loaded only when one is
    # drawn), caption
    todo: list[tuple[str, tuple[Any, ...], str, Callable[[Any], str], str]] = [(
        "trajectory" if origin is None else "trajectory-from-base",
        (inp.track_t_gps_ns, inp.track_quality, np.isfinite(inp.track_x_m), t_rows,
         np.isfinite(cam_x), grades, attitude, inp.lever_arm_m, inp.max_gap_s, crs,
         inp.projected),
        "Trajectory",
        lambda f: f.trajectory(inp.track_x_m, inp.track_y_m, inp.track_quality,
                               inp.track_t_gps_ns, cam_x, cam_y, max_gap_s=inp.max_gap_s,
                               crs=crs, projected=inp.projected, cam_grade=grades,
                               origin=origin),
        ("Antenna trajectory in the output CRS, coloured by solution quality (fixed: fixed and "
         "checked); circles are the camera positions (after the lever arm) in their grade's "
         "colour. Equal scale on both axes; north arrow points to grid north."
         + ("" if origin is None else
            f" Axes in metres from the base (the triangle, where it falls within the frame), "
            f"which is at {_map_origin_text(inp)}.")),
    ), (
        "quality",
        (inp.track_t_gps_ns, inp.track_quality, inp.max_gap_s, inp.radio_gaps,
         inp.source_outages, t_rows, inp.station_events, grades),
        "Quality over time",
        lambda f: f.quality_timeline(inp.track_t_gps_ns, inp.track_quality,
                                     max_gap_s=inp.max_gap_s, radio_gaps=inp.radio_gaps,
                                     outages=inp.source_outages, mark_t_gps_ns=t_rows,
                                     events_recorded=inp.station_events, mark_grade=grades),
        ("Solution quality per epoch (hatched: no solved epoch for longer than the gap limit), "
         "radio dropouts and source outages recorded by the ground station, and the camera "
         "positions in their grade's colour. Bottom axis UTC, top axis GPS seconds of week."),
    )]
    if sats is not None:
        todo.append((
            "satellites",
            (sats.sat, sats.t_gps_ns, sats.cno_dbhz, sats.slip, sats.half, sats.repaired),
            "Satellites",
            lambda f: f.satellites(sats.sat, sats.t_gps_ns, sats.cno_dbhz, sats.slip, sats.half,
                                   sats.repaired),
            ("Rover satellites over time: colour is C/N0, red ticks are cycle slips (loss of "
             "lock), orange marks epochs with the half-cycle ambiguity unresolved."),
        ))
    todo.append((
        "sigmas", (t_rows, sd, qual), "Standard deviations at the camera positions",
        lambda f: f.sigmas(t_rows, sd, qual),
        ("σ east, north and up of every camera position, as given by the engine and carried "
         "through the interpolation; red circles: not ambiguity-fixed."),
    ))
    if inp.pair_residual_s.size:
        todo.append((
            "timing", (inp.pair_t_gps_ns, inp.pair_residual_s, inp.pair_window_s),
            "Photo timing residuals",
            lambda f: f.timing_residuals(inp.pair_t_gps_ns, inp.pair_residual_s,
                                         inp.pair_window_s or math.nan,
                                         clockoffset.residual_sigma_s(inp.pair_residual_s)),
            ("Time of each mark minus the photo's EXIF time corrected by the camera clock "
             "offset. Whole-second EXIF times spread over ±500 ms; sub-second times sit near "
             "zero."),
        ))
    if inp.lever_residual_m.size:
        todo.append((
            "lever", (inp.lever_residual_m, inp.lever_outlier), "Lever-arm residuals",
            lambda f: f.lever_residuals(inp.lever_residual_m, inp.lever_outlier),
            "Lever arm estimated per image from the exterior orientation file, minus the mean.",
        ))
    out = []
    for key, inputs, title, draw, caption in todo:
        digest = _digest(*inputs)
        svg = inp.kept_figures.get(f"{key}@{digest}")
        if svg is None:
            from groundstation.solve import figures

            svg = draw(figures)
        out.append((key, digest, title, svg, caption))
    return out


def _map_origin_text(inp: ReportInput) -> str:
    """Where the map's origin (the base) is, in the output CRS."""
    assert inp.map_origin is not None
    x, y = inp.map_origin
    if inp.projected:
        return f"E {x:.3f}, N {y:.3f} m in EPSG:{inp.epsg}"
    return f"longitude {x:.8f}°, latitude {y:.8f}°"


def render_html(inp: ReportInput) -> str:
    """The whole page (self-contained: inline CSS and SVG, no scripts, no links)."""
    warn = warnings(inp)
    warn_html = (
        '<ul class="warn">' + "".join(f"<li>{_e(w)}</li>" for w in warn) + "</ul>" if warn
        else '<p class="ok">Nothing to report: every camera position is fixed, no gaps.</p>'
    )
    figs = "".join(
        f'<figure data-fig="{key}" data-inputs="{digest}"><h3>{_e(title)}</h3>{svg}'
        f"<figcaption>{_e(cap)}</figcaption></figure>"
        for key, digest, title, svg, cap in _figures(inp)
    )
    unmatched = "".join(f"<li>{_e(n)}: {_e(why)}</li>" for n, why in inp.photos_unmatched)
    notes = "".join(f"<li>{_e(n)}</li>" for n in inp.notes)
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>Flight report: {_e(inp.flight)}</title><style>{_CSS}</style></head><body>"
        f"<h1>Flight report: {_e(inp.flight)}</h1>"
        f'<p class="muted">Camera positions from groundstation solve. Times in UTC and GPS '
        f"(week, seconds of week).</p>"
        f'<section class="result" id="result"><h2>Result</h2>{_result(inp)}</section>'
        f"<h2>Warnings</h2>{warn_html}"
        f"<h2>Summary</h2>{_summary(inp)}"
        f"<h2>Counts</h2>{_counts_table(inp)}"
        f'<section class="integrity" id="integrity"><h2>Integrity</h2>{_integrity(inp)}'
        "</section>"
        f'<section class="figs"><h2>Figures</h2>{figs}</section>'
        f'<section class="positions"><h2>Camera positions</h2>'
        f'<p class="muted">One row per photo (then per mark without photo), as in cameras.csv. '
        f"E/N in EPSG:{inp.epsg}, h {_e(inp.height_datum)}; σ east/north/up; Δt epoch: time "
        f"from the mark to the nearest solved epoch; "
        f"{_e(mark_numbers_text('count (mark_count in cameras.csv)'))}</p>{_marks_notes(inp)}"
        f"{_marks_table(inp)}</section>"
        + (f"<h2>Photos without mark</h2><ul>{unmatched}</ul>" if unmatched else "")
        + f"<h2>Notes</h2><ul>{notes}</ul>"
        f'<section class="options" id="engine-options"><h2>Engine options</h2>{_options(inp)}'
        "</section></body></html>\n"
    )


def write_report(inp: ReportInput, out_dir: Path, *, pdf: bool = True,
                 ) -> tuple[list[Path], list[str]]:
    """Write ``report.html`` and (with Chromium, unless ``pdf`` is false) ``report.pdf``;
    returns (paths, notes).

    The notes say what is missing (not asked for, no Chromium, printing failed) so the caller
    can show them.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    hp = out_dir / HTML_NAME
    hp.write_text(render_html(inp), encoding="utf-8")
    paths, notes = [hp], []
    if not pdf:
        notes.append("report.pdf not written: not asked for (--no-pdf, or report_pdf = false "
                     "for the solver); a browser prints report.html as the same page")
        return paths, notes
    pp = out_dir / "report.pdf"
    chromium = find_chromium()
    if chromium is None:
        notes.append("report.pdf not written: Chromium is not installed (apt-get install "
                     "chromium); print report.html from a browser instead")
        return paths, notes
    try:
        print_pdf(hp, pp, chromium)
    except (RuntimeError, OSError) as err:
        notes.append(f"report.pdf not written: {err}")
        return paths, notes
    paths.append(pp)
    return paths, notes
