"""The camera's own clock, fitted on the photos paired with marks, to time the photos whose mark
never arrived.

A photo paired with a mark keeps the mark's time. For the pairs, ``mark − photo`` is the camera
clock's error: an offset and a drift (a quartz clock drifts by tens of ppm, a few
centimetres of flight per minute at survey speeds), plus each photo's own timing noise (the
shutter latency's jitter, the EXIF time's resolution). :func:`fit` estimates offset and drift
by least squares, leaving out pairs more than :data:`OUTLIER_SIGMAS` robust sigmas away (a
photo paired with the wrong mark), and keeps the spread of what is left. A photo without a
mark is then timed at ``photo + offset + drift·(photo − middle)``, with a timing sigma that
adds the fit's own uncertainty at that time to the photos' timing noise: whole-second EXIF
photos carry at least the uniform spread of their second (1/√12 s).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from groundstation.rules.marks import Mark, count_jump
from groundstation.solve.trajectory import Trajectory

if TYPE_CHECKING:
    from groundstation.solve.interpolate import MarkPositions

FloatArray = npt.NDArray[np.float64]
Interpolate = Callable[[Trajectory, Sequence[int | None], str, float], "MarkPositions"]
"""Positions at instants (:func:`groundstation.solve.interpolate.interpolate`'s signature)."""

OUTLIER_SIGMAS = 5.0
"""Pairs whose residual is further than this many robust sigmas from the fit are left out."""
WHOLE_SECOND_SD_S = 1.0 / math.sqrt(12.0)
"""The timing sigma of a photo whose EXIF time has whole seconds: uniform over its second."""
MIN_PAIRS = 3
"""Pairs needed to fit an offset and a drift and know their spread."""


@dataclass(frozen=True, slots=True)
class CameraClock:
    """The camera clock fitted on the pairs: ``gps_s = photo_s + offset_s + drift·(photo_s −
    t_mid_s)``.

    Attributes:
        offset_s, drift: the fit (drift in s/s).
        t_mid_s: the reference time on the camera clock (mean of the pairs used).
        cov: covariance of (offset, drift).
        sd_precise_s, sd_whole_s: the timing noise of photos with sub-second times and of
            whole-second photos (robust spread of their residuals; NaN without such pairs).
        used, outliers: pairs in the fit and pairs left out.
    """

    offset_s: float
    drift: float
    t_mid_s: float
    cov: FloatArray
    sd_precise_s: float
    sd_whole_s: float
    used: int
    outliers: int

    def gps_s(self, photo_s: float) -> float:
        return photo_s + self.offset_s + self.drift * (photo_s - self.t_mid_s)

    def sigma_s(self, photo_s: float, precise: bool) -> float:
        """The timing sigma of a photo timed by the clock: the fit's uncertainty there and
        the photo's own noise."""
        d = photo_s - self.t_mid_s
        fit_var = float(self.cov[0, 0] + 2 * d * self.cov[0, 1] + d * d * self.cov[1, 1])
        own = self.sd_precise_s if precise else self.sd_whole_s
        if not math.isfinite(own):
            own = WHOLE_SECOND_SD_S
        if not precise:
            own = max(own, WHOLE_SECOND_SD_S)
        return math.sqrt(max(fit_var, 0.0) + own * own)

    def text(self) -> str:
        sd = [f"{v * 1e3:.0f} ms" for v in (self.sd_precise_s, self.sd_whole_s)
              if math.isfinite(v)]
        return (f"camera clock fitted on {self.used} paired photos ({self.outliers} left out): "
                f"drift {self.drift * 1e6:+.1f} ppm, photo timing spread "
                f"{' / '.join(sd) or 'unknown'}")


def _robust_sd(r: FloatArray) -> float:
    if r.size < 2:
        return math.nan
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def fit(photo_s: FloatArray, mark_s: FloatArray, precise: npt.NDArray[np.bool_],
        ) -> CameraClock | None:
    """Offset and drift from paired photo and mark times (camera clock, GPS; seconds), or None
    with fewer than :data:`MIN_PAIRS` pairs."""
    ok = np.isfinite(photo_s) & np.isfinite(mark_s)
    p, m, pr = photo_s[ok], mark_s[ok], precise[ok]
    if p.size < MIN_PAIRS:
        return None
    # Photos with sub-second times say more: fit on them when there are enough.
    fit_on = pr if int(pr.sum()) >= MIN_PAIRS else np.ones(p.size, bool)
    use = fit_on.copy()
    y = m - p
    coef = np.zeros(2)
    t_mid = float(np.mean(p[use]))
    for _ in range(5):
        t_mid = float(np.mean(p[use]))
        a = np.column_stack([np.ones(int(use.sum())), p[use] - t_mid])
        coef = np.linalg.lstsq(a, y[use], rcond=None)[0]
        r = y - (coef[0] + coef[1] * (p - t_mid))
        sd = _robust_sd(r[use])
        if not math.isfinite(sd) or sd == 0.0:
            break
        new = fit_on & (np.abs(r) <= OUTLIER_SIGMAS * sd)
        if int(new.sum()) < MIN_PAIRS or np.array_equal(new, use):
            break
        use = new
    a = np.column_stack([np.ones(int(use.sum())), p[use] - t_mid])
    r = y - (coef[0] + coef[1] * (p - t_mid))
    n, k = int(use.sum()), 2
    s2 = float(np.sum(r[use] ** 2) / max(n - k, 1))
    try:
        cov = s2 * np.linalg.inv(a.T @ a)
    except np.linalg.LinAlgError:
        cov = np.full((2, 2), np.inf)
    inliers = np.abs(r) <= OUTLIER_SIGMAS * max(_robust_sd(r[use]), 1e-6)
    return CameraClock(
        offset_s=float(coef[0]), drift=float(coef[1]), t_mid_s=t_mid, cov=cov,
        sd_precise_s=_robust_sd(r[pr & inliers]) if int((pr & inliers).sum()) >= 2 else math.nan,
        sd_whole_s=_robust_sd(r[~pr & inliers]) if int((~pr & inliers).sum()) >= 2 else math.nan,
        used=n, outliers=int(fit_on.sum()) - n,
    )


def lost_numbers(
    photo_gps_s: Sequence[float], marks: Sequence[Mark], mark_s: Sequence[float],
) -> dict[int, int]:
    """The receiver's number of the lost mark each clock-timed photo stands for, where a count
    jump accounts for exactly the photos between its two received marks: photo index -> number.

    Args:
        photo_gps_s: the clock-timed photos' GPS times (seconds), by photo index order given.
        marks: the received marks, in order; ``mark_s`` their exposure times (NaN: none).
    """
    out: dict[int, int] = {}
    t = np.asarray(photo_gps_s, dtype=np.float64)
    for k, m in enumerate(marks):
        jump = count_jump(m)
        if jump is None or k == 0:
            continue
        lo, hi = mark_s[k - 1], mark_s[k]
        if not (math.isfinite(lo) and math.isfinite(hi)):
            continue
        inside = np.flatnonzero((t > lo) & (t < hi))
        missing = [(jump[0] + i) & 0xFFFF for i in range(1, ((jump[1] - jump[0]) & 0xFFFF))]
        if inside.size == len(missing):
            order = inside[np.argsort(t[inside])]
            out.update(zip(order.tolist(), missing, strict=True))
    return out


@dataclass(frozen=True, slots=True)
class ClockPositions:
    """Photos positioned at their own time (the camera clock): one entry per photo index.

    Attributes:
        photo: photo indices (into the photo list).
        t_gps_ns: the instant used.
        timing_sd_s: the timing sigma (:meth:`CameraClock.sigma_s`).
        ecef_m, sd_enu_m, quality, flags, grade, check: as :class:`MarkPositions`, the timing
            sigma times the antenna's velocity added to ``sd_enu_m``.
    """

    photo: tuple[int, ...]
    t_gps_ns: npt.NDArray[np.int64]
    timing_sd_s: FloatArray
    ecef_m: FloatArray
    sd_enu_m: FloatArray
    quality: npt.NDArray[np.int64]
    flags: npt.NDArray[np.int64]
    grade: npt.NDArray[np.int64]
    check: npt.NDArray[np.int64]

    def index(self) -> dict[int, int]:
        return {p: j for j, p in enumerate(self.photo)}


VELOCITY_STEP_NS = 100_000_000
"""Half the time step over which the antenna's velocity is taken (one 5 Hz epoch)."""


def position_photos(
    traj: Trajectory, clock: CameraClock, photo_s: FloatArray, precise: npt.NDArray[np.bool_],
    photos: Sequence[int], method: str, max_gap_s: float,
    interpolate: Interpolate | None = None,
) -> ClockPositions:
    """The antenna at each photo's clock time, its sigma widened by the timing sigma times the
    velocity there (a fixed epoch's photo whose sigma is then no longer a centimetre one is
    demoted to float, as an interpolated mark is)."""
    from groundstation.geodesy import ecef_to_llh, enu_rotation
    from groundstation.solve import interpolate as mi
    from groundstation.solve.integrity import grade as gr
    from groundstation.solve.trajectory import Q_FLOAT

    idx = [i for i in photos if math.isfinite(photo_s[i])]
    t_ns = [round(clock.gps_s(float(photo_s[i])) * 1e9) for i in idx]
    sd_t = np.array([clock.sigma_s(float(photo_s[i]), bool(precise[i])) for i in idx])
    at_times = interpolate or mi.interpolate
    at = at_times(traj, t_ns, method, max_gap_s)
    before = at_times(traj, [t - VELOCITY_STEP_NS for t in t_ns], "linear", max_gap_s)
    after = at_times(traj, [t + VELOCITY_STEP_NS for t in t_ns], "linear", max_gap_s)
    step_s = VELOCITY_STEP_NS / 1e9
    v_ecef = (after.ecef_m - before.ecef_m) / (2 * step_s)
    # at an end of the trajectory (or of a gap), one side only
    one = ~np.all(np.isfinite(v_ecef), axis=1)
    v_ecef[one] = np.where(np.isfinite(after.ecef_m[one]), after.ecef_m[one] - at.ecef_m[one],
                           at.ecef_m[one] - before.ecef_m[one]) / step_s
    sd = at.sd_enu_m.copy()
    for j in range(len(idx)):
        if not np.all(np.isfinite(at.ecef_m[j])):
            continue
        lat, lon, _ = ecef_to_llh(*at.ecef_m[j].tolist())
        v = np.asarray(enu_rotation(lat, lon)) @ v_ecef[j]
        if not np.all(np.isfinite(v)):  # a lone epoch: no speed to tell, none added
            v = np.zeros(3)
        sd[j] = np.sqrt(sd[j] ** 2 + (v * sd_t[j]) ** 2)
    grade, check = at.grade.copy(), at.check.copy()
    loose = (grade == gr.FIXED) & ~np.all(sd <= gr.FIXED_MAX_SIGMA_M, axis=1)
    grade[loose] = gr.FLOAT
    check[loose] = gr.C_DEM_CLOCK
    quality = np.where(loose, Q_FLOAT, at.quality)
    flags = np.where(loose, at.flags | mi.FLAG_NOT_FIXED, at.flags) | mi.FLAG_CAMERA_CLOCK
    return ClockPositions(tuple(idx), at.t_gps_ns, sd_t, at.ecef_m, sd, quality,
                          flags.astype(np.int64), grade, check)
