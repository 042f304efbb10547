"""Synthetic photo sets with known truth: camera clock error, bursts, missing and extra marks.

Used by the tests, the matching benchmark and the demo flight. :func:`photo_scenario` is pure;
:func:`write_photo_set` writes real JPEGs with real EXIF through :func:`exif.make_jpeg`.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from groundstation import gpstime
from groundstation.solve.exif import make_jpeg


@dataclass(frozen=True, slots=True)
class SimPhoto:
    """One synthetic photo: its file name, EXIF fields and the true shutter time."""

    name: str
    exif_datetime: dt.datetime
    subsec: str | None
    offset_time: str | None
    true_t_gps_ns: int


@dataclass(frozen=True, slots=True)
class PhotoScenario:
    """Photos, marks and the truth that links them.

    Attributes:
        photos: in file order.
        mark_t_gps_ns: mark times, sorted.
        truth: for each photo, the index of its mark, or -1 when the mark was lost.
        clock_error_s: camera clock − UTC(+zone) error, seconds.
        extra_marks: indices of marks without a photo.
    """

    photos: tuple[SimPhoto, ...]
    mark_t_gps_ns: tuple[int, ...]
    truth: tuple[int, ...]
    clock_error_s: float
    extra_marks: tuple[int, ...]


def photo_scenario(
    n_photos: int,
    *,
    start_t_gps_ns: int = 2022 * gpstime.NS_PER_WEEK + 217_400 * gpstime.NS_PER_S,
    clock_error_s: float = -(2 * 3600 + 17 * 60 + 23.37),
    zone_s: int = 7200,
    write_zone: bool = False,
    subsec: bool = False,
    burst_fraction: float = 0.2,
    missing_fraction: float = 0.05,
    extra_fraction: float = 0.05,
    extra_min_sep_s: float = 0.8,
    seed: int = 0,
) -> PhotoScenario:
    """A flight's photos and marks.

    Shots come singly (1.3-2.5 s apart, any phase in the second) or as bursts of 4 at 4 frames
    per second. Without sub-second EXIF times a burst fills one EXIF second the way
    :data:`~groundstation.solve.clockoffset.BURST_SPREAD_S` assumes (first frame at 0.10 ± 0.02 s).
    The camera clock runs local time (``zone_s`` east of UTC) plus ``clock_error_s``. A fraction
    of marks is lost, and extra marks (loose contact) are added at least ``extra_min_sep_s`` from
    any shot.
    """
    rng = np.random.default_rng(seed)
    true_s: list[float] = []
    t = 10.0
    while len(true_s) < n_photos:
        if rng.random() < burst_fraction and len(true_s) + 4 <= n_photos:
            # The burst's place in the second is on the camera clock, not on GPS time.
            cam_phase = (0.10 + rng.uniform(-0.02, 0.02)) if not subsec else rng.random()
            first = np.floor(t) + 1.0 + (cam_phase - clock_error_s) % 1.0
            true_s.extend(first + 0.25 * k + rng.uniform(-0.01, 0.01) for k in range(4))
            t = true_s[-1] + rng.uniform(1.3, 2.5)
        else:
            true_s.append(t)
            t += rng.uniform(1.3, 2.5)
    true_ns = [start_t_gps_ns + round(s * 1e9) for s in true_s]
    photos = photos_at_times(
        true_ns, clock_error_s=clock_error_s, zone_s=zone_s, write_zone=write_zone, subsec=subsec
    )
    n_missing = int(round(missing_fraction * n_photos))
    lost = set(rng.choice(n_photos, size=n_missing, replace=False).tolist())
    kept = [(tn, k) for k, tn in enumerate(true_ns) if k not in lost]
    arr = np.array(true_s)
    extras: list[int] = []
    n_extra = int(round(extra_fraction * n_photos))
    while len(extras) < n_extra:
        cand = rng.uniform(arr[0], arr[-1])
        if np.min(np.abs(arr - cand)) >= extra_min_sep_s:
            extras.append(start_t_gps_ns + round(cand * 1e9))
    marks = sorted([(tn, k) for tn, k in kept] + [(tn, -1) for tn in extras])
    truth = [-1] * n_photos
    extra_idx = []
    for i, (_, k) in enumerate(marks):
        if k >= 0:
            truth[k] = i
        else:
            extra_idx.append(i)
    return PhotoScenario(
        photos, tuple(tn for tn, _ in marks), tuple(truth), clock_error_s, tuple(extra_idx)
    )


def photos_at_times(
    true_t_gps_ns: Sequence[int],
    *,
    clock_error_s: float = -(2 * 3600 + 17 * 60 + 23.37),
    zone_s: int = 7200,
    write_zone: bool = False,
    subsec: bool = False,
    drift_ppm: float = 0.0,
) -> tuple[SimPhoto, ...]:
    """One photo per true shutter time (e.g. a simulated flight's exposures), in that order.

    File names number the shots from ``IMG_0001.JPG``; the EXIF times are those of a camera
    clock running local time (``zone_s`` east of UTC) plus ``clock_error_s`` at the first shot,
    drifting by ``drift_ppm`` from there, in whole seconds unless ``subsec`` (10 ms digits).
    """
    sign = "+" if zone_s >= 0 else "-"
    zone = f"{sign}{abs(zone_s) // 3600:02d}:{abs(zone_s) % 3600 // 60:02d}"
    photos: list[SimPhoto] = []
    t0 = true_t_gps_ns[0] if true_t_gps_ns else 0
    for k, tn in enumerate(true_t_gps_ns):
        unix_ns = gpstime.gps_to_unix_ns(tn)
        cam_ns = unix_ns + round((zone_s + clock_error_s) * 1e9 + (tn - t0) * drift_ppm * 1e-6)
        sec, frac = divmod(cam_ns, gpstime.NS_PER_S)
        when = dt.datetime.fromtimestamp(sec, tz=dt.UTC).replace(tzinfo=None)
        photos.append(
            SimPhoto(
                f"IMG_{k + 1:04d}.JPG",
                when,
                f"{frac // 10_000_000:02d}" if subsec else None,
                zone if write_zone else None,
                tn,
            )
        )
    return tuple(photos)


def write_photo_set(
    scenario: PhotoScenario | Sequence[SimPhoto], directory: Path
) -> list[Path]:
    """Write every photo of a scenario (or a sequence of photos) as a real JPEG with EXIF;
    returns the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for ph in scenario.photos if isinstance(scenario, PhotoScenario) else scenario:
        p = directory / ph.name
        p.write_bytes(make_jpeg(ph.exif_datetime, subsec=ph.subsec, offset_time=ph.offset_time))
        paths.append(p)
    return paths
