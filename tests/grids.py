"""Whether PROJ has the geoid grids the height tests need (Debian's proj-data, installed by CI;
the tests that need one skip with this reason without it)."""

from __future__ import annotations

from pathlib import Path

import pytest

from groundstation.solve.outputs import SYSTEM_GRID_DIRS


def egm96_available() -> bool:
    import pyproj

    dirs = [*SYSTEM_GRID_DIRS, Path(pyproj.datadir.get_user_data_dir())]  # type: ignore[attr-defined]
    return any((d / g).is_file() for d in dirs
               for g in ("egm96_15.gtx", "us_nga_egm96_15.tif"))


needs_egm96 = pytest.mark.skipif(not egm96_available(),
                                 reason="no EGM96 grid (apt install proj-data)")
