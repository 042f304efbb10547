"""RTKLIB demo5 (RTKLIB-EX) through ``pyrtklib5``, run in a worker process.

The caller never loads the C library: the option table and every solve come from
``python -m groundstation.solve.engine.worker``, so a fault in C ends the worker, not the
solver service.
"""

from __future__ import annotations

import functools
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, ClassVar

from groundstation import jsonio
from groundstation.solve.engine import options as eo
from groundstation.solve.engine.protocol import (
    EngineError,
    EngineJob,
    EngineRun,
    Progress,
    ToolMissingError,
)

WORKER_MODULE = "groundstation.solve.engine.worker"


def _call_worker(request: dict[str, Any], work: Path, timeout_s: float) -> dict[str, Any]:
    """Run one worker request; the response as a dict.

    Raises:
        ToolMissingError: pyrtklib5 cannot be imported in the worker.
        EngineError: the worker died, timed out or wrote no response.
    """
    # Absolute: the worker runs with ``cwd=work``, where a relative ``work`` would not exist.
    work = work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    req = work / "demo5-request.json"
    resp = work / "demo5-response.json"
    resp.unlink(missing_ok=True)
    req.write_bytes(jsonio.dumps(request))
    cmd = [sys.executable, "-m", WORKER_MODULE, str(req), str(resp)]
    # The worker must import this very package, wherever it is being run from.
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[3])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH", "")) if p)
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, timeout=timeout_s, check=False, env=env,
            cwd=work,
        )
    except subprocess.TimeoutExpired as err:
        raise EngineError(f"demo5 did not finish within {timeout_s:.0f} s") from err
    err_text = (proc.stderr or "").strip()
    if "No module named 'pyrtklib5'" in err_text:
        raise ToolMissingError("demo5 engine needs pyrtklib5: pip install pyrtklib5")
    if proc.returncode < 0:
        sig = signal.Signals(-proc.returncode).name
        raise EngineError(f"demo5 worker crashed ({sig}); the solver itself is unaffected")
    if proc.returncode != 0 or not resp.exists():
        tail = " / ".join(err_text.splitlines()[-3:])
        raise EngineError(f"demo5 worker failed (exit {proc.returncode}): {tail}")
    out: dict[str, Any] = jsonio.loads(resp.read_bytes())
    return out


@functools.lru_cache(maxsize=1)
def _table_and_version() -> tuple[eo.OptionTable, str]:
    with tempfile.TemporaryDirectory(prefix="gs-demo5-") as tmp:
        resp = _call_worker({"op": "table"}, Path(tmp), 120.0)
    table = eo.OptionTable.from_rows("demo5", ((r[0], r[1], r[2]) for r in resp["rows"]))
    return table, f"RTKLIB {resp['version']} ({resp['library']})"


class Demo5Engine:
    """RTKLIB demo5 (RTKLIB-EX 2.5) ``postpos`` via pyrtklib5, in a worker process."""

    name: ClassVar[str] = "demo5"
    defaults: ClassVar[dict[str, str]] = eo.UBLOX_L1_5HZ
    combines_in_house: ClassVar[bool] = True

    def option_table(self) -> eo.OptionTable:
        return _table_and_version()[0]

    def version(self) -> str:
        return _table_and_version()[1]

    def run(self, job: EngineJob, progress: Progress | None = None) -> EngineRun:
        conf = job.work_dir / "demo5.conf"
        conf.write_text(
            eo.conf_text(job.options, [f"groundstation: demo5 options ({self.version()})"]),
            encoding="ascii",
        )
        out = job.work_dir / "rover.pos"
        out.unlink(missing_ok=True)
        resp = _call_worker(
            {
                "op": "postpos",
                "conf": str(conf.resolve()),
                "inputs": [str(p.resolve()) for p in (job.rover_obs, job.base_obs, *job.nav)],
                "out": str(out.resolve()),
                "options_out": str((job.work_dir / "demo5-effective.conf").resolve()),
                "prog": "groundstation demo5",
            },
            job.work_dir,
            job.timeout_s,
        )
        if resp.get("status") != 0 or not out.exists() or out.stat().st_size == 0:
            raise EngineError(
                f"demo5 postpos failed (status {resp.get('status')}): "
                f"{resp.get('error', 'no solution written')}"
            )
        effective = {str(k): str(v) for k, v in resp["options"]}
        return EngineRun(
            self.name, self.version(), out, job.work_dir / "engine.json", effective, 0.0,
        )
