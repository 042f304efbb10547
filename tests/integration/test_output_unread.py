"""A command whose work is files finishes it when nobody reads its printout any more
(``solve ... | head -1``, a pager quit early): it used to stop half-way, exit 0 and write
nothing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from peers import cli_env

from groundstation.sim.profiles import sim_config
from groundstation.sim.stream import simulate


def test_solve_piped_into_head_still_writes_its_result(tmp_path: Path) -> None:
    sim = simulate(sim_config(duration_s=60.0))
    (tmp_path / "r.ubx").write_bytes(sim.rover_bytes)
    (tmp_path / "b.ubx").write_bytes(sim.base_bytes)
    xyz = ",".join(f"{v:.4f}" for v in sim.truth["base"]["ecef_m"])
    proc = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "solve", "--no-pdf", "r.ubx", "--base", "b.ubx",
         "--base-xyz", xyz, "--out-dir", "sol"],
        cwd=tmp_path, env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    assert proc.stdout is not None
    first = proc.stdout.readline()  # what `| head -1` reads, then it goes away
    proc.stdout.close()
    assert proc.wait(timeout=300) == 0, first
    assert (tmp_path / "sol" / "cameras.csv").is_file()
    assert (tmp_path / "sol" / "report.html").is_file()
