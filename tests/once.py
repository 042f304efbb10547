"""Work several test modules need, done once per test run, whichever worker asks first.

With pytest-xdist each worker has its own session; a session fixture alone would make the same
demo flight once per worker. :func:`made_once` keeps the result in the run's shared temporary
folder under a file lock: the first worker makes it, the others wait and read it. Results are
read-only for their users (each test writes its own outputs elsewhere).
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from peers import cli_env

RTKLIB_PROGRAMS = {"rnx2rtkp", "convbin", "rtkrcv", "str2str", "pos2kml", "rtkpost"}


def made_once(factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]) -> Path:
    """The folder ``name``, filled by ``make(folder)`` once for the whole run (all workers)."""
    base = factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (folder / ".done").exists():
            shutil.rmtree(folder, ignore_errors=True)  # a worker that failed half way
            folder.mkdir()
            make(folder)
            (folder / ".done").touch()
    return folder


def path_without_rtklib(shadow: Path) -> str:
    """A PATH with every program of today's PATH except RTKLIB's (symlinks in ``shadow``)."""
    shadow.mkdir(parents=True, exist_ok=True)
    for d in os.environ.get("PATH", "").split(os.pathsep):
        if not d or not Path(d).is_dir():
            continue
        for exe in Path(d).iterdir():
            link = shadow / exe.name
            if exe.name not in RTKLIB_PROGRAMS and not link.exists() and not link.is_symlink():
                link.symlink_to(exe)
    return str(shadow)


def cli_without_rtklib(*args: str, cwd: Path,
                       timeout_s: float = 180.0) -> subprocess.CompletedProcess[str]:
    """``groundstation *args`` with no RTKLIB program on PATH, as after a plain pip install."""
    env = {**os.environ, "PATH": path_without_rtklib(cwd / "bin-without-rtklib")}
    assert shutil.which("rnx2rtkp", path=env["PATH"]) is None
    return subprocess.run([sys.executable, "-m", "groundstation.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout_s, check=False)


@dataclass(frozen=True)
class DemoFlight:
    """A finished ``groundstation demo`` run: what it printed and the files it names."""

    stdout: str
    files: dict[str, Path]
    """``MCAP``, ``base UBX``, ``truth`` as its summary names them."""


def demo_flight_300(factory: pytest.TempPathFactory) -> DemoFlight:
    """``groundstation demo --flight 300 --speed max --seed 4 --no-zenoh`` (no RTKLIB on
    PATH), run once for the whole test run."""
    def make(d: Path) -> None:
        proc = cli_without_rtklib("demo", "--flight", "300", "--speed", "max", "--out-dir",
                                  str(d / "flights"), "--no-zenoh", "--seed", "4", cwd=d)
        assert proc.returncode == 0, proc.stderr
        (d / "stdout.txt").write_text(proc.stdout)

    d = made_once(factory, "demo-300-seed4", make)
    stdout = (d / "stdout.txt").read_text()
    files = {k: Path(v) for k, v in
             re.findall(r"^\s+(MCAP|base UBX|truth):\s+(\S+)$", stdout, re.M)}
    return DemoFlight(stdout, files)


JD_1009 = "real/jdesbonnet__GNSS_RTK_data/20181009"
JD_1009_BASE_ECEF = (3774696.5547, -596647.9083, 5089485.6511)
"""The 2018-10-09 base's coordinates (RTKLIB's "ref pos" of its solution)."""
JD_1009_BASE_XYZ = ",".join(f"{v:.4f}" for v in JD_1009_BASE_ECEF)
"""The same as ``--base-xyz`` takes them."""


def jd_1009_solved(factory: pytest.TempPathFactory, shared_data: Path) -> Path:
    """``groundstation solve --no-pdf`` of the real 2018-10-09 flight against its base at
    :data:`JD_1009_BASE_XYZ` (a result folder, read only), made once for the whole run."""
    def make(d: Path) -> None:
        proc = subprocess.run(
            [sys.executable, "-m", "groundstation.cli", "solve", "--no-pdf",
             str(shared_data / JD_1009 / "rover-20181009-1221.ubx.gz"),
             "--base", str(shared_data / JD_1009 / "base-20181009-1220.ubx.gz"),
             "--base-xyz", JD_1009_BASE_XYZ, "--out-dir", str(d / "out"), "--no-progress"],
            cwd=d, env=cli_env(), capture_output=True, text=True, timeout=600, check=False)
        assert proc.returncode == 0, proc.stderr

    return made_once(factory, "jd-1009-base-xyz", make) / "out"
