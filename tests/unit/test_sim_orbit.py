"""Orbit computation, LNAV encode/decode with parity, and the constellation the simulator uses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from groundstation.gnss import lnav, lnav_encode
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.orbit import sat_state, sat_state_at, toe_gps_ns
from groundstation.gpstime import NS_PER_S, week_tow
from groundstation.sim.constellation import make_constellation
from groundstation.sim.stream import DEFAULT_START_GPS_NS

T0 = DEFAULT_START_GPS_NS


@pytest.fixture(scope="module")
def ephs() -> list[BroadcastEphemeris]:
    c = make_constellation(7, T0, T0 + 3600 * NS_PER_S)
    assert len(c.svs) == 31
    return c.all_ephemerides()


def test_positions_at_gps_radius_and_velocity_matches_differences(
    ephs: list[BroadcastEphemeris],
) -> None:
    for eph in ephs:
        dt = np.linspace(-3600.0, 3600.0, 13)
        st = sat_state(eph, dt)
        radius = np.linalg.norm(st.pos_m, axis=1)
        assert np.all((radius > 26.0e6) & (radius < 27.2e6)), eph.sv
        h = 0.5
        ahead, behind = sat_state(eph, dt + h), sat_state(eph, dt - h)
        numeric = (ahead.pos_m - behind.pos_m) / (2 * h)
        assert np.max(np.abs(numeric - st.vel_m_s)) < 1e-3
        clock_num = (ahead.clock_s - behind.clock_s) / (2 * h)
        assert np.max(np.abs(clock_num - st.clock_drift_s_s)) < 1e-15


def test_constellation_is_gps_like(ephs: list[BroadcastEphemeris]) -> None:
    incl = np.degrees([e.i0_rad for e in ephs])
    assert np.all(np.abs(incl - 55.0) < 5.0)
    assert all(0 < e.e < 0.03 for e in ephs)
    assert all(abs(e.af0_s) < 1e-3 for e in ephs)
    # Orbital period of about 11 h 58 min.
    a = np.array([e.sqrt_a_sqrt_m for e in ephs]) ** 2
    period_h = 2 * np.pi * np.sqrt(a**3 / 3.986005e14) / 3600
    assert np.all(np.abs(period_h - 11.967) < 0.05)


def test_ephemeris_round_trips_exactly_through_subframes(ephs: list[BroadcastEphemeris]) -> None:
    week, tow_ns = week_tow(T0)
    frame_tow = (tow_ns // NS_PER_S) // 30 * 30
    for eph in ephs:
        sf = lnav_encode.encode_ephemeris(eph, week, frame_tow)
        # Through the on-air form with parity, and back.
        data = [lnav.parity_decode(lnav_encode.to_on_air(words)) for words in sf]
        assert tuple(data) == sf
        got = lnav.decode_ephemeris(data[0], data[1], data[2], week_hint=week, sv=eph.sv)
        assert dataclasses.replace(got, tow_s=None) == eph
        assert got.tow_s == frame_tow


def test_parity_detects_a_flipped_bit(ephs: list[BroadcastEphemeris]) -> None:
    week, _ = week_tow(T0)
    words = list(lnav_encode.to_on_air(lnav_encode.encode_ephemeris(ephs[0], week, 0)[1]))
    words[4] ^= 1 << 17
    with pytest.raises(lnav.LnavParityError) as info:
        lnav.parity_decode(words)
    assert info.value.word == 5


def test_parity_solving_bits_leave_d29_d30_zero(ephs: list[BroadcastEphemeris]) -> None:
    week, _ = week_tow(T0)
    for sf in lnav_encode.encode_ephemeris(ephs[3], week, 60):
        air = lnav_encode.to_on_air(sf)
        assert air[1] & 0x3 == 0 and air[9] & 0x3 == 0


def test_iono_page_round_trips() -> None:
    c = make_constellation(1, T0, T0)
    page = lnav_encode.encode_iono_utc_page(c.iono, 1000)
    got = lnav.decode_iono_utc(page)
    assert got is not None
    assert got.alpha == c.iono.alpha and got.beta == c.iono.beta
    assert lnav.subframe_id(page) == 4


def test_subframe_schedule_ids_and_tow() -> None:
    c = make_constellation(1, T0, T0)
    eph = c.ephemerides[1][0]
    for start in range(0, 60, 6):
        words = lnav_encode.subframe_for(eph, c.iono, 2369, 115200 + start)
        assert lnav.subframe_id(words) == (start // 6) % 5 + 1
        assert lnav.how_tow_s(words) == 115200 + start + 6


def test_state_at_matches_relative_time(ephs: list[BroadcastEphemeris]) -> None:
    eph = ephs[0]
    a = sat_state_at(eph, toe_gps_ns(eph) + 90 * NS_PER_S)
    b = sat_state(eph, 90.0)
    assert np.allclose(a.pos_m, b.pos_m, rtol=0, atol=1e-6)
