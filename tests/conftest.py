"""Shared fixtures: where the real recordings are, and skipping cleanly when they are absent."""

from __future__ import annotations

from pathlib import Path

import pytest

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
