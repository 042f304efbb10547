"""What a solve keeps of the flight recording for a re-base (``flight.npz``): read back, it is
what was read, so that marks, lost marks and the report come out the same without the
recording being read again."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from groundstation.errors import InputError
from groundstation.records import TimeMark
from groundstation.solve import flight as fl

T0 = 2022 * 604_800 * 10**9


def _mark(count: int, rising: int | None, falling: int | None) -> TimeMark:
    return TimeMark(channel=0, count=count, rising_t_gps_ns=rising, falling_t_gps_ns=falling,
                    new_rising=rising is not None, new_falling=True, time_base=1, valid=True,
                    acc_ns=21, t_host_ns=1_700_000_000_000_000_000 + count, flags=0x45,
                    mode_running=True, run=False, utc_valid=True, leap_s_applied=18)


def _records(observed: fl.FlightObservations | None) -> fl.FlightRecords:
    marks = (_mark(1, T0 + 5, T0 + 3), _mark(2, None, T0 + 10**9), _mark(5, T0 + 3 * 10**9, None))
    return fl.FlightRecords(marks, (), 1234, 7, (T0, T0 + 200_000_000, T0 + 10**9),
                            (T0 + 200_000_000,), observed)


def test_what_a_solve_keeps_of_the_flight_reads_back_the_same(tmp_path: Path) -> None:
    sats = fl.SatelliteObs(sat=("G05", "R12", "G05"),
                           t_gps_ns=np.array([T0, T0, T0 + 200_000_000], np.int64),
                           cno_dbhz=np.array([41.0, 38.5, 40.0]),
                           slip=np.array([False, True, False]), half=np.array([True, False, False]))
    for observed in (
        None,
        fl.FlightObservations(None, (fl.Span(T0, T0 + 2 * 10**9),), (), False),
        fl.FlightObservations(sats, (fl.Span(T0, T0 + 2 * 10**9),), (fl.Span(T0 + 5, T0 + 9),),
                              True),
    ):
        rec = _records(observed)
        fl.save_npz(rec, tmp_path / "flight.npz")
        back = fl.load_npz(tmp_path / "flight.npz")
        assert back.timemarks == rec.timemarks
        assert (back.frames, back.damaged) == (rec.frames, rec.damaged)
        assert back.epoch_t_gps_ns == rec.epoch_t_gps_ns
        assert back.damage_t_gps_ns == rec.damage_t_gps_ns
        assert back.nav == ()  # the receiver's fixes are not kept (a re-base needs none)
        if observed is None:
            assert back.observed is None
            continue
        assert back.observed is not None
        assert (back.observed.radio_gaps, back.observed.source_outages,
                back.observed.station_events) == (observed.radio_gaps, observed.source_outages,
                                                  observed.station_events)
        if observed.satellites is None:
            assert back.observed.satellites is None
            continue
        got = back.observed.satellites
        assert got is not None
        for f in dataclasses.fields(fl.SatelliteObs):
            a, b = getattr(observed.satellites, f.name), getattr(got, f.name)
            assert (a == b if not isinstance(a, np.ndarray) else np.array_equal(a, b)), f.name


def test_kept_records_that_are_not_ours_are_an_input_error(tmp_path: Path) -> None:
    """One line each, saying what is wrong (never numpy's advice to load pickles)."""
    (tmp_path / "flight.npz").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(InputError, match=r"not flight records this program wrote \(not a "
                       r"NumPy .npz archive\)"):
        fl.load_npz(tmp_path / "flight.npz")
    np.savez(tmp_path / "objects.npz", timemarks=np.array([{"a": 1}], dtype=object))
    with pytest.raises(InputError, match=r"\(holds objects, not plain arrays\)"):
        fl.load_npz(tmp_path / "objects.npz")
    np.savez(tmp_path / "other.npz", timemarks=np.zeros((1, 3)), timemark_fields=np.array(["a"]))
    with pytest.raises(InputError, match="not flight records this program wrote") as err:
        fl.load_npz(tmp_path / "other.npz")
    assert "\n" not in str(err.value)
