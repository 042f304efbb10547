"""Lost marks named by their cause, and photos timed by the camera clock.

The rule (:func:`groundstation.rules.marks.lost_cause`): a pulse the receiver counted is lost
on the link when the epoch its TIM-TM2 comes with did not arrive, or damaged data lies within
an epoch of it; otherwise the receiver did not report it. The camera clock: offset and drift
from the paired photos, wrong pairs left out, a timing sigma that covers what it does not know.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundstation.errors import ConfigError
from groundstation.rules.marks import (
    LOST_IN_RECEIVER,
    LOST_ON_LINK,
    Mark,
    lost_by_cause,
    lost_cause,
    lost_times,
    numbers_text,
)
from groundstation.solve import camclock
from groundstation.solve.photos import MatchResult, check_belongs

IV = 200_000_000  # 5 Hz
T0 = 2369 * 604_800 * 10**9


def test_a_pulse_whose_epoch_did_not_arrive_was_lost_on_the_link() -> None:
    t = T0 + 10 * IV + 50_000_000  # its record comes with epoch 11
    assert lost_cause(t, [(T0 + 9 * IV, T0 + 14 * IV)], [], IV) == LOST_ON_LINK
    # its epoch arrived, the hole began after it: the burst came whole
    assert lost_cause(t, [(T0 + 11 * IV, T0 + 14 * IV)], [], IV) == LOST_IN_RECEIVER
    assert lost_cause(t, [(T0 + 12 * IV, T0 + 14 * IV)], [], IV) == LOST_IN_RECEIVER
    assert lost_cause(t, [(T0 + 2 * IV, T0 + 11 * IV)], [], IV) == LOST_IN_RECEIVER  # arrived
    assert lost_cause(t, [], [(T0 + 11 * IV, T0 + 11 * IV)], IV) == LOST_ON_LINK  # damaged
    assert lost_cause(t, [], [(T0 + 10 * IV, T0 + 10 * IV)], IV) == LOST_ON_LINK
    assert lost_cause(t, [], [(T0 + 12 * IV, T0 + 12 * IV)], IV) == LOST_IN_RECEIVER  # later
    assert lost_cause(t, [], [(T0 + 14 * IV, T0 + 20 * IV)], IV) == LOST_IN_RECEIVER
    assert lost_cause(t, [], [(T0 + 5 * IV, T0 + 10 * IV)], IV) == LOST_ON_LINK  # monitor span


def test_lost_pulses_are_timed_by_photos_or_spread_evenly() -> None:
    assert lost_times(0, 300, 2) == [100, 200]
    assert lost_times(0, 300, 2, [250, 20]) == [20, 250]
    assert lost_times(0, 300, 2, [250]) == [100, 200]  # one photo for two pulses: spread


def _mark(t: int, number: int, lost: int) -> Mark:
    return Mark(t, t + 14_000_000, number + 1, 0, 0, 1, True, True, 10, lost, number)


def test_a_jump_of_two_with_one_pulse_in_a_hole_names_each() -> None:
    marks = [_mark(T0, 10, 0), _mark(T0 + 30 * IV, 13, 2)]  # 11 and 12 lost
    holes = [(T0 + 9 * IV, T0 + 12 * IV)]  # pulse 11 at T0 + 10 IV: in the hole
    lost = lost_by_cause(marks, holes, [], IV, [T0 + 10 * IV, T0 + 20 * IV])
    assert lost == {LOST_ON_LINK: [11], LOST_IN_RECEIVER: [12]}
    assert numbers_text([2, 3, 4, 12, 13, 26]) == "2-4, 12-13, 26"
    assert numbers_text(list(range(0, 100, 2)), most=3) == "0, 2, 4 and 47 more"


def test_the_camera_clock_offset_drift_and_a_wrong_pair() -> None:
    rng = np.random.default_rng(3)
    photo = np.sort(rng.uniform(0, 1800, 300)) + 1e9
    drift, offset = -20e-6, -10819.0
    mark = photo + offset + drift * (photo - photo.mean()) + rng.normal(0, 0.004, photo.size)
    mark[17] += 2.3  # a photo paired with the wrong mark
    clock = camclock.fit(photo, mark, np.ones(photo.size, bool))
    assert clock is not None and clock.outliers == 1 and clock.used == 299
    assert abs(clock.drift - drift) < 1e-6 and abs(clock.offset_s - offset) < 1e-3
    assert 0.003 < clock.sd_precise_s < 0.005
    # a photo timed by the clock: its error is within 3 of its sigmas
    t = 1e9 + 900.0
    true = t + offset + drift * (t - photo.mean())
    assert abs(clock.gps_s(t) - true) < 3 * clock.sigma_s(t, precise=True)
    # a whole-second photo knows its time to its second only
    assert clock.sigma_s(t, precise=False) >= camclock.WHOLE_SECOND_SD_S
    assert camclock.fit(photo[:2], mark[:2], np.ones(2, bool)) is None


def test_photos_for_lost_pulses_are_named_by_their_numbers() -> None:
    marks = [_mark(T0, 10, 0), _mark(T0 + 30 * IV, 13, 2), _mark(T0 + 40 * IV, 15, 1)]
    mark_s = [m.falling_t_gps_ns / 1e9 for m in marks]  # type: ignore[operator]
    photos = [(T0 + 20 * IV) / 1e9, (T0 + 10 * IV) / 1e9, (T0 + 35 * IV) / 1e9,
              (T0 + 36 * IV) / 1e9]
    # two photos for the jump 10 -> 13 (11, 12 in time order); two for 13 -> 15: not one
    assert camclock.lost_numbers(photos, marks, mark_s) == {1: 11, 0: 12}


def _result(offset_s: float, photo_s: np.ndarray) -> MatchResult:
    return MatchResult(offset_s, 0.1, (), tuple(range(photo_s.size)), (), (), photo_s,
                       math.nan, 18)


def test_photos_of_another_flight_are_refused() -> None:
    marks = [T0 + k * 2 * 10**9 for k in range(100)]
    photo = np.array([t / 1e9 for t in marks])
    check_belongs(_result(-3600.0 * 2 + 3.2, photo + 7196.8), marks)  # a zone and a clock
    with pytest.raises(ConfigError) as err:
        check_belongs(_result(-209_775_193.0, photo + 209_775_193.0), marks)
    assert err.value.key == "--photos" and "6.6 years off" in err.value.message
    with pytest.raises(ConfigError) as err:  # most photos hours away from the marks
        check_belongs(_result(0.0, np.concatenate([photo[:10], photo[10:] + 7200.0])), marks)
    assert "90 of 100 photos lie outside the flight's marks" in err.value.message
