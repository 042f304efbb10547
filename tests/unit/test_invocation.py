"""The command that hint lines print (groundstation.invocation): as the user ran the program,
so that a pasted line runs. Real executables in a temporary directory, ``PATH`` set per case."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from groundstation import invocation


def _exe(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("#!/bin/sh\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


@pytest.fixture
def venv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    _exe(tmp_path / ".venv" / "bin" / "groundstation")
    _exe(tmp_path / ".venv" / "bin" / "python3")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    return tmp_path / ".venv" / "bin"


def test_the_venv_script_off_path_is_named_by_its_path(venv: Path) -> None:
    assert invocation.program(".venv/bin/groundstation", "") == ".venv/bin/groundstation"


def test_the_script_on_path_is_named_groundstation(
        venv: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(venv))
    assert invocation.program(str(venv / "groundstation"), "") == "groundstation"
    assert invocation.program("groundstation", "") == "groundstation"


def test_another_groundstation_on_path_does_not_count(
        venv: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    other = _exe(tmp_path / "elsewhere" / "groundstation")
    monkeypatch.setenv("PATH", str(other.parent))
    assert invocation.program(".venv/bin/groundstation", "") == ".venv/bin/groundstation"


def test_python_m_names_the_interpreter(venv: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cli = str(Path(invocation.__file__).with_name("cli.py"))
    python = str(venv / "python3")
    assert invocation.program(cli, python) == f"{python} -m groundstation.cli"
    monkeypatch.setenv("PATH", str(venv))
    assert invocation.program(cli, python) == "python3 -m groundstation.cli"


def test_paths_with_spaces_are_quoted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    script = _exe(tmp_path / "my venv" / "bin" / "groundstation")
    monkeypatch.setenv("PATH", os.devnull)
    assert invocation.program(str(script), "") == f"'{script}'"


def test_command_and_examples_use_the_program(
        venv: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sys.argv", [".venv/bin/groundstation", "demo"])
    assert invocation.command("solve", "a b.mcap") == ".venv/bin/groundstation solve 'a b.mcap'"
    assert invocation.examples("  groundstation demo\nsee groundstation docs") == (
        "  .venv/bin/groundstation demo\nsee groundstation docs")
