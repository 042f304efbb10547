"""The rover's observed dynamics and the acceleration noise derived from them, on known motion.

The trajectories are built here from their accelerations (half-sine ramps, as a multicopter's
jerk-limited climb), so what the measurement must find is known independently of the simulator
and of the engine.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from groundstation.geodesy import enu_rotation, llh_to_ecef
from groundstation.solve.engine import dynamics as dy

LAT, LON, H = 53.28, -9.06, 60.0
T0_NS = 1_223_122_930_000_000_000
Arr = npt.NDArray[np.float64]


def _ecef(enu: Arr) -> Arr:
    origin = np.array(llh_to_ecef(LAT, LON, H))
    out: Arr = origin + enu @ np.asarray(enu_rotation(LAT, LON))
    return out


def _integrate(acc: Arr, dt: float) -> Arr:
    """Positions from accelerations (trapezoidal twice), starting at rest at the origin."""
    vel = np.concatenate([[0.0], np.cumsum((acc[1:] + acc[:-1]) / 2) * dt])
    out: Arr = np.concatenate([[0.0], np.cumsum((vel[1:] + vel[:-1]) / 2) * dt])
    return out


def _flight(duration_s: float = 600.0, climb: bool = True, speed_m_s: float = 5.0,
            rate_hz: float = 5.0, noise_m: float = 0.003, seed: int = 1,
            ) -> tuple[npt.NDArray[np.int64], Arr]:
    """A straight line at constant speed; with ``climb`` a 1.5 m/s climb at 100 s and the
    descent at 300 s, each speed change a half-cosine ramp of peak 0.5 m/s^2 (4.7 s)."""
    fine = 100.0
    t = np.arange(0.0, duration_s, 1.0 / fine)
    acc_up = np.zeros_like(t)
    if climb:
        ramp = math.pi * 1.5 / (2 * 0.5)
        for start, sign in ((100.0, 1), (100.0 + ramp + 20.0, -1), (300.0, -1),
                            (300.0 + ramp + 20.0, 1)):
            on = (t >= start) & (t < start + ramp)
            acc_up[on] = sign * 0.5 * np.sin(math.pi * (t[on] - start) / ramp)
    enu = np.column_stack([speed_m_s * t, np.zeros_like(t), _integrate(acc_up, 1.0 / fine)])
    step = int(fine / rate_hz)
    enu = enu[::step] + np.random.default_rng(seed).normal(0.0, noise_m, (len(t[::step]), 3))
    t_ns = T0_NS + np.round(t[::step] * 1e9).astype(np.int64)
    return t_ns, _ecef(enu)


def _all(n: int) -> npt.NDArray[np.bool_]:
    return np.ones(n, dtype=bool)


def test_a_steady_line_gets_demo5s_builtin_noise() -> None:
    t, xyz = _flight(climb=False)
    dyn = dy.observed_dynamics(t, xyz, _all(t.size))
    assert dyn is not None
    assert dyn.accel_h_m_s2 < 0.01 and dyn.accel_v_m_s2 < 0.01  # 3 mm noise: ~1 mm/s^2
    assert dy.process_noise(dyn) == dy.FLOOR == (0.1, 0.01)


def test_a_climb_is_measured_and_loosens_the_vertical_only() -> None:
    t, xyz = _flight()
    dyn = dy.observed_dynamics(t, xyz, _all(t.size))
    assert dyn is not None
    # Peak 0.5 m/s^2 over 4.7 s, seen through the +-4 s second difference: ~0.3 at the top;
    # four ramps keep it above ~0.25 for the 10 s of the statistic.
    assert 0.28 <= dyn.peak_v_m_s2 <= 0.32
    assert 0.2 <= dyn.accel_v_m_s2 <= 0.3
    q_h, q_v = dy.process_noise(dyn)
    assert q_h == 0.1
    # What the simulated multicopter's climb needs to stay free of wrong fixes (>= ~0.05),
    # and well under the 3 / 1 ceiling.
    assert 0.05 <= q_v <= 0.08


def test_radio_gaps_do_not_hide_the_climb() -> None:
    t, xyz = _flight()
    whole = dy.observed_dynamics(t, xyz, _all(t.size))
    keep = np.random.default_rng(7).random(t.size) > 0.3  # 30 % of epochs lost
    keep[(t - T0_NS >= 101_000_000_000) & (t - T0_NS < 104_000_000_000)] = False  # 3 s gap
    gappy = dy.observed_dynamics(t[keep], xyz[keep], _all(int(keep.sum())))
    assert whole is not None and gappy is not None
    assert abs(gappy.accel_v_m_s2 - whole.accel_v_m_s2) <= 0.1 * whole.accel_v_m_s2
    # Unusable epochs (float) are skipped the same way as missing ones.
    masked = dy.observed_dynamics(t, xyz, keep)
    assert masked is not None and masked.accel_v_m_s2 == gappy.accel_v_m_s2


def test_a_few_wrong_fixes_do_not_set_the_noise() -> None:
    t, xyz = _flight(climb=False)
    bad = xyz.copy()
    up = np.asarray(enu_rotation(LAT, LON))[2]
    for k in (500, 501, 1500, 2500):  # four epochs 1 m off: each spoils 3 samples of 5 Hz
        bad[k] += up
    dyn = dy.observed_dynamics(t, bad, _all(t.size))
    assert dyn is not None and dyn.peak_v_m_s2 > 0.1  # they are seen ...
    assert dy.process_noise(dyn) == dy.FLOOR  # ... but last far less than 10 s


def test_violent_motion_is_capped_at_the_ceiling() -> None:
    t, xyz = _flight(climb=False)
    secs = (t - T0_NS) / 1e9
    w = 2 * math.pi / 30.0
    up = np.asarray(enu_rotation(LAT, LON))[2]
    east = np.asarray(enu_rotation(LAT, LON))[0]
    shake = (30.0 / w**2) * np.sin(w * secs)  # 30 m/s^2 amplitude, 30 s period
    xyz = xyz + np.outer(shake, up) + np.outer(shake, east)
    dyn = dy.observed_dynamics(t, xyz, _all(t.size))
    assert dyn is not None and dyn.accel_v_m_s2 > 20
    assert dy.process_noise(dyn) == dy.CEILING == (3.0, 1.0)


def test_one_hertz_stamps_a_microsecond_short_work() -> None:
    # The 2018-10-09 M8P rover stamps its 1 Hz epochs 999.999 ms apart now and then.
    t, xyz = _flight(climb=True, rate_hz=1.0)
    t = t - (np.arange(t.size) // 3) * 1000
    dyn = dy.observed_dynamics(t, xyz, _all(t.size))
    assert dyn is not None and dyn.epochs >= t.size - 10
    assert 0.2 <= dyn.accel_v_m_s2 <= 0.3


def test_too_little_motion_data_gives_nothing() -> None:
    t, xyz = _flight(duration_s=100.0, climb=False)
    assert dy.observed_dynamics(t, xyz, _all(t.size)) is None
    ok = np.zeros(t.size, dtype=bool)
    assert dy.observed_dynamics(t, xyz, ok) is None
