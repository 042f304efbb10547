"""Shared fixtures: where the real recordings are, and skipping cleanly when they are absent."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from peers import Daemon, Pty

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the checkout; tests that need it skip when it is absent."""
    if not (SHARED_DATA / "real").is_dir():
        pytest.skip(
            f"real recordings not available: {SHARED_DATA} is absent "
            "(a fresh clone has no ../shared)"
        )
    return SHARED_DATA


@pytest.fixture
def pty(tmp_path: Path) -> Iterator[Pty]:
    """A pty pair; the daemon opens it through a symlink that can be pulled and plugged."""
    p = Pty(tmp_path / "ttyGS0")
    yield p
    p.close()


@pytest.fixture
def daemons() -> Iterator[list[Daemon]]:
    """Daemon processes started by a test; killed at the end whatever happened."""
    started: list[Daemon] = []
    yield started
    for d in started:
        d.kill()
