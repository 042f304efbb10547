"""Debian's RTKLIB 2.4.3 b34 ``rnx2rtkp`` as a subprocess (``--engine rnx2rtkp``)."""

from __future__ import annotations

import logging
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar

from groundstation.solve.engine import options as eo
from groundstation.solve.engine.b34_table import SYSOPTS_B34
from groundstation.solve.engine.protocol import (
    EngineError,
    EngineJob,
    EngineRun,
    Progress,
    ToolMissingError,
)

log = logging.getLogger("groundstation.solve")

RNX2RTKP = "rnx2rtkp"
TABLE_B34 = eo.OptionTable.from_rows("rnx2rtkp 2.4.3 b34", SYSOPTS_B34)


def rnx2rtkp_command(
    exe: str, conf: Path, out: Path, rover_obs: Path, base_obs: Path, nav: Sequence[Path]
) -> list[str]:
    """The argument list (no shell) that runs rnx2rtkp on rover + base + navigation files."""
    return [exe, "-k", str(conf), "-o", str(out), str(rover_obs), str(base_obs), *map(str, nav)]


def find_rnx2rtkp(exe: str | None = None) -> str:
    """Full path of rnx2rtkp.

    Raises:
        ToolMissingError: not on PATH.
    """
    path = shutil.which(exe or RNX2RTKP)
    if path is None:
        raise ToolMissingError(
            f"{exe or RNX2RTKP} not found: install RTKLIB (e.g. `apt-get install rtklib`), "
            "use the default engine (--engine demo5) or give --positions FILE.pos"
        )
    return path


class Rnx2rtkpEngine:
    """RTKLIB 2.4.3 b34 ``rnx2rtkp -k CONF`` (GPS L1 settings; no demo5 AR controls)."""

    name: ClassVar[str] = "rnx2rtkp"
    defaults: ClassVar[dict[str, str]] = eo.B34_L1_KINEMATIC
    # b34 stays as Debian ships it (the baseline the issue compares with): its own combination.
    combines_in_house: ClassVar[bool] = False
    exe: ClassVar[str | None] = None

    def option_table(self) -> eo.OptionTable:
        return TABLE_B34

    def version(self) -> str:
        return "RTKLIB 2.4.3 b34 (Debian rnx2rtkp)"

    def run(self, job: EngineJob, progress: Progress | None = None) -> EngineRun:
        exe_path = find_rnx2rtkp(self.exe)
        conf = job.work_dir / "rnx2rtkp.conf"
        conf.write_text(
            eo.conf_text(job.options, [f"groundstation: rnx2rtkp options ({self.version()})"]),
            encoding="ascii",
        )
        out = job.work_dir / "rover.pos"
        out.unlink(missing_ok=True)
        cmd = rnx2rtkp_command(exe_path, conf, out, job.rover_obs, job.base_obs, job.nav)
        log.info("running %s", " ".join(cmd))
        try:
            proc = subprocess.run(
                cmd, capture_output=True, text=True, timeout=job.timeout_s, check=False
            )
        except subprocess.TimeoutExpired as err:
            raise EngineError(f"rnx2rtkp did not finish within {job.timeout_s:.0f} s") from err
        if proc.returncode != 0 or not out.exists() or out.stat().st_size == 0:
            tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-3:]
            raise EngineError(f"rnx2rtkp failed (exit {proc.returncode}): {' / '.join(tail)}")
        return EngineRun(
            self.name, self.version(), out, job.work_dir / "engine.json", dict(job.options), 0.0,
            ("rnx2rtkp: options not listed are b34's built-in defaults",),
        )
