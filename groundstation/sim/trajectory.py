"""The rover's path: static start, take-off, lawnmower survey lines, landing, static end.

Optionally (the field procedure) a lever-arm calibration pass at a lower height before and after
the survey lines.

Every leg between waypoints has a jerk-limited speed profile (half-cosine ramps: the acceleration
is continuous, as a flight controller makes it; the copter stops at each waypoint), so position
and velocity are closed-form and the time a given distance is reached is found by bisection.
Positions are local east/north/up metres at the take-off point, converted to ECEF in bulk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from groundstation.geodesy import enu_rotation, llh_to_ecef

FloatArray = NDArray[np.float64]

DEFAULT_SITE_LLH = (49.01300, 8.40400, 165.0)
"""Take-off point: a field near Karlsruhe (ETRS89 / UTM 32N), ellipsoidal height in metres."""
DEFAULT_BASE_ENU_M = (-260.0, 180.0, 1.5)
"""Base antenna relative to the take-off point: a few hundred metres away, on a tripod."""


@dataclass(frozen=True, slots=True)
class TrajectoryConfig:
    """Shape and timing of the flight.

    Attributes:
        static_start_s: static initialisation before take-off.
        static_end_s: static period after landing.
        height_m: survey height above the take-off point.
        speed_m_s: cruise speed on the lines.
        climb_m_s: vertical speed in take-off and landing.
        accel_m_s2: peak acceleration at the ends of each leg (the climb and the descent use half).
        line_length_m: length of one survey line.
        line_spacing_m: distance between neighbouring lines.
        n_lines: number of lines, flown in alternating directions.
        heading_deg: direction of the first line (clockwise from north).
        dwell_s: hover at each waypoint.
        exposure_spacing_m: distance between camera exposures on the lines.
        site_llh: take-off point (deg, deg, m).
        calibration_height_m: if set, a lever-arm calibration pass over the first line at this
            height (lower: over surveyed targets) before the survey and another after it.
    """

    static_start_s: float = 60.0
    static_end_s: float = 60.0
    height_m: float = 30.0
    speed_m_s: float = 2.0
    climb_m_s: float = 1.5
    accel_m_s2: float = 1.0
    line_length_m: float = 100.0
    line_spacing_m: float = 20.0
    n_lines: int = 4
    heading_deg: float = 30.0
    dwell_s: float = 1.0
    exposure_spacing_m: float = 2.0
    site_llh: tuple[float, float, float] = DEFAULT_SITE_LLH
    calibration_height_m: float | None = None

    @classmethod
    def for_duration(
        cls,
        duration_s: float,
        template: TrajectoryConfig | None = None,
        static_fraction: float = 0.25,
    ) -> TrajectoryConfig:
        """A configuration whose whole span is about ``duration_s``: ``static_fraction`` of it
        static at each end, the flight in between with as many (and as long) lines as
        ``template`` allows."""
        base = template if template is not None else cls()
        static = max(duration_s * static_fraction, 2.0)
        budget = duration_s - 2 * static
        length = base.line_length_m
        n = base.n_lines
        while True:
            trial = replace(base, static_start_s=static, static_end_s=static,
                            line_length_m=length, n_lines=n)
            flight = Trajectory(trial).flight_s
            if flight <= budget or (n == 1 and length <= 10.0):
                break
            if n > 1:
                n -= 1
            else:
                length = max(10.0, length * 0.7)
        # Give any remainder to the static periods so the total matches.
        extra = max(0.0, budget - flight) / 2
        return replace(trial, static_start_s=static + extra, static_end_s=static + extra)


@dataclass(frozen=True, slots=True)
class Leg:
    """A straight move between two waypoints, starting at ``t0_s``, jerk-limited.

    Speed rises and falls as half a cosine (``v/2 (1 - cos(pi t / T))`` over the ramp time
    ``T``), so the acceleration is a half sine: continuous, zero at rest and at cruise speed, at
    most ``accel_m_s2``. A multicopter's flight controller limits jerk the same way; a
    trapezoidal speed profile would step the acceleration by ``accel_m_s2`` at four instants of
    every leg, which no airframe does and which a PPK filter's dynamics model (acceleration as a
    slow random walk) is right to distrust.
    """

    t0_s: float
    start_enu_m: tuple[float, float, float]
    end_enu_m: tuple[float, float, float]
    v_max_m_s: float
    accel_m_s2: float
    is_line: bool
    calibration: bool = False

    @property
    def length_m(self) -> float:
        return math.dist(self.start_enu_m, self.end_enu_m)

    def _profile(self) -> tuple[float, float, float]:
        """(ramp time, top speed, total time).

        The ramp to speed ``v`` with peak acceleration ``a`` takes ``T = pi v / (2 a)`` and covers
        ``v T / 2``; a leg too short for two ramps at ``v_max`` never reaches it.
        """
        d, a, v = self.length_m, self.accel_m_s2, self.v_max_m_s
        if d <= math.pi * v * v / (2 * a):  # two ramps, no cruise
            v = math.sqrt(2 * a * d / math.pi)
        if v <= 0:
            return 0.0, 0.0, 0.0
        ta = math.pi * v / (2 * a)
        cruise = (d - v * ta) / v
        return ta, v, 2 * ta + max(cruise, 0.0)

    @property
    def duration_s(self) -> float:
        return self._profile()[2]

    def _ramp(self, t: FloatArray, ta: float, v: float) -> tuple[FloatArray, FloatArray]:
        """Distance and speed ``t`` seconds into the ramp up (``0 <= t <= ta``)."""
        w = np.pi / ta
        return 0.5 * v * (t - np.sin(w * t) / w), 0.5 * v * (1.0 - np.cos(w * t))

    def distance(self, tau_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Distance along the leg and speed at times since the leg started."""
        ta, v, total = self._profile()
        if total <= 0:
            z = np.zeros_like(np.asarray(tau_s, dtype=np.float64))
            return z, z
        t = np.clip(tau_s, 0.0, total)
        up_s, up_v = self._ramp(np.minimum(t, ta), ta, v)
        down_s, down_v = self._ramp(np.minimum(total - t, ta), ta, v)
        s = np.where(t < ta, up_s,
                     np.where(t <= total - ta, 0.5 * v * ta + v * (t - ta),
                              self.length_m - down_s))
        spd = np.where(t < ta, up_v, np.where(t <= total - ta, v, down_v))
        return s, spd

    def time_at_distance(self, s_m: float) -> float:
        """Seconds after the leg start at which the distance ``s_m`` is reached."""
        ta, v, total = self._profile()
        if total <= 0:
            return 0.0
        d_ramp = 0.5 * v * ta
        if d_ramp <= s_m <= self.length_m - d_ramp:
            return ta + (s_m - d_ramp) / v
        w = math.pi / ta
        target = s_m if s_m < d_ramp else self.length_m - s_m
        target = min(max(target, 0.0), d_ramp)
        lo, hi = 0.0, ta
        for _ in range(60):  # the ramp's distance grows monotonically: bisection
            mid = 0.5 * (lo + hi)
            if 0.5 * v * (mid - math.sin(w * mid) / w) < target:
                lo = mid
            else:
                hi = mid
        t = 0.5 * (lo + hi)
        return t if s_m < d_ramp else total - t


@dataclass(frozen=True, slots=True)
class Turn:
    """The copter turning from one survey line to the next.

    Attributes:
        t_s: seconds since the trajectory start when the line ends and the turn begins.
        away_azimuth_deg: the side it banks away from (clockwise from north): the airframe
            hides low satellites there.
    """

    t_s: float
    away_azimuth_deg: float


@dataclass(frozen=True, slots=True)
class Exposure:
    """A planned camera exposure: seconds since the trajectory start, line index."""

    t_s: float
    line: int


class Trajectory:
    """The rover's antenna path; times in seconds since the start of the simulation."""

    def __init__(self, config: TrajectoryConfig) -> None:
        self.config = config
        c = config
        self.origin_ecef_m = llh_to_ecef(*c.site_llh)
        self._rot = np.array(enu_rotation(c.site_llh[0], c.site_llh[1]), dtype=np.float64)
        h = math.radians(c.heading_deg)
        along = (math.sin(h), math.cos(h))
        across = (math.cos(h), -math.sin(h))
        pts: list[tuple[tuple[float, float, float], float, float, bool, bool]] = []
        up = (0.0, 0.0, c.height_m)
        line0 = ((0.0, 0.0), (c.line_length_m * along[0], c.line_length_m * along[1]))

        def calibration_pass(v_to_start: float, acc_to_start: float) -> None:
            if c.calibration_height_m is None:
                return
            hc = c.calibration_height_m
            pts.append(((*line0[0], hc), v_to_start, acc_to_start, False, False))
            pts.append(((*line0[1], hc), c.speed_m_s, c.accel_m_s2, True, True))

        calibration_pass(c.climb_m_s, c.accel_m_s2 * 0.5)  # straight up from the take-off point
        pts.append((up, c.climb_m_s, c.accel_m_s2 * 0.5, False, False))
        for k in range(c.n_lines):
            off = (k * c.line_spacing_m * across[0], k * c.line_spacing_m * across[1])
            a = (off[0], off[1], c.height_m)
            b = (off[0] + c.line_length_m * along[0], off[1] + c.line_length_m * along[1],
                 c.height_m)
            first, second = (a, b) if k % 2 == 0 else (b, a)
            pts.append((first, c.speed_m_s * 2, c.accel_m_s2, False, False))
            pts.append((second, c.speed_m_s, c.accel_m_s2, True, False))
        calibration_pass(c.speed_m_s * 2, c.accel_m_s2)
        pts.append((up, c.speed_m_s * 2, c.accel_m_s2, False, False))
        pts.append(((0.0, 0.0, 0.0), c.climb_m_s, c.accel_m_s2 * 0.5, False, False))
        legs: list[Leg] = []
        t = c.static_start_s
        here = (0.0, 0.0, 0.0)
        for target, v, acc, is_line, calibration in pts:
            if math.dist(here, target) < 1e-9:
                continue
            leg = Leg(t, here, target, v, acc, is_line, calibration)
            legs.append(leg)
            t += leg.duration_s + c.dwell_s
            here = target
        self.legs = tuple(legs)
        self.takeoff_s = c.static_start_s
        self.landing_s = t
        self.flight_s = t - c.static_start_s
        self.duration_s = t + c.static_end_s
        self._starts = np.array([lg.t0_s for lg in legs], dtype=np.float64)

    def enu(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Local ENU position and velocity (m, m/s) at times ``t_s``; shape (..., 3)."""
        t = np.asarray(t_s, dtype=np.float64)
        pos = np.zeros(t.shape + (3,), dtype=np.float64)
        vel = np.zeros(t.shape + (3,), dtype=np.float64)
        idx = np.searchsorted(self._starts, t, side="right") - 1
        for i, leg in enumerate(self.legs):
            sel = idx == i
            if not np.any(sel):
                continue
            s, spd = leg.distance(t[sel] - leg.t0_s)
            d = np.subtract(leg.end_enu_m, leg.start_enu_m) / max(leg.length_m, 1e-12)
            pos[sel] = np.asarray(leg.start_enu_m) + s[:, None] * d
            vel[sel] = spd[:, None] * d
        if self.legs:
            last = self.legs[-1]
            after = t >= last.t0_s + last.duration_s
            pos[after] = last.end_enu_m
            vel[after] = 0.0
        return pos, vel

    def ecef(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """ECEF position and velocity (m, m/s) at times ``t_s``; shape (..., 3)."""
        pos, vel = self.enu(t_s)
        return pos @ self._rot + np.asarray(self.origin_ecef_m), vel @ self._rot

    def enu_to_ecef(self, enu_m: tuple[float, float, float]) -> tuple[float, float, float]:
        x = np.asarray(enu_m, dtype=np.float64) @ self._rot + np.asarray(self.origin_ecef_m)
        return float(x[0]), float(x[1]), float(x[2])

    def exposures(self) -> list[Exposure]:
        """Exposures every ``exposure_spacing_m`` along each survey line."""
        out: list[Exposure] = []
        spacing = self.config.exposure_spacing_m
        line = 0
        for leg in self.legs:
            if not leg.is_line:
                continue
            s = spacing / 2
            while s < leg.length_m:
                out.append(Exposure(leg.t0_s + leg.time_at_distance(s), line))
                s += spacing
            line += 1
        return out

    def turns(self) -> list[Turn]:
        """One turn at the end of every survey line that another survey line follows."""
        h = math.radians(self.config.heading_deg)
        # The next line lies across the first (see __init__); the copter banks towards it.
        away = math.degrees(math.atan2(-math.cos(h), math.sin(h))) % 360.0
        ends = [lg.t0_s + lg.duration_s for lg in self.legs if lg.is_line and not lg.calibration]
        return [Turn(t, away) for t in ends[:-1]]

    def phase(self, t_s: float) -> str:
        """``static``, ``flight`` or ``static`` again: for the squaring model and summaries."""
        return "flight" if self.takeoff_s <= t_s < self.landing_s else "static"
