"""RINEX 3.04 navigation records of GLONASS, Galileo and BeiDou ephemerides, and the header
system of a navigation file that mixes them with GPS.

The GPS records stay with the navigation writer (:func:`groundstation.offline.rinex.write_nav`),
which calls :func:`header_system` and :func:`records` and passes its value formatter, so every
system's numbers are printed the same way. Field order is RINEX 3.04's (tables A8, A10, A12).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from groundstation import gpstime
from groundstation.gnss.glonass import GlonassEphemeris
from groundstation.offline.multinav import MultiNav

if TYPE_CHECKING:
    from groundstation.gnss.kepler import KeplerEphemeris

FieldFormat = Callable[[float], str]
"""A navigation value as its 19-character RINEX field."""

_NAMES = {"G": "GPS", "R": "GLONASS", "E": "Galileo", "C": "BeiDou", "M": "Mixed"}
_INDENT = "    "


def systems(multi: MultiNav | None) -> list[str]:
    """The non-GPS systems a :class:`MultiNav` has records of."""
    if multi is None:
        return []
    out = ["R"] if multi.glonass else []
    out += sorted({e.system for e in multi.kepler}, key="EC".index)
    return out


def header_system(has_gps: bool, multi: MultiNav | None) -> str:
    """The ``RINEX VERSION / TYPE`` system field, e.g. ``"G: GPS"`` or ``"M: Mixed"``."""
    present = (["G"] if has_gps else []) + systems(multi)
    letter = present[0] if len(present) == 1 else "M" if present else "G"
    return f"{letter}: {_NAMES[letter]}"


def _epoch(label: str, t_ns: int) -> str:
    return _epoch_dt(label, gpstime.gps_as_datetime(t_ns))


def _epoch_dt(label: str, d: dt.datetime) -> str:
    return (f"{label} {d.year:04d} {d.month:02d} {d.day:02d} {d.hour:02d} {d.minute:02d} "
            f"{d.second:02d}")


def glonass_record(e: GlonassEphemeris, f: FieldFormat) -> str:
    """One GLONASS record: epoch ``tb`` in UTC, ``-tau_n``, ``gamma_n``, frame time as seconds
    of the UTC week; then x, y, z rows in km (position, velocity, acceleration) with health,
    frequency number and age."""
    leap_ns = gpstime.leap_seconds_at_gps(e.toe_gps_ns) * gpstime.NS_PER_S
    tof_utc_ns = e.tof_gps_ns - gpstime.leap_seconds_at_gps(e.tof_gps_ns) * gpstime.NS_PER_S
    tof_s = (tof_utc_ns % gpstime.NS_PER_WEEK) / gpstime.NS_PER_S
    lines = [_epoch(f"R{e.slot:02d}", e.toe_gps_ns - leap_ns)
             + f(-e.tau_n_s) + f(e.gamma_n) + f(tof_s)]
    last = (float(e.health), float(e.fcn), float(e.age_days))
    for k in range(3):
        lines.append(_INDENT + f(e.pos_m[k] / 1e3) + f(e.vel_m_s[k] / 1e3)
                     + f(e.acc_m_s2[k] / 1e3) + f(last[k]))
    return "\n".join(lines) + "\n"


def kepler_record(e: KeplerEphemeris, f: FieldFormat) -> str:
    """One Galileo or BeiDou record (RINEX 3.04 tables A8 and A14; BeiDou on BDT)."""
    label = f"{e.system}{e.prn:02d}"
    if e.system == "C":
        from groundstation.gnss.beidou import bdt_datetime  # only with BeiDou records

        head = _epoch_dt(label, bdt_datetime(e.week, e.toc_s))
    else:
        head = _epoch(label, round((e.week * 604_800 + e.toc_s) * gpstime.NS_PER_S))
    if e.system == "E":
        row5_last, row6_last, row7_last = 0.0, e.tgd2_s, 0.0
    else:
        row5_last, row6_last, row7_last = 0.0, e.tgd2_s, float(e.iodc)
    rows = (
        (float(e.iode), e.crs_m, e.delta_n_rad_s, e.m0_rad),
        (e.cuc_rad, e.e, e.cus_rad, e.sqrt_a_sqrt_m),
        (e.toe_s, e.cic_rad, e.omega0_rad, e.cis_rad),
        (e.i0_rad, e.crc_m, e.omega_rad, e.omega_dot_rad_s),
        (e.idot_rad_s, float(e.data_source), float(e.week), row5_last),
        (e.accuracy_m, float(e.health), e.tgd1_s, row6_last),
        (e.tx_s, row7_last),
    )
    lines = [head + f(e.af0_s) + f(e.af1_s_s) + f(e.af2_s_s2)]
    lines += [_INDENT + "".join(f(v) for v in r) for r in rows]
    return "\n".join(lines) + "\n"


def records(multi: MultiNav | None, f: FieldFormat) -> Iterable[str]:
    """Every GLONASS record, then every Galileo and BeiDou record, each by time then number."""
    if multi is None:
        return []
    out = [glonass_record(e, f)
           for e in sorted(multi.glonass, key=lambda e: (e.toe_gps_ns, e.slot))]
    out += [kepler_record(e, f) for e in sorted(
        multi.kepler, key=lambda e: ("EC".index(e.system), e.week * 604_800 + e.toc_s, e.prn))]
    return out
