"""The demo hands over to the solver: its "next:" line runs as printed, and a solver service
started in another directory solves the demo's session from the bus.

The daemon's session message names its recordings by absolute path (a relative ``flights/...``
meant nothing to a solver whose working directory is elsewhere).
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from peers import CliProc, Daemon, cli_env, free_port, wait_until

BASE_XYZ = "4146349.2471, 612312.5498, 4791750.8505"
"""The simulator's base (its default site), as the demo's truth file gives it."""


def test_demo_photos_and_its_next_solve_line(tmp_path: Path) -> None:
    demo = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "demo", "--flight", "120", "--speed", "max",
         "--no-zenoh", "--no-view", "--photos", "photos"],
        cwd=tmp_path, env=cli_env(), capture_output=True, text=True, timeout=300, check=False)
    assert demo.returncode == 0, demo.stderr
    jpegs = sorted((tmp_path / "photos").glob("*.JPG")) + sorted(
        (tmp_path / "photos").glob("*.jpg"))
    assert jpegs, demo.stdout
    # Run as python -m groundstation.cli: the line says so, and runs pasted verbatim.
    (line,) = [x for x in demo.stdout.splitlines() if x.startswith("next: ") and " solve " in x]
    words = shlex.split(line.removeprefix("next: "))
    assert words[1:4] == ["-m", "groundstation.cli", "solve"], line
    assert "--base-xyz" in words and "<" not in line  # filled in, not a placeholder
    proc = subprocess.run(line.removeprefix("next: ") + " --no-progress", shell=True,
                          cwd=tmp_path, env=cli_env(), capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    assert f"{len(jpegs)} positioned" in proc.stdout or "positioned" in proc.stdout
    assert "WARNING" not in proc.stdout  # the base filled in is the right one


def test_next_lines_run_verbatim_from_the_venv_script_not_on_path(tmp_path: Path) -> None:
    """The README's quick start: ``.venv/bin/groundstation demo`` without activating the venv
    (the script is not on ``PATH``): the next lines name the script by the path it was run by,
    and run as printed (a bare ``groundstation`` would exit 127)."""
    script = Path(sys.executable).parent / "groundstation"
    if not script.is_file():
        pytest.skip(f"no groundstation script next to {sys.executable} (package not installed)")
    env = cli_env()
    env["PATH"] = os.pathsep.join(
        d for d in env.get("PATH", "").split(os.pathsep)
        if d and not (Path(d) / "groundstation").exists())
    assert shutil.which("groundstation", path=env["PATH"]) is None
    rel = os.path.relpath(script, tmp_path)
    demo = subprocess.run([rel, "demo", "--flight", "120", "--speed", "max", "--no-zenoh",
                           "--no-view"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300, check=False)
    assert demo.returncode == 0, demo.stderr
    nexts = [x.removeprefix("next: ") for x in demo.stdout.splitlines()
             if x.startswith("next: ")]
    assert len(nexts) == 2 and all(shlex.split(x)[0] == rel for x in nexts), nexts
    for line in nexts:
        extra = " --no-progress" if " solve " in line else ""
        proc = subprocess.run(line + extra, shell=True, cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=300, check=False)
        assert proc.returncode == 0, (line, proc.stderr)


def test_solver_in_another_directory_solves_the_demo_session(
    tmp_path: Path, daemons: list[Daemon]
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    field, office = tmp_path / "field", tmp_path / "office"
    field.mkdir()
    office.mkdir()
    conf = office / "solver.toml"
    conf.write_text(
        f'out_root = "solutions"\nrecording_roots = ["{field / "flights"}"]\n\n'
        f'[zenoh]\nconnect = ["{endpoint}"]\nlisten = []\n\n'
        f'[stations.demo]\nbase = "{{dir}}/{{stem}}_base.ubx"\nbase_xyz = [{BASE_XYZ}]\n',
        encoding="utf-8")
    demo = CliProc(field, "demo", "--flight", "120", "--speed", "4", "--zenoh-listen", endpoint,
                   "--no-view")  # records to the relative flights/
    try:
        demo.wait_for("demo: publishing on Zenoh")
        solver = CliProc(office, "solver", "--config", str(conf))
        try:
            assert demo.proc.wait(timeout=180) == 0, demo.stderr()
            wait_until(lambda: " solved in " in solver.stderr() or "failed" in solver.stderr(),
                       120, "the solver's verdict", poll_s=0.2)
        finally:
            solver.stop()
    finally:
        demo.stop()
    said = solver.stderr()
    (solved,) = [x for x in said.splitlines() if " solved in " in x]
    assert f"{field}/flights/demo_" in solved and "0 positioned" not in solved, said
    (out_dir,) = (office / "solutions" / "demo").iterdir()
    assert (out_dir / "cameras.csv").is_file() and (out_dir / "geo.txt").is_file()
