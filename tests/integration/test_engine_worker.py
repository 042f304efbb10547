"""The demo5 worker process: a fault in C ends the worker, never the caller."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from groundstation.solve.engine import demo5
from groundstation.solve.engine.protocol import EngineError


def test_a_segfault_in_the_worker_is_an_engine_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A worker module that dies the way a bug in RTKLIB's C would: SIGSEGV on a null read.
    (tmp_path / "gs_crashing_worker.py").write_text("import ctypes\nctypes.string_at(0)\n")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), os.environ.get(
        "PYTHONPATH", "")]))
    monkeypatch.setattr(demo5, "WORKER_MODULE", "gs_crashing_worker")
    with pytest.raises(EngineError, match=r"demo5 worker crashed \(SIGSEGV\)"):
        demo5._call_worker({"op": "table"}, tmp_path / "w", 60.0)
    # The caller is alive and the real worker still answers.
    monkeypatch.undo()
    resp = demo5._call_worker({"op": "table"}, tmp_path / "w2", 60.0)
    assert resp["rows"][0][0] == "pos1-posmode"


def test_a_bad_request_is_an_engine_error(tmp_path: Path) -> None:
    with pytest.raises(EngineError, match="exit 2"):
        demo5._call_worker({"op": "nonsense"}, tmp_path, 60.0)
