"""The receiver's own fix as ``foxglove.LocationFix`` (MCAP ``/groundstation/location``), so a map
panel in Foxglove or Lichtblick shows the station: one per epoch, from the first solution of
that epoch with a position (the session recorder skips the others of the same instant)."""

from __future__ import annotations

import msgspec

from groundstation import jsonio
from groundstation.records import NavSolution
from groundstation.storage.mcapio import json_channel
from groundstation.storage.schemas import LOCATION_FIX_SCHEMA

LOCATION_CHANNEL = json_channel("/groundstation/location", LOCATION_FIX_SCHEMA)


class _Time(msgspec.Struct):
    sec: int
    nsec: int


class _LocationFix(msgspec.Struct):
    """The message, field for field in the schema's order (a Struct is written without a
    dict being built: one is recorded per NavSolution)."""

    timestamp: _Time
    frame_id: str
    latitude: float
    longitude: float | None  # set with latitude by every decoder
    altitude: float
    position_covariance: list[float]
    position_covariance_type: int


def location_fix(nav: NavSolution, publish_ns: int, frame_id: str) -> bytes | None:
    """``nav`` as a LocationFix message (JSON) stamped ``publish_ns``; None without a
    position."""
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
    return jsonio.dumps(_LocationFix(
        _Time(publish_ns // 1_000_000_000, publish_ns % 1_000_000_000), frame_id, nav.lat_deg,
        nav.lon_deg, nav.height_m if nav.height_m is not None else 0.0, cov, cov_type,
    ))
