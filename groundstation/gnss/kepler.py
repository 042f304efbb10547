"""Keplerian broadcast ephemeris of Galileo and BeiDou, in the shape RINEX 3 navigation records
take (the GPS one, :class:`~groundstation.gnss.ephemeris.BroadcastEphemeris`, keeps its LNAV
fields; these systems fill the same orbit rows with their own clock and group-delay terms).

Angles in radians, times in seconds; ``week``, ``toe_s``, ``toc_s`` and ``tx_s`` are on the
system's own week as RINEX writes them (Galileo: GPS week numbering; BeiDou: BDT week, BDT
seconds).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class KeplerEphemeris:
    """One Galileo or BeiDou satellite's broadcast clock and orbit.

    Attributes:
        system: ``"E"`` or ``"C"``.
        prn: satellite number.
        week: week of ``toe`` (Galileo: GST week + 1024; BeiDou: BDT week).
        toc_s, toe_s: clock and ephemeris reference times, seconds of ``week``.
        iode: Galileo IODnav, BeiDou AODE.
        iodc: BeiDou AODC (Galileo: IODnav).
        tgd1_s, tgd2_s: Galileo BGD E5a/E1 and E5b/E1; BeiDou TGD1 B1/B3 and TGD2 B2/B3.
        accuracy_m: Galileo SISA, BeiDou URA (metres, RINEX row 7).
        health: Galileo signal health and data validity bits; BeiDou SatH1.
        data_source: Galileo data-source bits (RINEX row 6); 0 for BeiDou.
        tx_s: transmission time, seconds of ``week`` (may exceed a week).
    """

    system: str
    prn: int
    week: int
    toc_s: float
    toe_s: float
    af0_s: float
    af1_s_s: float
    af2_s_s2: float
    iode: int
    iodc: int
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
    tgd1_s: float
    tgd2_s: float
    accuracy_m: float
    health: int
    data_source: int
    tx_s: float
