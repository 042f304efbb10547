"""Satellite position, velocity and clock from a GPS broadcast ephemeris (IS-GPS-200 20.3.3.4.3).

Pure functions on numpy arrays. Times are given as seconds from the ephemeris reference epochs so
that callers keep nanosecond integer time and never lose precision in a large float.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from groundstation.gnss.ephemeris import MU_GPS, OMEGA_E_DOT, BroadcastEphemeris
from groundstation.gpstime import NS_PER_S, NS_PER_WEEK

C_M_S = 299_792_458.0
"""Speed of light (m/s), as GPS defines it."""
F_REL_S_SQRT_M = -4.442807633e-10
"""Relativistic clock constant F = -2 sqrt(mu) / c^2 (s / sqrt(m))."""
L1_HZ = 1_575_420_000.0
L1_WAVELENGTH_M = C_M_S / L1_HZ

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class SatState:
    """Satellite state at transmission time(s), ECEF at that same instant.

    Attributes:
        pos_m: ECEF position, shape (..., 3).
        vel_m_s: ECEF velocity (rotating frame), shape (..., 3).
        clock_s: satellite clock offset including the relativistic term, excluding TGD.
        clock_drift_s_s: derivative of ``clock_s``.
    """

    pos_m: FloatArray
    vel_m_s: FloatArray
    clock_s: FloatArray
    clock_drift_s_s: FloatArray


def toe_gps_ns(eph: BroadcastEphemeris) -> int:
    """The ephemeris reference time as GPS ns."""
    return eph.week * NS_PER_WEEK + round(eph.toe_s * NS_PER_S)


def toc_gps_ns(eph: BroadcastEphemeris) -> int:
    """The clock reference time as GPS ns."""
    return eph.week * NS_PER_WEEK + round(eph.toc_s * NS_PER_S)


def _kepler(m_rad: FloatArray, e: float) -> FloatArray:
    ecc = np.array(m_rad, dtype=np.float64, copy=True)
    for _ in range(30):
        step = (ecc - e * np.sin(ecc) - m_rad) / (1.0 - e * np.cos(ecc))
        ecc = ecc - step
        if float(np.max(np.abs(step), initial=0.0)) < 1e-15:
            break
    return ecc


def sat_state(
    eph: BroadcastEphemeris, dt_toe_s: ArrayLike, dt_toc_s: ArrayLike | None = None
) -> SatState:
    """Satellite ECEF position, velocity and clock offset at GPS time(s) of transmission.

    Args:
        eph: the broadcast ephemeris.
        dt_toe_s: transmission time minus ``toe`` in seconds (scalar or array).
        dt_toc_s: transmission time minus ``toc``; defaults to ``dt_toe_s`` shifted by
            ``toe - toc``.

    Returns:
        The state, arrays shaped like ``dt_toe_s`` (positions with a trailing axis of 3).
    """
    tk = np.asarray(dt_toe_s, dtype=np.float64)
    tc = tk + (eph.toe_s - eph.toc_s) if dt_toc_s is None else np.asarray(dt_toc_s, np.float64)
    a = eph.sqrt_a_sqrt_m**2
    n0 = np.sqrt(MU_GPS / a**3)
    n = n0 + eph.delta_n_rad_s
    m = eph.m0_rad + n * tk
    ecc_anom = _kepler(m, eph.e)
    sin_e, cos_e = np.sin(ecc_anom), np.cos(ecc_anom)
    e = eph.e
    denom = 1.0 - e * cos_e
    nu = np.arctan2(np.sqrt(1.0 - e * e) * sin_e, cos_e - e)
    phi = nu + eph.omega_rad
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    du = eph.cus_rad * s2 + eph.cuc_rad * c2
    dr = eph.crs_m * s2 + eph.crc_m * c2
    di = eph.cis_rad * s2 + eph.cic_rad * c2
    u = phi + du
    r = a * denom + dr
    inc = eph.i0_rad + di + eph.idot_rad_s * tk
    xp, yp = r * np.cos(u), r * np.sin(u)
    omega = eph.omega0_rad + (eph.omega_dot_rad_s - OMEGA_E_DOT) * tk - OMEGA_E_DOT * eph.toe_s
    so, co = np.sin(omega), np.cos(omega)
    si, ci = np.sin(inc), np.cos(inc)
    x = xp * co - yp * ci * so
    y = xp * so + yp * ci * co
    z = yp * si

    # Velocity: derivatives of the same chain (as in IS-GPS-200 table 20-IV, extended).
    e_dot = n / denom
    nu_dot = e_dot * np.sqrt(1.0 - e * e) / denom
    u_dot = nu_dot * (1.0 + 2.0 * (eph.cus_rad * c2 - eph.cuc_rad * s2))
    r_dot = a * e * sin_e * e_dot + 2.0 * nu_dot * (eph.crs_m * c2 - eph.crc_m * s2)
    i_dot = eph.idot_rad_s + 2.0 * nu_dot * (eph.cis_rad * c2 - eph.cic_rad * s2)
    om_dot = eph.omega_dot_rad_s - OMEGA_E_DOT
    xp_dot = r_dot * np.cos(u) - r * u_dot * np.sin(u)
    yp_dot = r_dot * np.sin(u) + r * u_dot * np.cos(u)
    vx = xp_dot * co - yp_dot * ci * so + yp * si * i_dot * so - y * om_dot
    vy = xp_dot * so + yp_dot * ci * co - yp * si * i_dot * co + x * om_dot
    vz = yp_dot * si + yp * ci * i_dot

    rel = F_REL_S_SQRT_M * e * eph.sqrt_a_sqrt_m * sin_e
    rel_dot = F_REL_S_SQRT_M * e * eph.sqrt_a_sqrt_m * cos_e * e_dot
    clock = eph.af0_s + eph.af1_s_s * tc + eph.af2_s_s2 * tc * tc + rel
    drift = eph.af1_s_s + 2.0 * eph.af2_s_s2 * tc + rel_dot
    return SatState(
        pos_m=np.stack([x, y, z], axis=-1),
        vel_m_s=np.stack([vx, vy, vz], axis=-1),
        clock_s=np.asarray(clock, dtype=np.float64),
        clock_drift_s_s=np.asarray(drift, dtype=np.float64),
    )


def sat_state_at(eph: BroadcastEphemeris, t_gps_ns: int) -> SatState:
    """Convenience: the state at one GPS time given in integer ns."""
    return sat_state(eph, (t_gps_ns - toe_gps_ns(eph)) / NS_PER_S)


def rotate_earth(pos_m: FloatArray, tau_s: ArrayLike) -> FloatArray:
    """ECEF vectors at transmission rotated into the ECEF frame at reception (Sagnac)."""
    th = OMEGA_E_DOT * np.asarray(tau_s, dtype=np.float64)
    c, s = np.cos(th), np.sin(th)
    x, y = pos_m[..., 0], pos_m[..., 1]
    return np.stack([c * x + s * y, -s * x + c * y, pos_m[..., 2]], axis=-1)
