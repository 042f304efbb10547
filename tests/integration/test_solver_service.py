"""`groundstation solver` as a real process on loopback: sessions in, solutions out.

The test process plays the daemon's ``session`` messages (as ``live/publisher.py`` encodes them)
for a recording the demo wrote, and subscribes to ``groundstation/*/solution``.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from peers import REPO, Daemon, Received, free_port, wait_until

from groundstation.bus import Bus, encode, key, open_bus
from groundstation.config import ZenohSettings

# One worker runs this module's tests (pytest-xdist): its module fixture records a demo flight,
# made once.
pytestmark = pytest.mark.xdist_group("test_solver_service")


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A recorded demo flight: MCAP, ``<stem>_base.ubx`` beside it, the truth."""
    d = tmp_path_factory.mktemp("solver_flight")
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "demo", "--flight", "120", "--speed", "max",
         "--out-dir", str(d / "flights"), "--no-zenoh", "--seed", "6"],
        cwd=d, capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    paths = dict(re.findall(r"^\s+(MCAP|truth):\s+(\S+)$", proc.stdout, re.M))
    truth = json.loads(Path(paths["truth"]).read_text())
    return {"mcap": Path(paths["MCAP"]), "truth": truth}


class Solutions(Received):
    """Every ``solution`` message on the bus, with its arrival time."""

    def __init__(self, bus: Bus) -> None:
        super().__init__(bus, key("*", "solution"))

    def wait(self, session_id: str, status: str, timeout_s: float = 60.0) -> dict[str, Any]:
        """The first ``status`` solution of the session; fails listing what came instead."""
        def found() -> list[dict[str, Any]]:
            return self.all(lambda m: m.get("session_id") == session_id
                            and m.get("status") == status)

        try:
            return wait_until(found, timeout_s, poll_s=0.05)[0]
        except AssertionError:
            seen = [(m.get("station"), m.get("session_id"), m.get("status"))
                    for m in self.all()]
            raise AssertionError(f"no {status} solution for {session_id}; got {seen}") from None

    def of(self, session_id: str) -> list[tuple[float, dict[str, Any]]]:
        return self.timed(lambda m: m.get("session_id") == session_id)


def session(bus: Bus, station: str, session_id: str, files: list[str],
            state: str = "finished") -> None:
    """The daemon's session message (live/publisher.py)."""
    body = {"state": state, "files": files, "session_id": session_id, "marks": 25}
    bus.put(key(station, "session"), encode("session", body, station=station))


@pytest.fixture
def solver(tmp_path: Path, flight: dict[str, Any],
           daemons: list[Daemon]) -> Iterator[tuple[Bus, Solutions, Daemon, Path]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = open_bus(ZenohSettings(listen=(endpoint,)))
    photos = tmp_path / "photos" / "alpha"
    photos.mkdir(parents=True)
    xyz = ", ".join(f"{v:.4f}" for v in flight["truth"]["base"]["ecef_m"])
    conf = tmp_path / "solver.toml"
    conf.write_text(
        f'out_root = "{tmp_path / "solutions"}"\ninterp = "smoother"\n'
        f'recording_roots = ["{flight["mcap"].parent}", "{tmp_path / "flights"}"]\n\n'
        f'[zenoh]\nconnect = ["{endpoint}"]\nlisten = []\n\n'
        f'[stations.alpha]\nbase = "{{dir}}/{{stem}}_base.ubx"\nbase_xyz = [{xyz}]\n'
        f'photos = "{tmp_path / "photos"}/{{station}}"\nlever_arm = [0.16, -0.03, 0.57]\n'
    )
    d = Daemon("--config", str(conf), command="solver")
    daemons.append(d)
    d.wait_for("listening on groundstation/*/session")
    sols = Solutions(bus)
    # The subscription travels to this peer asynchronously: knock until the solver answers.
    deadline = time.monotonic() + 15
    n = 0
    while True:
        n += 1
        session(bus, "bravo", f"hello-{n}", ["/nowhere/hello.mcap"])
        try:
            sols.wait(f"hello-{n}", "skipped", timeout_s=0.5)
            break
        except AssertionError:
            if time.monotonic() > deadline:
                raise
    yield bus, sols, d, tmp_path
    bus.close()


def test_finished_session_is_solved_and_published(
    solver: tuple[Bus, Solutions, Daemon, Path], flight: dict[str, Any]
) -> None:
    bus, sols, d, tmp = solver
    mcap = str(flight["mcap"])
    session(bus, "alpha", "s1", [mcap], state="started")
    session(bus, "alpha", "s1", [mcap])
    session(bus, "alpha", "s1", [mcap])  # repeated (the daemon re-announces after reconnect)
    solving = sols.wait("s1", "solving", timeout_s=10)
    session(bus, "bravo", "s2", [mcap])  # no base for bravo, while alpha is being solved
    skipped = sols.wait("s2", "skipped", timeout_s=10)
    ok = sols.wait("s1", "ok", timeout_s=90)
    # The service stayed responsive: bravo's answer came while alpha was being solved.
    t = {m["status"]: ts for ts, m in sols.of("s1")}
    (t_skip,) = [ts for ts, _ in sols.of("s2")]
    assert t["solving"] < t_skip < t["ok"]
    assert "no base configured for station 'bravo'" in skipped["reason"]
    assert skipped["schema"] == 1 and skipped["type"] == "solution"
    # The solution message: status, counts, output paths, quality.
    n_marks = len(flight["truth"]["exposures"])
    assert ok["schema"] == 1 and ok["type"] == "solution" and ok["station"] == "alpha"
    assert ok["flight"] == mcap and ok["out_dir"] == solving["out_dir"]
    assert Path(ok["out_dir"]) == tmp / "solutions" / "alpha" / flight["mcap"].stem
    counts, quality = ok["counts"], ok["quality"]
    assert counts["marks"] == n_marks and counts["marks_positioned"] == n_marks
    assert counts["photos_paired"] == 0  # the photo directory is empty
    assert quality["source"] == "demo5" and quality["fixed_fraction"] > 0.9
    assert quality["interp"] == "smoother" and 0 < quality["sd_horizontal_median_m"] < 0.05
    names = {Path(f).name for f in ok["files"]}
    assert {"cameras.csv", "geo.txt", "reference.csv", "pix4d.csv", "cameras.geojson",
            "report.html"} <= names
    assert all(Path(f).is_file() for f in ok["files"])
    # The message names the report (and its PDF when Chromium printed one).
    assert ok["report"] == str(Path(ok["out_dir"]) / "report.html")
    assert ok["report_pdf"] in (None, str(Path(ok["out_dir"]) / "report.pdf"))
    assert any("lever arm" in n for n in ok["notes"])
    # Solved once, whatever the repeats; nothing for the started state.
    time.sleep(0.5)
    assert [m["status"] for _, m in sols.of("s1")] == ["solving", "ok"]
    rc, out = d.stop()
    assert rc == 0
    assert "solver: stopped: 1 solved, 0 failed, " in out


def test_missing_recording_fails_and_the_service_goes_on(
    solver: tuple[Bus, Solutions, Daemon, Path], flight: dict[str, Any]
) -> None:
    bus, sols, d, tmp = solver
    gone = str(tmp / "flights" / "alpha_20990101T000000Z.mcap")
    session(bus, "alpha", "s3", [gone])
    failed = sols.wait("s3", "failed", timeout_s=20)
    assert "recording not found" in failed["reason"] and gone in failed["reason"]
    assert d.proc.poll() is None
    # Still there: the next session is handled.
    session(bus, "bravo", "s4", [gone])
    sols.wait("s4", "skipped", timeout_s=10)
    assert d.proc.poll() is None


@pytest.mark.parametrize(("text", "key_name"), [
    ("[stations.alpha]\nbase = \"b.ubx\"\nbase_xyz = [1, 2]\n", "stations.alpha.base_xyz"),
    ("[stations.alpha]\nbase = \"b.ubx\"\n", "stations.alpha.base_xyz"),
    ("[stations.alpha]\nphotoz = \"p\"\n", "stations.alpha.photoz"),
    ("interp = \"cubic\"\n", "interp"),
    ("[zenoh]\nmode = \"router\"\n", "zenoh.mode"),
    ("queue_size = 0\n", "queue_size"),
])
def test_bad_config_exits_2_naming_the_key(tmp_path: Path, text: str, key_name: str) -> None:
    conf = tmp_path / "solver.toml"
    conf.write_text(text)
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "solver", "--config", str(conf)],
        cwd=REPO, capture_output=True, text=True, timeout=60, check=False,
    )
    assert proc.returncode == 2, proc.stderr
    assert f"configuration error: {key_name}:" in proc.stderr


def test_crafted_sessions_are_refused_and_a_recording_is_solved_once(
    solver: tuple[Bus, Solutions, Daemon, Path], flight: dict[str, Any]
) -> None:
    bus, sols, d, tmp = solver
    elsewhere = tmp / "elsewhere"
    elsewhere.mkdir()
    outside = elsewhere / flight["mcap"].name
    shutil.copy(flight["mcap"], outside)
    before = sorted(p.name for p in elsewhere.iterdir())
    session(bus, "alpha", "c1", ["/etc/shadow"])
    session(bus, "alpha", "c2", [str(outside)])
    session(bus, "alpha", "c3", [str(flight["mcap"].parent / ".." / "x" / "a.mcap")])
    for sid in ("c1", "c2", "c3"):
        refused = sols.wait(sid, "refused", timeout_s=10)
        assert refused["reason"].startswith("refused:"), refused
        assert "exist" not in refused["reason"] and "found" not in refused["reason"]
    # a station named ".." (or a wildcard) is dropped without an answer
    bus.put("groundstation/../session", encode("session", {
        "state": "finished", "files": [str(flight["mcap"])], "session_id": "c4"}))
    # the same recording three times, and a copy of its bytes under another name in a root
    copy = tmp / "flights" / "copy_of_flight.mcap"
    copy.parent.mkdir(exist_ok=True)
    shutil.copy(flight["mcap"], copy)
    for sid in ("r1", "r1", "r2"):
        session(bus, "alpha", sid, [str(flight["mcap"])])
    sols.wait("r1", "ok", timeout_s=120)
    session(bus, "alpha", "r3", [str(copy)])
    skipped = sols.wait("r3", "skipped", timeout_s=30)
    assert "already solved" in skipped["reason"]
    time.sleep(1.0)
    assert not sols.of("c4")
    assert [m["status"] for _, m in sols.of("r1")] == ["solving", "ok"]
    assert [m["status"] for _, m in sols.of("r2")] in (["solving", "skipped"], [])
    # nothing written outside out_root, nothing added next to the refused recording
    assert sorted(p.name for p in elsewhere.iterdir()) == before
    assert sorted(p.name for p in (tmp / "solutions").iterdir()) == ["alpha"]
    rc, out = d.stop()
    assert rc == 0
    assert "1 solved" in out and "3 refused" in out and "messages dropped" in out
