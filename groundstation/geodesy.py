"""WGS84 coordinate conversions: ECEF <-> geodetic <-> local ENU, azimuth and elevation."""

from __future__ import annotations

import math

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


def llh_to_ecef(lat_deg: float, lon_deg: float, h_m: float) -> tuple[float, float, float]:
    """Geodetic latitude, longitude (degrees) and ellipsoidal height to ECEF metres."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    s = math.sin(lat)
    n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * s * s)
    return (
        (n + h_m) * math.cos(lat) * math.cos(lon),
        (n + h_m) * math.cos(lat) * math.sin(lon),
        (n * (1.0 - WGS84_E2) + h_m) * s,
    )


def ecef_to_llh(x_m: float, y_m: float, z_m: float) -> tuple[float, float, float]:
    """ECEF metres to geodetic latitude, longitude (degrees) and ellipsoidal height (m)."""
    p = math.hypot(x_m, y_m)
    lon = math.atan2(y_m, x_m)
    if p < 1e-9:
        lat = math.copysign(math.pi / 2, z_m)
        return math.degrees(lat), math.degrees(lon), abs(z_m) - WGS84_A * math.sqrt(1 - WGS84_E2)
    lat = math.atan2(z_m, p * (1.0 - WGS84_E2))
    h = 0.0
    for _ in range(10):
        s = math.sin(lat)
        n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * s * s)
        h = p / math.cos(lat) - n
        new_lat = math.atan2(z_m, p * (1.0 - WGS84_E2 * n / (n + h)))
        if abs(new_lat - lat) < 1e-14:
            lat = new_lat
            break
        lat = new_lat
    return math.degrees(lat), math.degrees(lon), h


def enu_rotation(lat_deg: float, lon_deg: float) -> tuple[tuple[float, float, float], ...]:
    """Rows of the ECEF -> ENU rotation at a point."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl = math.sin(lat), math.cos(lat)
    so, co = math.sin(lon), math.cos(lon)
    return ((-so, co, 0.0), (-sl * co, -sl * so, cl), (cl * co, cl * so, sl))


def ecef_to_enu(
    xyz_m: tuple[float, float, float], ref_ecef_m: tuple[float, float, float]
) -> tuple[float, float, float]:
    """ECEF point to east/north/up metres relative to a reference ECEF point."""
    lat, lon, _ = ecef_to_llh(*ref_ecef_m)
    d = (xyz_m[0] - ref_ecef_m[0], xyz_m[1] - ref_ecef_m[1], xyz_m[2] - ref_ecef_m[2])
    r = enu_rotation(lat, lon)
    e, n, u = (sum(r[i][j] * d[j] for j in range(3)) for i in range(3))
    return e, n, u


def enu_to_ecef(
    enu_m: tuple[float, float, float], ref_ecef_m: tuple[float, float, float]
) -> tuple[float, float, float]:
    """East/north/up metres relative to a reference ECEF point back to ECEF."""
    lat, lon, _ = ecef_to_llh(*ref_ecef_m)
    r = enu_rotation(lat, lon)
    d = tuple(sum(r[i][j] * enu_m[i] for i in range(3)) for j in range(3))
    return ref_ecef_m[0] + d[0], ref_ecef_m[1] + d[1], ref_ecef_m[2] + d[2]


def azimuth_elevation(
    sat_ecef_m: tuple[float, float, float], rx_ecef_m: tuple[float, float, float]
) -> tuple[float, float]:
    """Azimuth and elevation in degrees of a satellite seen from a receiver (ECEF metres)."""
    e, n, u = ecef_to_enu(sat_ecef_m, rx_ecef_m)
    az = math.degrees(math.atan2(e, n)) % 360.0
    el = math.degrees(math.atan2(u, math.hypot(e, n)))
    return az, el
