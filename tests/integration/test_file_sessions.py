"""A recorded session read back through ``run --file``, ``inspect``, ``rinex`` and ``solve``:
MCAP or its ``.ubx`` sidecar, whole or split in parts by rotation, all read as the same session.

The session: a simulated flight (with link faults) run through the real pipeline from a
``.ubx`` file (``U``), then ``U.mcap`` run again with a small rotation size (``S``, in parts,
keeping ``U``'s recorded chunk times).
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest
from peers import REPO

from groundstation.config import load_settings
from groundstation.live.daemon import RunSummary, run_daemon
from groundstation.offline import rinex
from groundstation.offline.inspect import inspect_path
from groundstation.sim.faults import FaultConfig
from groundstation.sim.stream import SimConfig, simulate
from groundstation.solve.flight import read_flight
from groundstation.solve.pipeline import solve
from groundstation.solve.settings import SolveSettings
from groundstation.storage import iter_messages, iter_raw_chunks

# One worker runs this module's tests (pytest-xdist):
# its module fixture simulates and records sessions, made once.
pytestmark = pytest.mark.xdist_group("test_file_sessions")

RECORD_TOPICS = ("/gnss/epoch", "/gnss/timemark", "/gnss/ephemeris", "/gnss/nav",
                 "/gnss/svinfo", "/groundstation/location")


def run_file(path: Path, out: Path, rotate_mb: float = 0.0) -> RunSummary:
    """``groundstation run --file path`` in process (no Zenoh), as fast as possible."""
    settings = load_settings(None, environ={}, overrides={
        "station": "st", "source": {"path": path},
        "recorder": {"out_dir": out, "rotate_size_mb": rotate_mb}, "zenoh": {"enabled": False},
    })
    return asyncio.run(run_daemon(settings))


@dataclass(frozen=True)
class Sessions:
    flight: bytes
    whole: RunSummary  # U: one part
    split: RunSummary  # S: the same chunks, in parts


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> Sessions:
    d = tmp_path_factory.mktemp("sessions")
    sim = simulate(SimConfig(duration_s=150, seed=6, faults=FaultConfig.default(),
                             with_base=False))
    src = d / "flight.ubx"
    src.write_bytes(sim.rover_bytes)
    whole = run_file(src, d / "whole")
    assert len(whole.files) == 1
    split = run_file(whole.files[0], d / "split", rotate_mb=0.08)
    assert len(split.files) >= 3, split.files
    return Sessions(sim.rover_bytes, whole, split)


def raw_of(paths: tuple[Path, ...]) -> list[tuple[bytes, int]]:
    return [c for p in paths for c in iter_raw_chunks(p)]


def records_of(paths: tuple[Path, ...]) -> list[tuple[str, int, dict[str, Any]]]:
    """Decoded records as recorded: topic, GPS time (0 for records without one, published at
    their host time) and body without the host time."""
    out = []
    for p in paths:
        for m in iter_messages(p, RECORD_TOPICS):
            body = json.loads(m.data)
            body.pop("t_host_ns", None)
            gps = 0 if m.publish_time_ns == m.log_time_ns else m.publish_time_ns
            out.append((m.topic, gps, body))
    return out


def test_the_split_session_is_the_whole_one_in_parts(sessions: Sessions) -> None:
    assert raw_of(sessions.split.files) == raw_of(sessions.whole.files)
    assert b"".join(c for c, _ in raw_of(sessions.whole.files)) == sessions.flight


def test_run_file_of_mcap_and_of_sidecar_record_the_same(
    sessions: Sessions, tmp_path: Path
) -> None:
    first_mcap, first_side = sessions.split.files[0], sessions.split.sidecars[0]
    from_mcap = run_file(first_mcap, tmp_path / "m")
    from_side = run_file(first_side, tmp_path / "u")
    for s in (from_mcap, from_side):
        assert s.stopped_by == "end of source"
        assert s.bytes_in == len(sessions.flight)
        assert s.frames == sessions.whole.frames and s.frames > 1000
        assert s.garbage_bytes == sessions.whole.garbage_bytes
        assert s.frames_by_type == sessions.whole.frames_by_type
        assert b"".join(c for c, _ in raw_of(s.files)) == sessions.flight
    # the MCAP's reception times are kept; the sidecar has none, it gets a link's
    assert raw_of(from_mcap.files) == raw_of(sessions.whole.files)
    assert from_mcap.records == from_side.records == sessions.whole.records
    recorded = records_of(from_mcap.files)
    assert len(recorded) > 1000 and sum(gps > 0 for _, gps, _ in recorded) > 500
    assert recorded == records_of(from_side.files) == records_of(sessions.whole.files)


def test_run_file_of_an_mcap_on_the_command_line(sessions: Sessions, tmp_path: Path) -> None:
    lying = tmp_path / "flight.ubx"  # an MCAP by content, whatever its name says
    shutil.copy(sessions.whole.files[0], lying)
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "run", "--file", str(lying), "--no-zenoh",
         "--out-dir", str(tmp_path / "out"), "--station", "cli"],
        cwd=REPO, capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    w = sessions.whole
    assert (f"{w.frames} frames, {w.garbage_bytes} garbage bytes, {w.records} records"
            in proc.stdout), proc.stdout


def test_inspect_reads_the_parts_as_one(sessions: Sessions) -> None:
    whole = inspect_path(sessions.whole.files[0]).as_json()
    split = inspect_path(sessions.split.files[0]).as_json()
    assert split["frames"] > 1000 and split["missing_epochs"] > 0
    for d in (whole, split):
        d.pop("path")
        d.pop("file_bytes")  # on disk: the parts' overheads differ; the stream is the same
    assert split == whole
    side = inspect_path(sessions.split.sidecars[0]).as_json()
    assert side["frames"] == whole["frames"] and side["timemarks"] == whole["timemarks"]


def rinex_text(path: Path) -> list[str]:
    """The file's lines without those naming the run (date, program) or the input."""
    return [line for line in path.read_text().splitlines()
            if "PGM / RUN BY / DATE" not in line and "COMMENT" not in line]


def test_rinex_reads_the_parts_as_one(sessions: Sessions, tmp_path: Path) -> None:
    opts = rinex.RinexOptions(marker="FLIGHT")  # not the input's name
    a = rinex.convert(sessions.whole.files[0], tmp_path / "whole", opts)
    b = rinex.convert(sessions.split.files[0], tmp_path / "split", opts)
    assert a.epochs == b.epochs > 500
    assert replace(b, obs_path=a.obs_path, nav_path=a.nav_path, marks_path=a.marks_path) == a
    for x, y in ((a.obs_path, b.obs_path), (a.nav_path, b.nav_path),
                 (a.marks_path, b.marks_path)):
        assert rinex_text(x) == rinex_text(y), x.name


def test_solve_reads_the_parts_as_one(sessions: Sessions, tmp_path: Path) -> None:
    whole, split = sessions.whole.files[0], sessions.split.files[0]
    assert read_flight(split) == read_flight(whole)
    results = [
        solve(SolveSettings(report_pdf=False, flight=f, out_dir=tmp_path / name, source="receiver"))
        for name, f in (("whole", whole), ("split", split))
    ]
    a, b = results
    assert len(a.marks) > 5  # 150 s leave one short line: 6 exposures with jerk-limited legs
    assert a.rows == b.rows and a.marks == b.marks
