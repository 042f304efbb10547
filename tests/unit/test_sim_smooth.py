"""The simulated world is smooth where the real one is: ionosphere in time and space, and the
rover's acceleration (a flight controller limits jerk).

Both were once step functions (the broadcast ionosphere's cut-off, trapezoidal speed profiles)
and made the PPK filter fix wrongly in the seed flight where a real flight gives no such cause.
"""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.geodesy import ecef_to_llh
from groundstation.gnss.atmosphere import (
    KLOBUCHAR_ALPHA_DEFAULT,
    KLOBUCHAR_BETA_DEFAULT,
    klobuchar_delay_m,
    smooth_ionosphere_delay_m,
)
from groundstation.sim.profiles import sim_config
from groundstation.sim.trajectory import DEFAULT_BASE_ENU_M, DEFAULT_SITE_LLH, Trajectory

DT_S = 0.2  # one 5 Hz epoch
TOW_S = np.arange(0.0, 86400.0, DT_S)
LINES_OF_SIGHT = [(az, el) for az in (0.0, 135.0, 270.0) for el in (15.0, 40.0, 85.0)]


def _delays(model: object, lat: float, lon: float) -> np.ndarray:
    assert callable(model)
    return np.stack([
        model(KLOBUCHAR_ALPHA_DEFAULT, KLOBUCHAR_BETA_DEFAULT, lat, lon, az, el, TOW_S)
        for az, el in LINES_OF_SIGHT
    ])


def _site_and_base() -> tuple[tuple[float, float], tuple[float, float]]:
    traj = Trajectory(sim_config("seed", duration_s=1200.0).trajectory)
    lat, lon, _ = ecef_to_llh(*traj.enu_to_ecef(DEFAULT_BASE_ENU_M))
    return (DEFAULT_SITE_LLH[0], DEFAULT_SITE_LLH[1]), (lat, lon)


@pytest.mark.parametrize("model", [smooth_ionosphere_delay_m, klobuchar_delay_m])
def test_ionosphere_has_no_step_between_epochs(model: object) -> None:
    """Over a whole day the simulator's ionosphere moves < 1 mm per 0.2 s on every line of sight;
    the broadcast model (kept as the standard has it) steps by centimetres at its cut-off."""
    d = _delays(model, *DEFAULT_SITE_LLH[:2])
    step = float(np.max(np.abs(np.diff(d, axis=1))))
    if model is klobuchar_delay_m:
        assert step > 0.01  # the step this test exists to catch
    else:
        assert step < 0.001, f"{step * 1000:.1f} mm in one epoch"


@pytest.mark.parametrize("model", [smooth_ionosphere_delay_m, klobuchar_delay_m])
def test_rover_and_base_see_nearly_the_same_ionosphere(model: object) -> None:
    """Rover and base a few hundred metres apart, same line of sight: the between-receiver
    difference (what a double difference keeps) stays at millimetres all day. With the broadcast
    model they cross its cut-off seconds apart and differ by centimetres meanwhile."""
    rover, base = _site_and_base()
    diff = float(np.max(np.abs(_delays(model, *rover) - _delays(model, *base))))
    if model is klobuchar_delay_m:
        assert diff > 0.01
    else:
        assert diff < 0.003, f"{diff * 1000:.1f} mm between rover and base"


def test_smooth_ionosphere_has_the_broadcast_model_shape() -> None:
    """Same amplitude, period and night-time floor: within 2 % of the day's largest delay of the
    broadcast model (its series and the cosine differ by that much near the cut-off), equal at
    night."""
    smooth = _delays(smooth_ionosphere_delay_m, *DEFAULT_SITE_LLH[:2])
    brdc = _delays(klobuchar_delay_m, *DEFAULT_SITE_LLH[:2])
    diff = np.abs(smooth - brdc)
    assert float(np.median(diff)) < 1e-6  # night: both the constant 5 ns
    assert np.all(diff <= 0.02 * brdc.max(axis=1, keepdims=True))
    assert float(smooth.max()) > 5.0  # a daytime ionosphere of metres at low elevation


def test_rover_acceleration_is_continuous_and_jerk_limited() -> None:
    """Seed flight: acceleration never steps (finite differences at 10 ms), peaks at the
    configured 1 m/s^2 horizontally and 0.5 m/s^2 in the climb, jerk below 2 m/s^3."""
    cfg = sim_config("seed", duration_s=1200.0).trajectory
    traj = Trajectory(cfg)
    dt = 0.01
    t = np.arange(0.0, traj.duration_s, dt)
    pos, vel = traj.enu(t)
    # Velocity is the derivative of position (closed forms agree).
    assert float(np.max(np.abs(np.diff(pos, axis=0) / dt - 0.5 * (vel[1:] + vel[:-1])))) < 1e-4
    acc = np.diff(vel, axis=0) / dt
    jerk = np.diff(acc, axis=0) / dt
    assert float(np.max(np.hypot(acc[:, 0], acc[:, 1]))) <= cfg.accel_m_s2 * 1.001
    assert float(np.max(np.abs(acc[:, 2]))) <= cfg.accel_m_s2 * 0.5 * 1.001
    # A step of 1 m/s^2 would show as 100 m/s^3 here.
    assert float(np.max(np.abs(jerk))) < 2.0
    # Still a real flight: it climbs to the survey height and comes back down.
    assert float(pos[:, 2].max()) == pytest.approx(cfg.height_m)
    assert float(np.abs(pos[-1]).max()) < 1e-9


def test_exposures_are_at_their_distances() -> None:
    """The planned exposures lie exactly every ``exposure_spacing_m`` along each line."""
    traj = Trajectory(sim_config("seed", duration_s=1200.0).trajectory)
    spacing = traj.config.exposure_spacing_m
    for leg in (lg for lg in traj.legs if lg.is_line):
        times = [e.t_s for e in traj.exposures() if leg.t0_s <= e.t_s <= leg.t0_s + leg.duration_s]
        s, _ = leg.distance(np.asarray(times) - leg.t0_s)
        expect = spacing / 2 + spacing * np.arange(len(times))
        assert np.max(np.abs(s - expect)) < 1e-6
