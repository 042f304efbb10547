"""The receiver's own fix as ``foxglove.LocationFix`` (MCAP ``/groundstation/location``), so a map
panel in Foxglove or Lichtblick shows the station."""

from __future__ import annotations

from typing import Any

from groundstation.records import NavSolution
from groundstation.storage.mcapio import json_channel
from groundstation.storage.schemas import LOCATION_FIX_SCHEMA

LOCATION_CHANNEL = json_channel("/groundstation/location", LOCATION_FIX_SCHEMA)


def location_fix(nav: NavSolution, publish_ns: int, frame_id: str) -> dict[str, Any] | None:
    """``nav`` as a LocationFix message stamped ``publish_ns``; None without a position."""
    if nav.lat_deg is None:
        return None
    cov = [0.0] * 9
    cov_type = 0
    if nav.h_acc_m is not None and nav.v_acc_m is not None:
        cov[0] = cov[4] = nav.h_acc_m**2
        cov[8] = nav.v_acc_m**2
        cov_type = 1
    elif nav.p_acc_m is not None:
        cov[0] = cov[4] = cov[8] = nav.p_acc_m**2
        cov_type = 1
    return {
        "timestamp": {"sec": publish_ns // 1_000_000_000, "nsec": publish_ns % 1_000_000_000},
        "frame_id": frame_id,
        "latitude": nav.lat_deg,
        "longitude": nav.lon_deg,
        "altitude": nav.height_m if nav.height_m is not None else 0.0,
        "position_covariance": cov,
        "position_covariance_type": cov_type,
    }
