"""The rover's observed dynamics and the Kalman acceleration noise derived from them.

RTKLIB's kinematic filter carries position, velocity and acceleration, and lets the acceleration
wander as a random walk of ``stats-prnaccelh`` (east, north) and ``stats-prnaccelv`` (up) m/s^2
per sqrt(s). No single pair suits every platform (measured in ``options.py`` and
``benchmarks/RESULTS.md``): a walk with a GNSS pole agrees best with RTKLIB's reference at
demo5's built-in 0.1 / 0.01, while a multicopter's climb needs at least 0.05 vertical to avoid
wrong fixes. So the default solve first measures how the rover moved (a forward-only pass of
the same engine, :func:`observed_dynamics`) and then sets the noise from that
(:func:`process_noise`). This module owns both rules; ``engine.run_engine`` runs the pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation.geodesy import ecef_to_llh, enu_rotation

FloatArray = npt.NDArray[np.float64]

BASELINE_S = 4.0
"""Half-width of the second difference that gives the acceleration. Over +-4 s a fixed
position's centimetre noise contributes ~1.5 mm/s^2 and a walker's steps (about 2 Hz) and an
airframe's vibration average out: what remains is the sustained acceleration of a manoeuvre
(a 0.5 m/s^2 half-sine climb ramp of 4.7 s reads 0.3 m/s^2), which is what the filter's
dynamics model has to follow; the jolts within are the measurements' business."""

EXCEEDED_S = 10.0
"""The statistic: the acceleration the rover exceeded for this many seconds of the pass in total.
A time, not a percentile, so that one climb in an hour-long flight counts as much as in a
ten-minute one, while a few wrong fixes of the pass (a few epochs each) cannot set it."""

GAIN = (0.5, 0.24)
"""Noise per observed acceleration, horizontal / vertical, 1/sqrt(s): q = GAIN * A, i.e. the
filter's acceleration random walk reaches the observed acceleration A (1 sigma) in 1 / GAIN^2
= 4 s horizontally, 17 s vertically. Calibrated, not derived, on two platforms
(benchmarks/RESULTS.md), with thin margins:
- vertical: the real 2018-10-09 walk (A_v 0.055 m/s^2 from our forward pass) agrees with RTKLIB's
  reference to 2 cm at p95 up to q_v ~0.016 (0.018: 2.05 cm); the simulated multicopter (A_v
  0.25-0.26) leaves wrong fixes in its climb below ~0.048 (0.044: one, 0.036: five). 0.19-0.29
  serve both; 0.24 is the middle.
- horizontal: the walk (A_h 0.31) stays under 2 cm up to q_h ~0.16 (0.14: 1.93 cm, 0.16: 1.95,
  0.2 with q_v 0.01: 2.20); the simulated multicopter (A_h 0.65) needs ~0.3 in the 1-hour
  flight (0.2 and 0.16: one wrong integer set, 230-340 epochs up to 97 cm; 0.3: 5 epochs, as
  the constant default), although 0.1 keeps the 20-minute flights clean. 0.46-0.55 serve both;
  0.5 is the middle."""


FLOOR = (0.1, 0.01)
"""Lowest noise, horizontal / vertical: demo5's built-in values, the stiffest RTKLIB ships; a rover
that barely moves (a walk on flat ground, a static test) gets them. Stiffer would trust the
dynamics model more than a measurement the pass cannot resolve (its noise is ~0.002 m/s^2)."""

CEILING = (3.0, 1.0)
"""Highest noise: demo5's published M8T settings for cars; a first pass full of wrong fixes
(metre jumps) must not leave the filter with no dynamics model at all."""

MAX_WEIGHT_S = 1.0
"""Longest time one sample stands for (a 1 Hz receiver's epoch; across a longer gap nothing is
known of the motion)."""

MIN_SPAN_S = 120.0
"""Fewer usable seconds than this (e.g. a pass that never fixed) and nothing is derived."""

MIN_COVERAGE = 0.75
"""Below this share of the pass's time covered by usable samples, the pass may have missed the
manoeuvres (the 1-hour simulated flight: the forward pass lost its fix before the descent and
read A_v 0.14 where the truth has 0.25); the derived noise may then only be looser than the
constant default, never stiffer. The 2018-10-09 walk covers 80 %, the 20-minute simulated
flights 97 %."""

@dataclass(frozen=True, slots=True)
class Dynamics:
    """What a pass says about the rover's motion.

    Attributes:
        accel_h_m_s2: horizontal acceleration exceeded for :data:`EXCEEDED_S` s (norm of E, N).
        accel_v_m_s2: the same for the vertical.
        peak_h_m_s2: largest horizontal acceleration seen (for the report).
        peak_v_m_s2: largest vertical acceleration seen.
        seconds: how much of the pass the statistic covers (epochs with both neighbours usable).
        epochs: how many such epochs.
        span_s: the pass's whole time span.
    """

    accel_h_m_s2: float
    accel_v_m_s2: float
    peak_h_m_s2: float
    peak_v_m_s2: float
    seconds: float
    epochs: int
    span_s: float

    @property
    def coverage(self) -> float:
        """Share of the pass's time span that the statistic covers."""
        return self.seconds / self.span_s if self.span_s > 0 else 0.0

    def as_dict(self) -> dict[str, float | int]:
        return {
            "accel_h_m_s2": round(self.accel_h_m_s2, 4),
            "accel_v_m_s2": round(self.accel_v_m_s2, 4),
            "peak_h_m_s2": round(self.peak_h_m_s2, 4),
            "peak_v_m_s2": round(self.peak_v_m_s2, 4),
            "seconds": round(self.seconds, 1),
            "epochs": self.epochs,
            "coverage": round(self.coverage, 3),
        }


def nearest_index(t: npt.NDArray[np.int64], target: npt.NDArray[np.int64]
                  ) -> npt.NDArray[np.intp]:
    """Index of the element of sorted ``t`` nearest to each ``target``."""
    hi = np.clip(np.searchsorted(t, target), 1, t.size - 1)
    lo = hi - 1
    return np.where(np.abs(t[hi] - target) < np.abs(t[lo] - target), hi, lo)


def _second_difference(
    t: npt.NDArray[np.int64], enu: FloatArray, baseline_s: float,
) -> tuple[npt.NDArray[np.bool_], FloatArray]:
    """The acceleration at each epoch from the epochs nearest to +-``baseline_s`` (accepted
    within a quarter of it): ``2 ((p+ - p) / h+ - (p - p-) / h-) / (h+ + h-)``; (which epochs
    have both neighbours, their accelerations)."""
    h_ns = int(round(baseline_s * 1e9))
    jp, jm = nearest_index(t, t + h_ns), nearest_index(t, t - h_ns)
    hp = (t[jp] - t) / 1e9
    hm = (t - t[jm]) / 1e9
    good = (np.abs(hp - baseline_s) <= baseline_s / 4) & (np.abs(hm - baseline_s) <= baseline_s / 4)
    hp, hm = hp[good, None], hm[good, None]
    p0 = enu[good]
    a = 2.0 * ((enu[jp[good]] - p0) / hp - (p0 - enu[jm[good]]) / hm) / (hp + hm)
    return good, np.asarray(a, dtype=np.float64)


def _local_enu(ecef_m: FloatArray) -> FloatArray:
    lat, lon, _ = ecef_to_llh(*(float(v) for v in ecef_m[0]))
    return np.asarray(ecef_m @ np.asarray(enu_rotation(lat, lon)).T, dtype=np.float64)


def accelerations(
    t_gps_ns: npt.NDArray[np.int64], ecef_m: FloatArray, usable: npt.NDArray[np.bool_],
    baseline_s: float = BASELINE_S,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Horizontal and vertical acceleration at every usable epoch from the usable epochs nearest
    to +-``baseline_s`` (accepted within a quarter of it, so a radio gap there costs nothing):
    the second difference ``2 ((p+ - p) / h+ - (p - p-) / h-) / (h+ + h-)`` in the local
    east/north/up frame.

    Returns:
        (|a| horizontal, |a| vertical, seconds each sample stands for), in epoch order. A sample
        stands for half the time to each neighbouring sample, at most :data:`MAX_WEIGHT_S`: where
        epochs are lost (radio gaps, float epochs) the remaining ones cover the time.
    """
    ok = np.asarray(usable, dtype=bool)
    if int(ok.sum()) < 3:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    t = np.asarray(t_gps_ns, dtype=np.int64)[ok]
    enu = _local_enu(np.asarray(ecef_m, dtype=np.float64)[ok])
    good, a = _second_difference(t, enu, baseline_s)
    ts = t[good] / 1e9
    if ts.size < 2:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    half = np.diff(ts) / 2
    weight = np.minimum(np.concatenate([half[:1], half]) + np.concatenate([half, half[-1:]]),
                        MAX_WEIGHT_S)
    return np.hypot(a[:, 0], a[:, 1]), np.abs(a[:, 2]), weight


def local_acceleration(
    t_gps_ns: npt.NDArray[np.int64], ecef_m: FloatArray, baseline_s: float = 1.0,
) -> FloatArray:
    """|acceleration| (3-D) at each epoch over +-``baseline_s`` (NaN where an epoch lacks a
    neighbour there): what a straight line between two epochs misses by (``a h^2 / 8``)."""
    t = np.asarray(t_gps_ns, dtype=np.int64)
    out = np.full(t.size, np.nan)
    if t.size < 3:
        return out
    good, a = _second_difference(t, _local_enu(np.asarray(ecef_m, dtype=np.float64)),
                                 baseline_s)
    out[good] = np.linalg.norm(a, axis=1)
    return out


def exceeded_for(values: FloatArray, weight_s: FloatArray, seconds: float = EXCEEDED_S) -> float:
    """The value that ``values`` (each standing for ``weight_s`` seconds) exceed for ``seconds``
    in total."""
    order = np.argsort(values)[::-1]
    k = int(np.searchsorted(np.cumsum(weight_s[order]), seconds))
    return float(values[order[min(k, order.size - 1)]])


def observed_dynamics(
    t_gps_ns: npt.NDArray[np.int64], ecef_m: FloatArray, usable: npt.NDArray[np.bool_],
) -> Dynamics | None:
    """The rover's acceleration statistics from a solution's usable (fixed) epochs.

    Returns:
        None when fewer than :data:`MIN_SPAN_S` seconds have usable neighbours.
    """
    ah, av, w = accelerations(t_gps_ns, ecef_m, usable)
    if ah.size == 0 or float(w.sum()) < MIN_SPAN_S:
        return None
    span = float(np.asarray(t_gps_ns)[-1] - np.asarray(t_gps_ns)[0]) / 1e9
    return Dynamics(
        exceeded_for(ah, w), exceeded_for(av, w), float(ah.max()), float(av.max()),
        float(w.sum()), int(ah.size), span,
    )


def process_noise(
    dyn: Dynamics, constant: tuple[float, float] | None = None
) -> tuple[float, float]:
    """(``stats-prnaccelh``, ``stats-prnaccelv``) for the observed dynamics:
    ``clamp(GAIN * A, FLOOR, CEILING)`` per axis, rounded to two significant digits; with a
    coverage under :data:`MIN_COVERAGE`, at least ``constant`` (the default it replaces)."""
    out = []
    lows = FLOOR
    if constant is not None and dyn.coverage < MIN_COVERAGE:
        lows = (max(FLOOR[0], constant[0]), max(FLOOR[1], constant[1]))
    for acc, gain, lo, hi in zip((dyn.accel_h_m_s2, dyn.accel_v_m_s2), GAIN, lows, CEILING,
                                 strict=True):
        q = min(max(gain * acc, lo), hi)
        out.append(float(f"{q:.2g}"))
    return out[0], out[1]


FORMULA = (
    f"q = clamp({GAIN[0]:g} / {GAIN[1]:g} * A, floor {FLOOR[0]:g} / {FLOOR[1]:g}, ceiling "
    f"{CEILING[0]:g} / {CEILING[1]:g}) m/s^2/sqrt(s) horizontal / vertical, A = the acceleration "
    f"(second difference over +-{BASELINE_S:g} s) exceeded for {EXCEEDED_S:g} s of a forward "
    f"pass's fixed epochs; under {MIN_COVERAGE:.0%} coverage never below the constant default"
)
"""The rule in one line, for engine.json and the report."""
