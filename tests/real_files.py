"""The real UBX recordings in ``../shared/data/real`` (every one the tests run over)."""

from __future__ import annotations

from pathlib import Path

import pytest

REAL_UBX_FILES = [
    "tomojitakasu__RTKLIB/test/data/rcvraw/ubx_20080526.ubx",
    "tridge__pyUblox/data/6P-raw-PPP.ubx",
    "tridge__pyUblox/data/6P-raw-PPP-2.ubx",
    "gpsd__gpsd-mirror/test/daemon/ublox-aek-4t.log",
    "gpsd__gpsd-mirror/test/daemon/ublox-lea-4t.log",
    "gpsd__gpsd-mirror/test/daemon/ublox-neo-m8t.log",
    "gpsd__gpsd-mirror/test/daemon/ublox-zed-f9p_hpg1.11.log",
    "jdesbonnet__GNSS_RTK_data/20181004/rover-20181004-1237.ubx.gz",
    "jdesbonnet__GNSS_RTK_data/20181004/base-20181004-1236.ubx.gz",
    "jdesbonnet__GNSS_RTK_data/20181004/rover-20181004-1532.ubx.gz",
    "jdesbonnet__GNSS_RTK_data/20181004/base-20181004-1452.ubx.gz",
    "jdesbonnet__GNSS_RTK_data/20181009/rover-20181009-1221.ubx.gz",
    "jdesbonnet__GNSS_RTK_data/20181009/base-20181009-1220.ubx.gz",
    "jdesbonnet__GNSS_RTK_data/20181104/rover-20181104-1634.ubx.gz",
    "nav-solutions__data/UBX/16dBatt_no_interference_coldstart.ubx.gz",
    "rtklibexplorer__GNSS_IMU/data/walk_0827/gnss_1730.ubx",
]


def real_bytes(shared_data: Path, name: str) -> bytes:
    """All bytes of one recording (decompressed); skips the test when the file is absent."""
    from groundstation.offline.rinex import read_recording

    path = shared_data / "real" / name
    if not path.exists():
        pytest.skip(f"{path} is absent")
    return read_recording(path)
