"""The simulated GPS constellation: orbits, broadcast ephemerides, clocks and atmosphere model.

Each satellite has one underlying orbit (Keplerian elements with secular rates and harmonic
corrections of realistic size). Every two hours a new broadcast ephemeris is issued: the same
orbit expressed at the new ``toe`` and quantised to the IS-GPS-200 LSBs. The *truth* the
observations are generated from is the broadcast ephemeris itself (the one a receiver would
select: nearest ``toe``), so a perfect solver using the broadcast message sees no orbit error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundstation.gnss.atmosphere import KLOBUCHAR_ALPHA_DEFAULT, KLOBUCHAR_BETA_DEFAULT
from groundstation.gnss.ephemeris import GPS_PI, BroadcastEphemeris
from groundstation.gnss.lnav_encode import FIELDS, IonoUtcParams, quantise
from groundstation.gnss.orbit import toe_gps_ns
from groundstation.gpstime import NS_PER_S, NS_PER_WEEK

EPH_INTERVAL_S = 7200
"""A new ephemeris (toe) every two hours; each is valid (fit interval) for four."""
N_SATELLITES = 31
_SLOTS_PER_PLANE = (6, 5, 5, 5, 5, 5)


@dataclass(frozen=True, slots=True)
class OrbitElements:
    """One satellite's underlying orbit at reference time ``t_ref_gps_ns`` (angles in rad)."""

    sv: int
    t_ref_gps_ns: int
    sqrt_a_sqrt_m: float
    e: float
    i0_rad: float
    omega0_rad: float  # longitude of the ascending node at the week start, as broadcast
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
    af0_s: float
    af1_s_s: float
    tgd_s: float
    ura_index: int


@dataclass(frozen=True, slots=True)
class Constellation:
    """Satellites, their ephemerides by issue, and the broadcast ionosphere model."""

    elements: tuple[OrbitElements, ...]
    ephemerides: dict[int, tuple[BroadcastEphemeris, ...]]
    iono: IonoUtcParams

    @property
    def svs(self) -> tuple[int, ...]:
        return tuple(el.sv for el in self.elements)

    def ephemeris_at(self, sv: int, t_gps_ns: int) -> BroadcastEphemeris:
        """The ephemeris a receiver would use at ``t``: the issue with the nearest ``toe``."""
        return min(self.ephemerides[sv], key=lambda e: abs(toe_gps_ns(e) - t_gps_ns))

    def all_ephemerides(self) -> list[BroadcastEphemeris]:
        return [e for sv in sorted(self.ephemerides) for e in self.ephemerides[sv]]


def _q(name: str, value: float) -> float:
    return quantise(FIELDS[name], value)


def make_elements(seed: int, t_ref_gps_ns: int, n_sv: int = N_SATELLITES) -> list[OrbitElements]:
    """A GPS-like constellation: 6 planes, 55° inclination, 12 h orbits, small eccentricity."""
    rng = np.random.default_rng(seed)
    out: list[OrbitElements] = []
    sv = 0
    for plane, n_slots in enumerate(_SLOTS_PER_PLANE):
        raan = math.radians(plane * 60.0 + 17.0) + rng.normal(0, 0.01)
        for slot in range(n_slots):
            if sv >= n_sv:
                break
            sv += 1
            a_m = 26_559_700.0 + rng.normal(0, 2000.0)
            arg_lat = (2 * math.pi * slot / n_slots + plane * math.radians(15.0)
                       + rng.normal(0, 0.05))
            omega = rng.uniform(-math.pi, math.pi)
            out.append(
                OrbitElements(
                    sv=sv,
                    t_ref_gps_ns=t_ref_gps_ns,
                    sqrt_a_sqrt_m=math.sqrt(a_m),
                    e=float(rng.uniform(0.001, 0.02)),
                    i0_rad=math.radians(55.0 + rng.normal(0, 1.0)),
                    omega0_rad=raan,
                    omega_rad=omega,
                    m0_rad=arg_lat - omega,
                    delta_n_rad_s=float(rng.uniform(4.0e-9, 5.5e-9)),
                    omega_dot_rad_s=float(rng.uniform(-8.6e-9, -7.8e-9)),
                    idot_rad_s=float(rng.normal(0, 2e-10)),
                    cuc_rad=float(rng.normal(0, 3e-6)),
                    cus_rad=float(rng.normal(0, 5e-6)),
                    crc_m=float(rng.uniform(150.0, 350.0)),
                    crs_m=float(rng.normal(0, 60.0)),
                    cic_rad=float(rng.normal(0, 1e-7)),
                    cis_rad=float(rng.normal(0, 1e-7)),
                    af0_s=float(rng.uniform(-4e-4, 4e-4)),
                    af1_s_s=float(rng.normal(0, 3e-12)),
                    tgd_s=float(rng.uniform(-3e-9, 3e-9)),
                    ura_index=int(rng.integers(0, 3)),
                )
            )
    return out


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def issue_ephemeris(el: OrbitElements, toe_gps_ns_: int, iode: int) -> BroadcastEphemeris:
    """The broadcast ephemeris of an orbit at a given toe, quantised to IS-GPS-200 LSBs."""
    week, toe_ns = divmod(toe_gps_ns_, NS_PER_WEEK)
    toe_s = toe_ns // NS_PER_S
    dt = (toe_gps_ns_ - el.t_ref_gps_ns) / NS_PER_S
    n = math.sqrt(3.986005e14 / el.sqrt_a_sqrt_m**6) + el.delta_n_rad_s
    # omega0 is referred to the start of the week of toe; the node drifts at omega_dot.
    omega0 = el.omega0_rad + el.omega_dot_rad_s * dt
    m0 = el.m0_rad + n * dt
    i0 = el.i0_rad + el.idot_rad_s * dt
    af0 = el.af0_s + el.af1_s_s * dt
    return BroadcastEphemeris(
        sv=el.sv,
        week=week,
        toc_s=float(toe_s),
        af0_s=_q("af0_s", af0),
        af1_s_s=_q("af1_s_s", el.af1_s_s),
        af2_s_s2=0.0,
        iodc=iode,
        iode=iode,
        tgd_s=_q("tgd_s", el.tgd_s),
        ura_index=el.ura_index,
        health=0,
        code_on_l2=1,
        l2p_data_flag=0,
        fit_interval_flag=0,
        toe_s=float(toe_s),
        sqrt_a_sqrt_m=_q("sqrt_a_sqrt_m", el.sqrt_a_sqrt_m),
        e=_q("e", el.e),
        i0_rad=_q("i0_rad", _wrap(i0)),
        omega0_rad=_q("omega0_rad", _wrap(omega0)),
        omega_rad=_q("omega_rad", _wrap(el.omega_rad)),
        m0_rad=_q("m0_rad", _wrap(m0)),
        delta_n_rad_s=_q("delta_n_rad_s", el.delta_n_rad_s),
        omega_dot_rad_s=_q("omega_dot_rad_s", el.omega_dot_rad_s),
        idot_rad_s=_q("idot_rad_s", el.idot_rad_s),
        cuc_rad=_q("cuc_rad", el.cuc_rad),
        cus_rad=_q("cus_rad", el.cus_rad),
        crc_m=_q("crc_m", el.crc_m),
        crs_m=_q("crs_m", el.crs_m),
        cic_rad=_q("cic_rad", el.cic_rad),
        cis_rad=_q("cis_rad", el.cis_rad),
    )


def make_constellation(
    seed: int, start_gps_ns: int, end_gps_ns: int, n_sv: int = N_SATELLITES
) -> Constellation:
    """Constellation and every ephemeris issue a receiver may use between start and end."""
    step = EPH_INTERVAL_S * NS_PER_S
    t_ref = (start_gps_ns // step) * step
    elements = make_elements(seed, t_ref, n_sv)
    first = ((start_gps_ns + step // 2) // step) * step
    toes = list(range(first, end_gps_ns + step // 2 + 1, step)) or [first]
    ephs: dict[int, tuple[BroadcastEphemeris, ...]] = {}
    for el in elements:
        issues = []
        for toe in toes:
            iode = (toe // step + 3 * el.sv) % 240
            issues.append(issue_ephemeris(el, toe, iode))
        ephs[el.sv] = tuple(issues)
    week = start_gps_ns // NS_PER_WEEK
    iono = IonoUtcParams(
        alpha=KLOBUCHAR_ALPHA_DEFAULT,
        beta=KLOBUCHAR_BETA_DEFAULT,
        tot_s=(((start_gps_ns % NS_PER_WEEK) // NS_PER_S) // 4096) * 4096,
        wnt=week % 256,
        wn_lsf=(week - 400) % 256,
    )
    return Constellation(tuple(elements), ephs, iono)


__all__ = ["GPS_PI", "Constellation", "OrbitElements", "make_constellation"]
