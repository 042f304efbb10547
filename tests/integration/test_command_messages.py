"""What commands say, as a user runs them: one clean line for a bad output directory or a
missing port, the right words for two outputs named alike, the default station, a dashboard
open to the network, and rinex's progress only on a terminal."""

from __future__ import annotations

import gzip
import os
import subprocess
import sys
from pathlib import Path

import pytest
from peers import cli_env, free_port, read_terminal
from streams import flight_stream

ROVER = "real/jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz"


def _cli(cwd: Path, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "groundstation.cli", *argv], cwd=cwd,
                          env=cli_env(), capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL, check=False)


def _one_line(proc: subprocess.CompletedProcess[str]) -> str:
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Errno" not in lines[0] and "Traceback" not in proc.stderr
    return lines[0]


@pytest.mark.parametrize(("out_dir", "says"), [
    ("/proc/nope", "--out-dir: cannot create /proc/nope"),
    ("afile", "--out-dir: afile is not a directory"),
])
def test_run_refuses_an_output_directory_like_every_writer(tmp_path: Path, out_dir: str,
                                                           says: str) -> None:
    (tmp_path / "good.ubx").write_bytes(flight_stream(5)[0])
    (tmp_path / "afile").write_text("mine\n")
    proc = _cli(tmp_path, "run", "--file", "good.ubx", "--no-zenoh", "--out-dir", out_dir)
    assert proc.returncode == 2, proc.stderr
    assert says in _one_line(proc)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "good.ubx"]


def test_configure_says_a_missing_port_as_run_does(tmp_path: Path) -> None:
    proc = _cli(tmp_path, "configure", "--port", "/dev/nonexistent", "--profile", "lea6t-5hz")
    assert proc.returncode == 1, proc.stderr
    line = _one_line(proc)
    assert line.startswith("groundstation configure: error: /dev/nonexistent does not exist")
    assert "--port" in line


def test_simulate_two_outputs_named_alike_are_not_called_the_input(tmp_path: Path) -> None:
    proc = _cli(tmp_path, "simulate", "--out", "a", "--base-out", "a", "--duration", "5")
    assert proc.returncode == 2, proc.stderr
    line = _one_line(proc)
    assert "--base-out: a is also the --out file" in line and "input" not in line
    assert list(tmp_path.iterdir()) == []


def _nobody() -> str:
    """A Zenoh endpoint of this test's own where no daemon listens (the default one may have
    a daemon of someone else's on this machine)."""
    return f"tcp/127.0.0.1:{free_port()}"


def test_watch_names_the_default_station_once(tmp_path: Path) -> None:
    proc = _cli(tmp_path, "watch", "--duration", "1", "--connect", _nobody())
    assert proc.returncode == 0, proc.stderr
    assert "default station 'station'" in proc.stdout
    assert "station station" not in proc.stdout
    named = _cli(tmp_path, "watch", "--duration", "1", "--station", "bg", "--connect", _nobody())
    assert "groundstation watch · station bg" in named.stdout


def test_dashboard_warns_once_when_open_to_the_network(tmp_path: Path) -> None:
    proc = _cli(tmp_path, "dashboard", "--bind", "0.0.0.0", "--port", "0", "--duration", "1",
                "--connect", _nobody())
    assert proc.returncode == 0, proc.stderr
    warnings = [ln for ln in proc.stderr.splitlines() if "WARNING" in ln]
    assert len(warnings) == 1 and "no authentication" in warnings[0], proc.stderr
    local = _cli(tmp_path, "dashboard", "--port", "0", "--duration", "1", "--connect", _nobody())
    assert local.returncode == 0, local.stderr
    assert "WARNING" not in local.stderr


@pytest.mark.shared_data
def test_rinex_shows_progress_only_on_a_terminal(shared_data: Path, tmp_path: Path) -> None:
    src = shared_data / ROVER
    if not src.exists():
        pytest.skip(f"{src} is absent")
    big = tmp_path / "rover.ubx"
    big.write_bytes(gzip.decompress(src.read_bytes()))  # over the 4 MiB of --progress auto
    piped = _cli(tmp_path, "rinex", "rover.ubx", "-o", "piped")
    assert piped.returncode == 0, piped.stderr
    assert piped.stderr == ""
    # stderr on a real terminal (a pty pair): the progress counter is shown there.
    master, slave = os.openpty()
    try:
        proc = subprocess.Popen([sys.executable, "-m", "groundstation.cli", "rinex", "rover.ubx",
                                 "-o", "tty"], cwd=tmp_path, env=cli_env(),
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=slave)
        os.close(slave)
        seen = read_terminal(master, 120)
        assert proc.wait(timeout=120) == 0
    finally:
        os.close(master)
    assert "rinex: read" in seen
