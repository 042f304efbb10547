"""The README's field steps, run verbatim, with a pty standing in for the Wi232 radio.

The commands are read out of README.md's "In the field" section (numbered steps 1 to 3), so the
README cannot drift from what works. Three substitutions only: ``/dev/wi232`` is the pty's path,
``FLIGHT`` the recording the daemon named at its end, and ``groundstation`` is this tree's
``python -m groundstation.cli``. The Zenoh endpoint is
moved off the default port through the environment (``GROUNDSTATION_ZENOH_LISTEN``,
``GROUNDSTATION_WATCH_ZENOH_CONNECT``), so the commands stay as written while other tests run.
The ``solve`` line holds placeholders (BASE.ubx, X,Y,Z, DIR) and is solved elsewhere
(``test_solve_demo.py``); it is checked here to name existing options only.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
from pathlib import Path

from peers import REPO, Pty, free_port

from groundstation.pacing import paced
from groundstation.sim.stream import SimConfig, simulate


def field_commands() -> list[str]:
    """Every ``groundstation ...`` code span of the numbered steps, in order."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## In the field", 1)[1].split("\n## ", 1)[0]
    steps = section[section.index("\n1. "):section.index("\nExit status")]
    spans = re.findall(r"`([^`]+)`", steps.replace("\n   ", " "))
    return [s for s in spans if s.startswith("groundstation ")]


def _argv(command: str, pty: Pty) -> list[str]:
    words = shlex.split(command.replace("/dev/wi232", str(pty.link)))
    assert words[0] == "groundstation"
    return [sys.executable, "-m", "groundstation.cli", *words[1:]]


def _feed(pty: Pty, stop: threading.Event) -> None:
    """The flight's stream at 6x real time, from 70 s in (the camera fires from 78 s to 101 s)."""
    sim = simulate(SimConfig(duration_s=200, with_base=False))
    t0 = sim.rover_chunks[0][0]
    chunks = [c for c in sim.rover_chunks if t0 + 70e9 <= c[0] < t0 + 140e9]
    for _, chunk in paced(chunks, 6.0):
        if stop.is_set():
            return
        with contextlib.suppress(OSError):
            pty.write(chunk)


def test_readme_field_steps_run_verbatim(tmp_path: Path, pty: Pty) -> None:
    commands = field_commands()
    run_cmd, dashboard_cmd, watch_cmd, inspect_cmd, rinex_cmd, solve_cmd = commands
    assert run_cmd == "groundstation run --port /dev/wi232 --baud 57600 --station rover"
    assert dashboard_cmd == "groundstation dashboard --station rover"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {**os.environ, "GROUNDSTATION_ZENOH_LISTEN": endpoint,
           "GROUNDSTATION_WATCH_ZENOH_CONNECT": endpoint, "COLUMNS": "100",
           "PYTHONPATH": os.pathsep.join((str(REPO), os.environ.get("PYTHONPATH", "")))}

    # 1. Before the flight: the daemon on the radio, and the terminal view.
    daemon = subprocess.Popen(_argv(run_cmd, pty), cwd=tmp_path, env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stop = threading.Event()
    feeder = threading.Thread(target=_feed, args=(pty, stop), daemon=True)
    watch = None
    try:
        feeder.start()
        watch = subprocess.Popen(_argv(watch_cmd, pty), cwd=tmp_path, env=env, text=True,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        # 2. During the flight: the stream flows for ~12 s.
        feeder.join(timeout=60)
        watch.send_signal(signal.SIGINT)
        w_out, w_err = watch.communicate(timeout=20)
        assert watch.returncode == 0, w_err
        assert "station rover" in w_out and "ALERTS" in w_out, w_out[-2000:]
        # 3. After landing: Ctrl-C ends the daemon.
        daemon.send_signal(signal.SIGINT)
        out, err = daemon.communicate(timeout=30)
        assert daemon.returncode == 0, err
        assert "stopped by signal" in out or "stopped by" in out, out
    finally:
        stop.set()
        for proc in (daemon, watch):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    (mcap,) = (tmp_path / "flights").glob("rover_*.mcap")
    for command in (inspect_cmd, rinex_cmd):
        assert "FLIGHT" in command, command
        assert mcap.name in out + err, out  # the daemon names the flight at its end
        words = command.replace("FLIGHT", str(mcap.relative_to(tmp_path))).split()
        assert words[0] == "groundstation"
        shell = " ".join([shlex.quote(sys.executable), "-m", "groundstation.cli", *words[1:]])
        done = subprocess.run(shell, shell=True, cwd=tmp_path, env=env, text=True,
                              capture_output=True, timeout=300, check=False)
        assert done.returncode == 0, done.stderr
    assert (tmp_path / "rinex").is_dir() and any((tmp_path / "rinex").iterdir())
    summary = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "inspect", str(mcap)], cwd=tmp_path,
        env=env, text=True, capture_output=True, check=True).stdout
    assert re.search(r"marks\s+\d+ time-mark records", summary), summary
    # The solve line: placeholders, but every option in it exists.
    help_text = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "solve", "--help"], cwd=tmp_path, env=env,
        text=True, capture_output=True, check=True).stdout
    for option in re.findall(r"--[a-z-]+", solve_cmd):
        assert option in help_text, option
