"""The flight report of the demo flight (simulated photos) and of the real 2018-10-09 flight.

Each flight is solved with the command a user runs. The report is then read the way a reviewer
reads it: the per-mark table is parsed back from the HTML and compared row by row with
``cameras.csv``; every count in the summary is recomputed from the exports; the page is opened
in headless Chromium (no console errors, no request but the file itself, figures laid out at
1366x768, nothing wider than the window) and its PDF (printed by Chromium from the same HTML)
is checked for A4 pages carrying the same table. Screenshots go to ``$GS_REPORT_SHOTS`` when set
(else the test's tmp dir).
"""

from __future__ import annotations

import csv
import html
import html.parser
import json
import os
import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from once import DemoFlight
from test_dashboard_chromium import CHROMIUM, Chromium
from test_solve_demo import _cli
from test_solve_jd import JD, REF, _photos_for_marks

from groundstation.rules.marks import build_marks
from groundstation.solve.flight import read_flight
from groundstation.solve.photosim import photos_at_times, write_photo_set
from groundstation.solve.report import MARK_COLUMNS

# One worker runs this module's tests (pytest-xdist):
# its module fixtures solve the demo and the real flight (~8 s each), made once.
pytestmark = pytest.mark.xdist_group("test_report")

needs_chromium = pytest.mark.skipif(
    not CHROMIUM.exists(),
    reason="headless Chromium not installed (/usr/bin/chromium absent; apt-get install chromium)",
)
needs_poppler = pytest.mark.skipif(shutil.which("pdfinfo") is None,
                                   reason="poppler-utils (pdfinfo, pdftotext) not installed")


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory, demo_flight: DemoFlight) -> dict[str, Any]:
    """The demo flight with a photo per exposure, solved with the default engine (demo5)."""
    d = tmp_path_factory.mktemp("report_demo")
    files = demo_flight.files  # (the demo made once for the run: conftest.py)
    truth = json.loads(files["truth"].read_text())
    photos = d / "photos"
    write_photo_set(photos_at_times([e["falling_t_gps_ns"] for e in truth["exposures"]],
                                    clock_error_s=-(1 * 3600 + 51 * 60 + 2.6)), photos)
    xyz = ",".join(f"{v:.4f}" for v in truth["base"]["ecef_m"])
    out = d / "out"
    proc = _cli("solve", str(files["MCAP"]), "--base", str(files["base UBX"]), "--base-xyz", xyz,
                "--photos", str(photos), "--lever-arm", "0.16,-0.03,0.57", "--interp",
                "smoother", "--out", str(out), "--no-progress", cwd=d)
    assert proc.returncode == 0, proc.stderr
    # Marks in the recording: the exposures less those whose pulse the camera missed or whose
    # TIM-TM2 the demo's link faults lost.
    lost = {c - 1 for c in truth["fault_summary"].get("marks_lost_in_link", [])}
    marks = [k for k, e in enumerate(truth["exposures"]) if k not in lost and not e.get("missed")]
    return {"name": "demo", "out": out, "stdout": proc.stdout, "photos": photos,
            "marks": len(marks)}


@pytest.fixture(scope="module")
def real(tmp_path_factory: pytest.TempPathFactory, shared_data: Path) -> dict[str, Any]:
    """The jdesbonnet 2018-10-09 flight with RTKLIB's positions, three photos missing."""
    d = tmp_path_factory.mktemp("report_real")
    rover = shared_data / JD / "rover-20181009-1221.ubx.gz"
    pos = shared_data / REF / "jd_20181009_kin_vs_M8Pbase_svin.pos.gz"
    marks = build_marks(read_flight(rover).timemarks)
    times = [m.falling_t_gps_ns for m in marks]
    _photos_for_marks([t for t in times if t is not None], d / "photos", -(47 * 60 + 12.34),
                      {5, 77, 300})
    out = d / "out"
    proc = _cli("solve", str(rover), "--positions", str(pos), "--photos", str(d / "photos"),
                "--lever-arm", "0.16,-0.03,0.57", "--epsg", "25829", "--interp", "smoother",
                "--out", str(out), "--no-progress", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return {"name": "real", "out": out, "stdout": proc.stdout, "photos": d / "photos",
            "marks": len(marks)}


FLIGHTS = [pytest.param("demo"), pytest.param("real", marks=pytest.mark.slow)]


@pytest.fixture(params=FLIGHTS)
def flight(request: pytest.FixtureRequest) -> dict[str, Any]:
    value: dict[str, Any] = request.getfixturevalue(request.param)
    return value


class _Report(html.parser.HTMLParser):
    """The per-mark table (header and cell texts), the ``data-count`` cells, every URL."""

    def __init__(self) -> None:
        super().__init__()
        self.header: list[str] = []
        self.rows: list[list[str]] = []
        self.counts: dict[str, str] = {}
        self.urls: list[str] = []
        self._in_marks = False
        self._cell: list[str] | None = None
        self._count_key: str | None = None
        self._row: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        for name in ("src", "href", "xlink:href", "data"):
            v = a.get(name)
            if v and not v.startswith(("#", "data:")):
                self.urls.append(v)
        if tag == "table" and a.get("id") == "marks":
            self._in_marks = True
        elif self._in_marks and tag == "tr":
            self._row = []
        elif self._in_marks and tag in ("td", "th"):
            self._cell = []
        if tag == "td" and a.get("data-count"):
            self._count_key = a["data-count"]
            self._cell = []

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None:
            text = "".join(self._cell).strip()
            if self._count_key is not None:
                self.counts[self._count_key] = text
                self._count_key = None
            elif self._row is not None:
                self._row.append(text)
            self._cell = None
        elif tag == "tr" and self._row is not None:
            if self.header:
                self.rows.append(self._row)
            else:
                self.header = self._row
            self._row = None
        elif tag == "table":
            self._in_marks = False


def _read(out: Path) -> _Report:
    p = _Report()
    p.feed((out / "report.html").read_text(encoding="utf-8"))
    return p


def _cameras(out: Path) -> list[dict[str, str]]:
    lines = [ln for ln in (out / "cameras.csv").read_text().splitlines()
             if not ln.startswith("#")]
    return list(csv.DictReader(lines))


def test_per_mark_table_equals_cameras_csv(flight: dict[str, Any]) -> None:
    rep = _read(flight["out"])
    rows = _cameras(flight["out"])
    assert tuple(rep.header) == MARK_COLUMNS
    assert len(rep.rows) == len(rows) > 0
    for got, want in zip(rep.rows, rows, strict=True):
        cell = dict(zip(MARK_COLUMNS, got, strict=True))
        assert cell["photo"] == want["photo"]
        assert cell["mark"] == want["mark"] and cell["count"] == want["mark_count"]
        # Times: the table shows milliseconds of the same instant (truncated).
        assert cell["UTC"] == want["utc"][:23].replace("T", " ")
        tow = want["gps_tow_s"]
        assert cell["GPS week s"] == (f"{want['gps_week']} {tow[:tow.index('.') + 4]}"
                                      if tow else "")
        assert (cell["E (m)"], cell["N (m)"], cell["h (m)"]) == (want["x_m"], want["y_m"],
                                                                 want["h_m"])
        assert (cell["σE (m)"], cell["σN (m)"], cell["σU (m)"]) == (
            want["sd_e_m"], want["sd_n_m"], want["sd_u_m"])
        assert cell["quality"] == (want["quality_name"] if want["x_m"] else "none")
        assert cell["grade"].startswith(want["grade"])
        assert want["check"].replace(":", ": ") in cell["grade"]
        assert cell["flags"] == want["flags"].replace(";", "")
        if want["utc"]:
            assert 0.0 <= float(cell["Δt epoch (s)"]) < 600.0
        else:
            assert cell["Δt epoch (s)"] == ""


def test_every_count_equals_the_exports(flight: dict[str, Any]) -> None:
    out: Path = flight["out"]
    counts = _read(out).counts
    rows = _cameras(out)
    pos = [r for r in rows if r["x_m"]]
    expect = {
        "rows": len(rows),
        "fixed": sum(r["quality_name"] == "fix" for r in pos),
        "float": sum(r["quality_name"] == "float" for r in pos),
        "single": sum(r["quality_name"] == "single" for r in pos),
        "not_positioned": len(rows) - len(pos),
        "photos": len(list(flight["photos"].iterdir())),
        "photos_matched": sum(bool(r["photo"] and r["mark"]) for r in rows),
        "photos_unmatched": sum(bool(r["photo"] and not r["mark"]) for r in rows),
        "photos_by_camera_clock": sum("camera_clock" in r["flags"].split(";") and bool(r["x_m"])
                                      for r in rows),
        "orphan_marks": sum(bool(r["mark"] and not r["photo"]) for r in rows),
        "marks_bridging_gap": sum("gap" in r["flags"].split(";") for r in rows),
        "nadir_assumed": sum(r["attitude"] == "nadir-track" for r in rows),
        "marks_total": flight["marks"],
    }
    for name in ("dgps", "sbas", "ppp"):
        n = sum(r["quality_name"] == name for r in pos)
        if n or name in counts:
            expect[name] = n
    got = {k: int(v) for k, v in counts.items() if k in expect}
    assert got == expect
    assert sum(got[k] for k in ("fixed", "float", "single", "dgps", "sbas", "ppp")
               if k in got) + got["not_positioned"] == got["rows"]
    # The other exports carry exactly the positioned photos.
    geo = (out / "geo.txt").read_text().splitlines()[1:]
    assert len(geo) == sum(bool(r["photo"] and r["x_m"]) for r in rows)
    assert f"marks      {flight['marks']}:" in flight["stdout"]
    assert counts["slips_found"].isdigit()


def test_nothing_points_outside_the_repository(flight: dict[str, Any]) -> None:
    out: Path = flight["out"]
    text = (out / "report.html").read_text(encoding="utf-8")
    rep = _read(out)
    assert rep.urls == [] and "<script" not in text and "@import" not in text
    assert "http" not in text  # no namespace URLs, no CDN, no links
    for p in [*out.glob("*.csv"), *out.glob("*.txt"), *out.glob("*.geojson"),
              out / "report.html"]:
        body = p.read_text(encoding="utf-8")
        assert "DOMAIN.md" not in body and "§" not in body, p.name
    assert "DOMAIN.md" not in flight["stdout"] and "§" not in flight["stdout"]


def test_warnings_name_what_a_reviewer_must_know(flight: dict[str, Any]) -> None:
    text = (flight["out"] / "report.html").read_text(encoding="utf-8")
    assert "<h2>Warnings</h2>" in text
    assert "Attitude assumed for" in text  # no EO file: nadir camera assumed
    if flight["name"] == "real":
        assert "3 time mark(s) without a photo" in text
        assert "not ambiguity-fixed" in text and "interpolated across a gap" in text
        assert "rnx2rtkp ver.EX 2.5.1" in text  # engine and version from the solution header
    else:
        assert re.search(r"demo5 RTKLIB EX 2\.5", text)  # engine and version
        assert "pos1-navsys" in text  # the full option set
        assert "pos2-armode = fix-and-hold" in text  # and its options
        assert "m from the mean of the base receiver" in text
        # a LEA-6T's RXM-RAW: half cycles, except between the arcs checked whole
        assert re.search(r"lattice 0\.5 cycle, 1 cycle between the \d+ arcs checked whole",
                         text)
        # the integrity section says what every check it counts means
        from groundstation.solve.integrity.grade import CHECK_TEXT

        decided = re.search(r"Decided by \(epochs\)</t[hd]>\s*<td>(.*?)</td>", text)
        assert decided, "no Decided by row"
        for name in re.findall(r"([a-z:-]+) \d+", decided.group(1)):
            if name in CHECK_TEXT:
                assert f"{name}: {html.escape(CHECK_TEXT[name], quote=True)}" in text, name


def test_the_result_comes_first_and_the_full_options_last(flight: dict[str, Any]) -> None:
    """A surveyor reads the result (fixed share, marks positioned and missed, accuracy) and the
    warnings first; the engine's option set is at the end, whole (issue 13)."""
    text = (flight["out"] / "report.html").read_text(encoding="utf-8")
    headings = re.findall(r"<h2>(.*?)</h2>", text)
    assert headings[:2] == ["Result", "Warnings"], headings
    assert headings[-1] == "Engine options", headings
    result = text[text.index('id="result"'):text.index("<h2>Warnings</h2>")]
    rows = _cameras(flight["out"])
    fixed = sum(1 for r in rows if r["quality_name"] == "fix")
    # The fixed share is over the computed positions: photos without a mark (their own line)
    # do not pull it down.
    positioned = [r for r in rows if r["x_m"]]
    share = f"{fixed / len(positioned):.0%}"
    assert (f"{fixed} of {len(positioned)}</b> computed camera positions fixed and checked "
            f"({share})") in result
    unmatched = sum(bool(r["photo"] and not r["mark"]) for r in rows)
    if flight["name"] == "demo":
        assert unmatched > 0  # the demo's missed marks leave photos without a mark
    if unmatched:
        timed = sum("camera_clock" in r["flags"].split(";") for r in rows if r["photo"])
        said = f"{unmatched} ({timed} positioned by the camera clock)" if timed else unmatched
        assert re.search(rf"Photos without a mark</th>\s*<td>{re.escape(str(said))}<",
                         result), result
    assert f"of {flight['marks']}</b> marks in the flight" in result
    assert "Missed marks" in result and "σ horizontal" in result and " cm " in result
    head, _, tail = text.partition('id="engine-options"')
    info = flight["out"] / "rtklib" / "engine.json"
    if info.is_file():  # our engine ran: every option it ran with, only at the end
        options = json.loads(info.read_text())["options"]
        assert len(options) > 100
        for key, value in options.items():
            assert f"<code>{html.escape(f'{key} = {value}')}</code>" in tail, key
            assert f"<code>{html.escape(key)} = " not in head, key
        assert f"({len(options)} options)" in tail
    else:  # an imported solution: the report says that no option set is recorded
        assert "No option set recorded" in tail


def test_one_timing_residual_sigma_in_printout_and_report(flight: dict[str, Any]) -> None:
    """The solve's printout and the report give the same residual σ, in the same unit."""
    printed = re.search(r"timing residual sigma (\d+\.\d) ms \(robust\)", flight["stdout"])
    assert printed, flight["stdout"]
    text = (flight["out"] / "report.html").read_text(encoding="utf-8")
    shown = re.search(r"timing residual σ (\d+\.\d) ms \(robust\)", text)
    assert shown
    assert printed.group(1) == shown.group(1)
    window = re.search(r"pairing window \+/-(\d+) ms", flight["stdout"])
    assert window and f"pairing window ±{window.group(1)} ms" in text


def _shots_dir(tmp_path: Path) -> Path:
    d = Path(os.environ.get("GS_REPORT_SHOTS") or tmp_path)
    d.mkdir(parents=True, exist_ok=True)
    return d


@pytest.mark.slow
@needs_chromium
def test_report_renders_in_chromium(flight: dict[str, Any], tmp_path: Path) -> None:
    page = (flight["out"] / "report.html").resolve()
    browser = Chromium()
    try:
        browser.send("Network.enable")
        browser.send("Page.navigate", {"url": page.as_uri()})
        deadline = time.monotonic() + 30
        while browser.eval("document.readyState") != "complete":
            assert time.monotonic() < deadline, "page did not load"
            time.sleep(0.1)
        assert browser.console_errors() == []
        requested = [e["params"]["request"]["url"] for e in browser.events
                     if e.get("method") == "Network.requestWillBeSent"]
        # The page itself and the rasters embedded in the figures (data: URLs), nothing else.
        assert [u for u in requested if not u.startswith("data:")] == [page.as_uri()]
        # Figures laid out: every SVG as wide as the text column and of a sensible height.
        boxes = browser.eval(
            "[...document.querySelectorAll('svg.fig')].map(s => {const r = "
            "s.getBoundingClientRect(); return [s.getAttribute('aria-label'), r.width, "
            "r.height]})")
        names = [b[0] for b in boxes]
        assert names[:2] == ["trajectory", "quality"] and "sigmas" in names
        assert "satellites" in names and "timing" in names
        for name, w, h in boxes:  # the map at its natural size (it fits the screen), the
            # time series a bit larger (900 px), type readable in both
            assert 600 < w <= 900 and 150 < h < 900, (name, w, h)
        traj = {b[0]: b[1:] for b in boxes}["trajectory"]
        assert 0.6 * traj[0] < traj[1] < 768  # the map is not a strip, and fits the screen
        assert browser.eval("document.documentElement.scrollWidth") <= 1366
        # The first screen (1366x768) holds the result and the start of the warnings; the
        # option set is after the per-mark table.
        first = browser.eval(
            "[document.getElementById('result').getBoundingClientRect().bottom, [...document"
            ".querySelectorAll('h2')].find(h => h.textContent === 'Warnings')"
            ".getBoundingClientRect().bottom, document.querySelector('.opts, #engine-options p')"
            ".getBoundingClientRect().top, document.getElementById('marks')"
            ".getBoundingClientRect().bottom]")
        assert first[0] < 768 and first[1] < 768 and first[2] > first[3], first
        n_rows = browser.eval("document.querySelectorAll('#marks tbody tr').length")
        assert n_rows == len(_cameras(flight["out"]))
        shots = _shots_dir(tmp_path)
        height = browser.eval("document.documentElement.scrollHeight")
        for k in range(min(6, -(-height // 768))):
            browser.eval(f"window.scrollTo(0, {k * 768})")
            time.sleep(0.2)
            browser.screenshot(shots / f"{flight['name']}-screen-{k + 1}.png")
        assert browser.console_errors() == []
    finally:
        browser.close()


@needs_poppler
@needs_chromium
def test_report_pdf_is_the_same_page_on_a4(flight: dict[str, Any]) -> None:
    out: Path = flight["out"]
    pdf = out / "report.pdf"
    assert pdf.is_file() and f"wrote      {pdf}" in flight["stdout"]
    info = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True, check=True)
    pages = int(re.search(r"^Pages:\s+(\d+)", info.stdout, re.M).group(1))  # type: ignore[union-attr]
    assert "(A4)" in info.stdout and pages >= 3
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True).stdout
    for heading in ("Result", "Warnings", "Summary", "Counts", "Figures", "Camera positions",
                    "Engine options"):
        assert heading in text
    rows = _cameras(out)
    # Every photo of the table is on paper (the table is not cut at the page bottom).
    for r in rows:
        if r["photo"]:
            assert r["photo"] in text
    assert "UTC" in text and "GPS week" in text


def test_without_chromium_the_html_is_written_and_the_missing_pdf_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import numpy as np

    from groundstation.solve.outputs import CameraRow
    from groundstation.solve.report import write_report
    from groundstation.solve.report_data import ReportInput

    t0 = 2022 * 604_800 * 10**9 + 217_373 * 10**9
    inp = ReportInput(
        flight="f.ubx", engine_name="E", engine_version="1", engine_options={},
        position_source="p", base_name=None, base_ecef_m=None, base_check="none",
        base_doubtful=True, epsg=25829, crs_name="ETRS89 / UTM zone 29N", projected=True,
        lever_arm_m=(0.0, 0.0, 0.3), shutter_delay_ms=0.0, edge="falling", interp="linear",
        max_gap_s=1.0, marks_total=1, marks_duplicate=0,
        rows=(CameraRow("IMG_1.JPG", 0, 1, t0, 53.28, -8.98, 90.0, 501100.0, 5903700.0,
                        0.01, 0.01, 0.02, 1, 0),),
        track_t_gps_ns=np.array([t0 - 10**9, t0 + 10**9]),
        track_x_m=np.array([501090.0, 501110.0]), track_y_m=np.array([5903690.0, 5903710.0]),
        track_quality=np.array([1, 1]),
    )
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))  # no chromium on this PATH
    paths, notes = write_report(inp, tmp_path / "out")
    assert [p.name for p in paths] == ["report.html"]
    assert not (tmp_path / "out" / "report.pdf").exists()
    assert notes == [("report.pdf not written: Chromium is not installed (apt-get install "
                     "chromium); print report.html from a browser instead")]
    text = paths[0].read_text()
    assert "Base coordinates doubtful" in text  # a warning the reviewer sees first
