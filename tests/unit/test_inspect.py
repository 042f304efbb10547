"""``groundstation inspect`` on streams the tests generate: gaps, marks, damage, JSON and text."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
from pathlib import Path

from streams import WEEK, flight_stream, rxm_raw, tim_tm2

from groundstation.offline.inspect import inspect_path


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", *args],
        capture_output=True, text=True, timeout=60, check=False,
    )


def test_gaps_and_marks(tmp_path: Path) -> None:
    data, _ = flight_stream(100, drop_epochs={10, 11, 12, 50})
    # A missed mark: count jumps from the stream's last count to +3.
    data += rxm_raw(WEEK, 345_600_000 + 200 * 100, [(3, 0)])
    data += tim_tm2(30, WEEK, 345_600_000 + 200 * 100 + 50, 0, None)
    path = tmp_path / "flight.ubx"
    path.write_bytes(data)
    s = inspect_path(path)
    assert s.epochs == 97
    assert s.epoch_interval_s == 0.2
    assert [g.missing_epochs for g in s.gaps] == [3, 1]
    assert s.missing_epochs == 4
    assert s.messages == {"RXM-RAW": 97, "TIM-TM2": 39}  # epoch 12 took its mark along
    tm = s.timemarks
    assert (tm.records, tm.falling, tm.rising) == (39, 20, 19)
    # the last rising-edge record said 19 pulses; this falling-edge record says 30 before its
    # own: pulses 20 to 30 never arrived
    assert (tm.count_jumps, tm.missed_marks) == (1, 11)
    assert s.satellites == ("G03", "G07", "G11", "G19", "G23")
    assert s.damaged_frames == 0 and s.garbage_bytes == 0


def test_cli_json_on_gzip_with_damage(tmp_path: Path) -> None:
    data, frames = flight_stream(20)
    damaged = bytearray(data)
    damaged[len(frames[0]) + 30] ^= 0x55  # corrupt the second frame's payload
    path = tmp_path / "damaged.ubx.gz"
    path.write_bytes(gzip.compress(bytes(damaged)))
    res = run_cli("inspect", str(path), "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["format"] == "gzip"
    assert out["damaged_frames"] == 1
    assert out["garbage_bytes"] == len(frames[1])
    assert out["messages"]["RXM-RAW"] + out["messages"]["TIM-TM2"] == len(frames) - 1
    assert set(out["timemarks"]) >= {"records", "falling", "rising", "count_jumps"}
    assert isinstance(out["gaps"], list) and out["epochs"] == out["messages"]["RXM-RAW"]


def test_cli_text_summary(tmp_path: Path) -> None:
    data, _ = flight_stream(30, drop_epochs={5})
    path = tmp_path / "f.ubx"
    path.write_bytes(data)
    res = run_cli("inspect", str(path))
    assert res.returncode == 0, res.stderr
    assert "1 gaps, 1 epochs missing" in res.stdout
    assert "RXM-RAW" in res.stdout and "falling edges" in res.stdout


def test_cli_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    res = run_cli("inspect", str(tmp_path / "nope.ubx"))
    assert res.returncode == 2  # bad input (README: exit statuses)
    assert "no such file" in res.stderr
    assert "Traceback" not in res.stderr
