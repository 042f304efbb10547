"""The RINEX 2.11 / 3.04 navigation file from broadcast ephemerides (RINEX 3: GPS, GLONASS,
Galileo, BeiDou; 2.11: GPS only)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from groundstation import __version__, gpstime
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.offline.ephemeris import NavResult
from groundstation.offline.multinav import MultiNav
from groundstation.offline.rinex import nav_multi
from groundstation.offline.rinex.format import d19, hl, utc_now

# IS-GPS-200 nominal URA (m) per index, as RINEX writers give it.
URA_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0,
         3072.0, 6144.0, 6144.0)  # fmt: skip


def write_nav(
    path: Path,
    ephemerides: Sequence[BroadcastEphemeris],
    version: str = "3.04",
    leap_s: int | None = None,
    nav: NavResult | None = None,
    multi: MultiNav | None = None,
) -> int:
    """Write a navigation file (RINEX 3: GPS, GLONASS, Galileo, BeiDou; 2.11: GPS only);
    returns the number of GPS ephemerides written."""
    v3 = version == "3.04"
    h: list[str] = []
    if v3:
        sys_field = nav_multi.header_system(bool(ephemerides), multi)
        h.append(hl(f"{version:>9s}{'':11s}{'N: GNSS NAV DATA':<20s}{sys_field:<20s}",
                     "RINEX VERSION / TYPE"))
    else:
        h.append(hl(f"{version:>9s}{'':11s}{'N: GPS NAV DATA':<20s}", "RINEX VERSION / TYPE"))
    h.append(hl(f"{'groundstation ' + __version__:<20.20s}{'':<20s}{utc_now():<20s}",
                 "PGM / RUN BY / DATE"))
    iono = nav.iono_utc if nav is not None else None
    if iono is not None:
        if v3:
            h.append(hl("GPSA" + " " + "".join(f"{a:12.4E}" for a in iono.alpha),
                         "IONOSPHERIC CORR"))
            h.append(hl("GPSB" + " " + "".join(f"{b:12.4E}" for b in iono.beta),
                         "IONOSPHERIC CORR"))
            h.append(hl(f"GPUT {iono.a0_s:17.10E}{iono.a1_s_s:16.9E}{iono.tot_s:7d}"
                         f"{iono.wnt:5d}", "TIME SYSTEM CORR"))
        else:
            h.append(hl("  " + "".join(f"{a:12.4E}" for a in iono.alpha), "ION ALPHA"))
            h.append(hl("  " + "".join(f"{b:12.4E}" for b in iono.beta), "ION BETA"))
    if leap_s is not None:
        h.append(hl(f"{leap_s:6d}", "LEAP SECONDS"))
    h.append(hl("", "END OF HEADER"))
    body: list[str] = []
    for e in sorted(ephemerides, key=lambda e: (e.week * 604800 + e.toc_s, e.sv)):
        toc_ns = round((e.week * 604800 + e.toc_s) * 1e9)
        # toc is in the week of toe give or take a half week
        d = gpstime.gps_as_datetime(toc_ns)
        ura = URA_M[min(max(e.ura_index, 0), 15)]
        tx = e.tow_s if e.tow_s is not None else e.toe_s
        fit_h = 4.0 if e.fit_interval_flag == 0 else 6.0
        if v3:
            body.append(f"G{e.sv:02d} {d.year:04d} {d.month:02d} {d.day:02d} {d.hour:02d} "
                        f"{d.minute:02d} {d.second:02d}"
                        f"{d19(e.af0_s)}{d19(e.af1_s_s)}{d19(e.af2_s_s2)}\n")
            ind = "    "
        else:
            sec = f"{d.second + d.microsecond / 1e6:5.1f}"
            body.append(f"{e.sv:2d} {d.year % 100:02d} {d.month:2d} {d.day:2d} {d.hour:2d} "
                        f"{d.minute:2d}{sec}"
                        f"{d19(e.af0_s)}{d19(e.af1_s_s)}{d19(e.af2_s_s2)}\n")
            ind = "   "
        rows = (
            (e.iode, e.crs_m, e.delta_n_rad_s, e.m0_rad),
            (e.cuc_rad, e.e, e.cus_rad, e.sqrt_a_sqrt_m),
            (e.toe_s, e.cic_rad, e.omega0_rad, e.cis_rad),
            (e.i0_rad, e.crc_m, e.omega_rad, e.omega_dot_rad_s),
            (e.idot_rad_s, e.code_on_l2, e.week, e.l2p_data_flag),
            (ura, e.health, e.tgd_s, e.iodc),
        )
        for r in rows:
            body.append(ind + "".join(d19(float(v)) for v in r) + "\n")
        body.append(ind + d19(float(tx)) + d19(fit_h) + "\n")
    if v3:
        body.extend(nav_multi.records(multi, d19))
    with path.open("w", encoding="ascii", newline="\n") as f:
        f.write("".join(h))
        f.write("".join(body))
    return len(ephemerides)
