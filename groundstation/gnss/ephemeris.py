"""The GPS LNAV broadcast ephemeris as physical quantities (IS-GPS-200 section 20.3.3).

This is the one representation shared by the navigation-message encoder (simulator), the
decoder (subframes, AID-EPH), the RINEX navigation writer and the orbit computation. Angles are
in radians (converted from semicircles with the GPS value of pi), times in seconds of the GPS week
(``toe_s``, ``toc_s``) with the full week number in ``week``.
"""

from __future__ import annotations

from dataclasses import dataclass

GPS_PI = 3.1415926535898
"""The value of pi the GPS interface specification uses for semicircle conversions."""
MU_GPS = 3.986005e14
"""WGS84 gravitational constant used by GPS (m^3/s^2)."""
OMEGA_E_DOT = 7.2921151467e-5
"""WGS84 earth rotation rate (rad/s)."""


@dataclass(frozen=True, slots=True)
class BroadcastEphemeris:
    """One satellite's broadcast clock and orbit parameters."""

    sv: int
    week: int
    toc_s: float
    af0_s: float
    af1_s_s: float
    af2_s_s2: float
    iodc: int
    iode: int
    tgd_s: float
    ura_index: int
    health: int
    code_on_l2: int
    l2p_data_flag: int
    fit_interval_flag: int
    toe_s: float
    sqrt_a_sqrt_m: float
    e: float
    i0_rad: float
    omega0_rad: float
    omega_rad: float
    m0_rad: float
    delta_n_rad_s: float
    omega_dot_rad_s: float
    idot_rad_s: float
    cuc_rad: float
    cus_rad: float
    crc_m: float
    crs_m: float
    cic_rad: float
    cis_rad: float
    aodo_s: int = 0
    tow_s: float | None = None
    """Transmission time (HOW of subframe 1) when known, for RINEX's transmission-time field."""
