"""What a peer sends or a file holds cannot crash, hang or fool a view, the solver or a writer.

Poison bus payloads (a time mark at 1e25 ns, an event at 1e30, a status with wrong types) are
counted and dropped by the dashboard's state, ``watch`` and the solver; crafted session messages
are refused by the solver without reading anything outside its roots; the looping-EXIF JPEG is
skipped; CSV exports neutralise formulas; the dashboard answers only its own Host names.
"""

from __future__ import annotations

import http.client
import subprocess
import sys
import threading
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from peers import cli_env
from poison import POISON, looping_exif_jpeg
from test_dashboard import FakeBus, event, mark, status
from test_solve_outputs import out  # noqa: F401 (the fixture)

from groundstation import jsonio, messages, outpaths
from groundstation.bus import encode
from groundstation.config import ZenohSettings, check_station
from groundstation.errors import ConfigError, GroundstationError
from groundstation.solve import clockoffset, exif, outputs, photos
from groundstation.solve import service as sv
from groundstation.solve.pipeline import SolveResult
from groundstation.solve.settings import SolveSettings
from groundstation.view.dashboard.server import Dashboard, DashboardSettings, host_ok
from groundstation.view.dashboard.state import StationView
from groundstation.view.watch import WatchState, _draw, render

REPO = Path(__file__).resolve().parents[2]
XYZ = (4_000_000.0, 600_000.0, 4_900_000.0)



def test_messages_accept_what_the_daemon_sends_and_refuse_poison() -> None:
    for payload in (status(100.0), mark(1, 2.0), event("link.dropout", {"missing_epochs": 3})):
        messages.parse(payload)
    for key_expr, payload in POISON:
        with pytest.raises(messages.BadMessage):
            messages.parse(payload, key_expr.rsplit("/", 1)[-1])


def test_dashboard_state_counts_poison_and_keeps_working() -> None:
    v = StationView("st")
    assert v.on_payload("groundstation/st/status", status(100.0), now_s=0.0)
    for key_expr, payload in POISON:
        v.on_payload(key_expr, payload, now_s=0.1)
    v.on_payload("groundstation/st/timemark", mark(0, 99.0), now_s=0.2)
    snap = v.snapshot(0.5)
    jsonio.dumps(snap)  # the page's document still encodes
    assert snap["rejected"] == len(POISON) and snap["has_status"]
    assert snap["marks"]["received"] == 1 and snap["link"]["epoch_interval_s"] == 0.2
    assert v.last_rejection.startswith("status")  # the last poison named


def test_watch_counts_poison_and_still_draws() -> None:
    w = WatchState("st")
    good = {"sv": "G05", "cno_dbhz": 44, "elev_deg": 40, "azim_deg": 120, "state": "clean",
            "lock_s": 10.0, "clean_phase_s": 9.0, "slips": 0, "half_cycle_unresolved": False}
    doc = jsonio.loads(status(100.0))
    doc["sats"] = [good]
    doc["marks"].update(last_count=1, rate_per_min=1.0, last_pulse_width_ms=1.0)
    w.on_payload("groundstation/st/status", jsonio.dumps(doc), now_s=0.0)
    assert w.status is not None
    for key_expr, payload in POISON:
        w.on_payload(key_expr, payload, now_s=0.1)
    # a status that is valid JSON and in range but that the screen cannot draw (no "state")
    bad = dict(doc, sats=[{k: v for k, v in good.items() if k != "state"}])
    w.on_payload("groundstation/st/status", jsonio.dumps(bad), now_s=0.2)
    assert w.rejected == len(POISON) + 1
    assert w.status is not None and w.status["sats"][0]["state"] == "clean"  # the good one
    _draw(render(w, now_s=0.3))  # still draws, with the count
    assert "bad messages dropped" in _text(render(w, now_s=0.3))


def _text(renderable: Any) -> str:
    import io

    from rich.console import Console

    buf = io.StringIO()
    Console(file=buf, width=200, color_system=None).print(renderable)
    return buf.getvalue()


# -- the solver: crafted sessions --------------------------------------------------------------


class Recorder:
    """A solver that only records what it was asked to solve."""

    def __init__(self) -> None:
        self.calls: list[SolveSettings] = []

    def __call__(self, s: SolveSettings) -> SolveResult:
        self.calls.append(s)
        raise GroundstationError("not solved in this test")


def _service(tmp_path: Path, **kw: Any) -> tuple[sv.SolverService, list[dict[str, Any]], Recorder]:
    roots = tmp_path / "flights"
    roots.mkdir(exist_ok=True)
    (tmp_path / "base.ubx").write_bytes(b"base")
    settings = sv.ServiceSettings(
        default=sv.StationSolve(base=str(tmp_path / "base.ubx"), base_ecef_m=XYZ,
                                out_root=tmp_path / "out"),
        recording_roots=(roots,), **kw)
    sent: list[dict[str, Any]] = []
    rec = Recorder()
    return sv.SolverService(settings, lambda _st, body: sent.append(body), solver=rec), sent, rec


def _finished(service: sv.SolverService, station: str, sid: str, *files: str) -> None:
    service.on_session(station, {"type": "session", "state": "finished", "session_id": sid,
                                 "files": list(files)})


def _drain(service: sv.SolverService) -> None:
    stop = threading.Event()
    t = threading.Thread(target=service.run, args=(stop,))
    t.start()
    service.close()
    t.join(10)


def test_solver_refuses_paths_outside_its_roots(tmp_path: Path) -> None:
    service, sent, rec = _service(tmp_path)
    outside = tmp_path / "secret.mcap"
    outside.write_bytes(b"secret")
    (tmp_path / "flights" / "escape.mcap").symlink_to(outside)
    _finished(service, "alpha", "s1", "/etc/shadow.mcap")
    _finished(service, "alpha", "s2", str(outside))
    _finished(service, "alpha", "s3", str(tmp_path / "flights" / ".." / "secret.mcap"))
    _finished(service, "alpha", "s4", str(tmp_path / "flights" / "escape.mcap"))
    _finished(service, "alpha", "s5", "/etc/shadow")
    _drain(service)
    assert [m["status"] for m in sent] == ["refused"] * 5
    assert all("refused" in m["reason"] for m in sent)
    assert not any("exist" in m["reason"] or "found" in m["reason"] for m in sent)  # no probe
    assert rec.calls == [] and not (tmp_path / "out").exists()


def test_solver_drops_bad_station_names_and_messages(tmp_path: Path) -> None:
    service, sent, rec = _service(tmp_path)
    flight = tmp_path / "flights" / "a.mcap"
    flight.write_bytes(b"a")
    for station in ("..", "*", "a/b", "$"):
        _finished(service, station, "s", str(flight))
    service.on_session("alpha", {"type": "session", "state": "finished", "files": "x.mcap"})
    service.on_session("alpha", {"type": "status", "files": [str(flight)]})
    _drain(service)
    assert sent == [] and rec.calls == [] and service.rejected == 6
    assert not (tmp_path / "out").exists()


def test_solver_solves_a_recording_once_by_content(tmp_path: Path) -> None:
    service, sent, rec = _service(tmp_path)
    a = tmp_path / "flights" / "a.mcap"
    a.write_bytes(b"flight bytes")
    copy = tmp_path / "flights" / "copy.mcap"
    copy.write_bytes(b"flight bytes")
    for _ in range(3):
        _finished(service, "alpha", "s1", str(a))  # repeats
    _finished(service, "alpha", "s2", str(copy))  # same bytes, another name and session
    _drain(service)
    statuses = [(m["session_id"], m["status"]) for m in sent]
    assert statuses.count(("s1", "solving")) == 1
    # the first solve failed (Recorder raises), so the same bytes may be tried again, once
    assert statuses.count(("s2", "solving")) == 1
    assert [c.flight for c in rec.calls] == [a, copy]


def test_solver_skips_a_copy_of_a_solved_recording(tmp_path: Path) -> None:
    service, sent, _ = _service(tmp_path)
    a = tmp_path / "flights" / "a.mcap"
    a.write_bytes(b"flight bytes")
    copy = tmp_path / "flights" / "copy.mcap"
    copy.write_bytes(b"flight bytes")
    service._hashes[sv.content_hash(a)] = a  # solved before
    _finished(service, "alpha", "s2", str(copy))
    _drain(service)
    assert [m["status"] for m in sent] == ["solving", "skipped"]
    assert "already solved" in sent[-1]["reason"]


def test_solver_rate_limits_session_messages(tmp_path: Path) -> None:
    service, sent, _ = _service(tmp_path, max_sessions_per_min=1.0)
    for i in range(sv.SESSION_BURST + 30):
        _finished(service, "alpha", f"s{i}", "/elsewhere/x.mcap")
    assert len(sent) == sv.SESSION_BURST  # the burst answered, the rest dropped unanswered
    assert service.rejected == 30


# -- stations, photos, outputs, output paths, the dashboard's HTTP -----------------------------


@pytest.mark.parametrize("name", ["$", "#", "?", "*", "**", "..", ".", "a/b", "a b", "a\x00b",
                                  "", "x" * 65, "-a", "a\nb", "ä"])
def test_station_names_outside_the_alphabet_are_refused(name: str) -> None:
    with pytest.raises(ConfigError) as err:
        check_station(name)
    assert err.value.key == "station"


def test_station_names_inside_the_alphabet_pass() -> None:
    for name in ("rover", "base-1", "A.b_c", "x" * 64, "0"):
        assert check_station(name) == name


def test_looping_exif_photo_is_skipped_and_counted(tmp_path: Path) -> None:
    import datetime as dt

    data = looping_exif_jpeg()
    assert len(data) == 215
    (tmp_path / "loop.jpg").write_bytes(data)
    (tmp_path / "ok.jpg").write_bytes(exif.make_jpeg(dt.datetime(2024, 1, 2, 3, 4, 5)))
    found = exif.scan_photos(tmp_path)
    by_name = {p.name: p for p in found}
    assert "looping EXIF IFD" in by_name["loop.jpg"].error
    assert by_name["ok.jpg"].usable
    match = photos.match(clockoffset.photo_times(found), [])
    assert any("1 photos skipped (no usable EXIF time)" in ln
               for ln in photos.reconciliation_lines(match, found, []))


def test_a_photo_read_while_the_process_is_paused_keeps_its_time(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A good photo is read whatever the machine's load: here every look at the clock finds
    10 s gone (a solve paused beside other work). A wall-clock budget lost such photos."""
    import datetime as dt
    import itertools
    import time

    (tmp_path / "ok.jpg").write_bytes(exif.make_jpeg(dt.datetime(2024, 1, 2, 3, 4, 5)))
    clock = itertools.count(0.0, 10.0)
    monkeypatch.setattr(time, "monotonic", lambda: next(clock))
    (photo,) = exif.scan_photos(tmp_path)
    assert photo.usable, photo.error
    assert photo.exif_second_ns == int(dt.datetime(2024, 1, 2, 3, 4, 5, tzinfo=dt.UTC)
                                       .timestamp()) * 1_000_000_000


def test_csv_cells_are_neutralised_and_geo_txt_skips_names_with_spaces(
    out: outputs.SolveOutput,  # noqa: F811 (the fixture)
) -> None:
    for bad in ("=HYPERLINK(\"x\")", "+1", "-1", "@SUM(A1)", "\tx", "\rx"):
        assert outputs.text_cell(bad).startswith("'")
    assert outputs.text_cell("IMG_1.JPG") == "IMG_1.JPG"
    assert outputs.text_cell("a\nb") == "a b"
    import dataclasses

    rows = (dataclasses.replace(out.rows[0], photo="=cmd|' /C calc'!A0"),
            dataclasses.replace(out.rows[1], photo="my photo 2.jpg"), *out.rows[2:])
    crafted = dataclasses.replace(out, rows=rows)
    for writer in ("cameras.csv", "reference.csv", "pix4d.csv"):
        text = outputs.WRITERS[writer](crafted)
        assert "\n=cmd" not in text and ",=cmd" not in text and "'=cmd" in text, writer
    geo = outputs.geo_txt(crafted).splitlines()
    assert geo[2] == "# not listed (whitespace or '#' in the name): 'my photo 2.jpg'"
    assert all(len(ln.split()) == 9 for ln in geo[1:] if not ln.startswith("#"))


def test_output_paths_never_replace_inputs_or_recordings(tmp_path: Path) -> None:
    x = tmp_path / "X"
    x.mkdir()
    (x / "cameras.csv").write_text("eo")
    with pytest.raises(ConfigError, match="would replace the input"):
        outputs.check_output_dir(x, [x / "cameras.csv"])
    outputs.check_output_dir(x, [x / "flight.ubx"])  # not a name solve writes
    rec = tmp_path / "r.mcap"
    rec.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(ConfigError, match="existing recording"):
        outpaths.check_output_file(rec, key="--out", force=True)
    with pytest.raises(ConfigError, match="without --force"):
        outpaths.check_output_file(x / "cameras.csv", key="--out")
    outpaths.check_output_file(x / "cameras.csv", key="--out", force=True)
    with pytest.raises(ConfigError, match="is the input"):
        outpaths.check_output_file(tmp_path / "X" / ".." / "r.mcap", [rec], key="--out",
                                   force=True)


def test_staged_files_appear_complete_or_not_at_all(tmp_path: Path) -> None:
    old = tmp_path / "old.txt"
    old.write_text("earlier")
    new = tmp_path / "new.ubx"
    with pytest.raises(RuntimeError), outpaths.staged_files([("--out", new),
                                                             ("--truth", old)]) as (a, b):
        a.write(b"half")
        b.write(b"half")
        raise RuntimeError("disk full")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.txt"]
    assert old.read_text() == "earlier"
    with outpaths.staged_files([("--out", new), ("--truth", old)]) as (a, b):
        a.write(b"stream")
        b.write(b"log")
        assert not new.exists() and old.read_text() == "earlier"  # not before the end
    assert (new.read_bytes(), old.read_text()) == (b"stream", "log")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.ubx", "old.txt"]
    unwritable = [("--out", tmp_path / "x"), ("--truth", tmp_path / "no" / "y")]
    with pytest.raises(ConfigError, match="--truth: cannot write"), \
            outpaths.staged_files(unwritable):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.ubx", "old.txt"]


def test_host_header_check() -> None:
    hosts = frozenset({"127.0.0.1", "localhost", "::1"})
    assert host_ok("127.0.0.1:8080", hosts, 8080) and host_ok("localhost:8080", hosts, 8080)
    assert host_ok("[::1]:8080", hosts, 8080) and host_ok("10.0.0.5:8080", hosts, 8080)
    for bad in ("evil.example:8080", "localhost:9999", "", "localhost:x", "127.0.0.1.nip.io"):
        assert not host_ok(bad, hosts, 8080), bad


@pytest.fixture
def served() -> Iterator[Dashboard]:
    dash = Dashboard(DashboardSettings(stations=("st",), port=0, bus=ZenohSettings()),
                     bus_factory=lambda _s: FakeBus())
    dash.start()
    yield dash
    dash.close()


def _request(dash: Dashboard, path: str, host: str | None) -> http.client.HTTPResponse:
    addr, port = dash.http.server_address[:2]
    conn = http.client.HTTPConnection(str(addr), int(port), timeout=5)
    conn.putrequest("GET", path, skip_host=True)
    if host is not None:
        conn.putheader("Host", host)
    conn.endheaders()
    resp = conn.getresponse()
    resp.read()
    conn.close()
    return resp


def test_dashboard_sends_security_headers_and_refuses_other_hosts(served: Dashboard) -> None:
    port = served.http.server_address[1]
    ok = _request(served, "/", f"127.0.0.1:{port}")
    assert ok.status == 200
    csp = ok.getheader("Content-Security-Policy") or ""
    assert "script-src 'self'" in csp and "frame-ancestors 'none'" in csp
    assert ok.getheader("X-Content-Type-Options") == "nosniff"
    assert ok.getheader("X-Frame-Options") == "DENY"
    for host in (f"attacker.example:{port}", None, "localhost:1"):
        resp = _request(served, "/api/snapshot", host)
        assert resp.status == 421, host
        assert resp.getheader("X-Frame-Options") == "DENY"


def test_bus_encode_round_trip_of_a_session() -> None:
    body = encode("session", {"state": "finished", "files": ["a.mcap"], "session_id": "s"},
                  station="st")
    assert messages.parse(body, "session")["files"] == ["a.mcap"]


def test_ctrl_c_while_a_command_is_still_starting_is_one_line_and_130(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Under load a command's modules take seconds to load (``build_parser`` loads them): a
    Ctrl-C then was a traceback and exit -2 (seen in a replay test on a machine at load 16)."""
    from groundstation import cli

    def loading(argv: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", loading)
    assert cli.main(["replay", "flight.ubx", "--speed", "1"]) == 130
    assert capsys.readouterr().err == "groundstation replay: interrupted\n"
    assert cli.main(["--speed", "1"]) == 130
    assert capsys.readouterr().err == "groundstation: interrupted\n"


def test_ctrl_c_while_the_command_line_itself_loads_is_one_line_and_130(tmp_path: Path) -> None:
    """Before :func:`groundstation.cli.main` runs, its own modules load: a Ctrl-C there was a
    traceback. The program's entry point (``pyproject.toml``) catches it."""
    with (REPO / "pyproject.toml").open("rb") as f:
        assert tomllib.load(f)["project"]["scripts"]["groundstation"] == \
            "groundstation.launch:main"
    code = (
        "import sys\n"
        "class Ctrl_C:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'groundstation.cli':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Ctrl_C())\n"
        "from groundstation.launch import main\n"
        "print('STATUS', main())\n")
    proc = subprocess.run([sys.executable, "-c", code, "solve"], cwd=tmp_path, env=cli_env(),
                          capture_output=True, text=True, timeout=60, check=False)
    assert proc.stdout == "STATUS 130\n", proc
    assert proc.stderr == "groundstation: interrupted\n"
