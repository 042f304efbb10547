"""Lever arm between antenna and projection centre with ω φ κ (DOMAIN.md §7), and EO files.

Convention (Mikhail/Kraus, object → image): ``M = R_κ · R_φ · R_ω``; the lever arm ``L`` is in
the camera frame, from projection centre to antenna phase centre; ``camera = antenna − Mᵀ·L``
and ``L_i = M_i · (antenna_i − camera_i)``. Coordinates are those of the exterior orientation
(a projected CRS: easting, northing, height). Sans-I/O except :func:`read_eo`.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from groundstation.errors import InputError

FloatArray = npt.NDArray[np.float64]

OUTLIER_SIGMAS = 3.0
"""Images whose lever-arm estimate is further than this many robust σ from the median."""


def rotation_matrix(omega_deg: float, phi_deg: float, kappa_deg: float) -> FloatArray:
    """``M = R_κ · R_φ · R_ω`` (object → image) for angles in degrees."""
    m: FloatArray = rotation_matrices(np.array([[omega_deg, phi_deg, kappa_deg]]))[0]
    return m


def rotation_matrices(opk_deg: FloatArray) -> FloatArray:
    """``M`` for each row (ω, φ, κ) in degrees: shape (n, 3, 3)."""
    a = np.radians(np.asarray(opk_deg, dtype=np.float64).reshape(-1, 3))
    co, so = np.cos(a[:, 0]), np.sin(a[:, 0])
    cp, sp = np.cos(a[:, 1]), np.sin(a[:, 1])
    ck, sk = np.cos(a[:, 2]), np.sin(a[:, 2])
    n = a.shape[0]
    one, zero = np.ones(n), np.zeros(n)
    r_o = np.stack([one, zero, zero, zero, co, so, zero, -so, co], axis=1).reshape(n, 3, 3)
    r_p = np.stack([cp, zero, -sp, zero, one, zero, sp, zero, cp], axis=1).reshape(n, 3, 3)
    r_k = np.stack([ck, sk, zero, -sk, ck, zero, zero, zero, one], axis=1).reshape(n, 3, 3)
    return np.asarray(r_k @ r_p @ r_o, dtype=np.float64)


def lever_offsets(opk_deg: FloatArray, lever_m: Sequence[float]) -> FloatArray:
    """``Mᵀ·L`` per image: the antenna's offset from the projection centre in object axes."""
    m = rotation_matrices(opk_deg)
    return np.asarray(np.einsum("nji,j->ni", m, np.asarray(lever_m, float)), dtype=np.float64)


def apply_lever_arm(
    antenna_m: FloatArray, opk_deg: FloatArray, lever_m: Sequence[float]
) -> FloatArray:
    """Projection centres: ``camera = antenna − Mᵀ·L`` for each image (rows of (n, 3))."""
    ant = np.asarray(antenna_m, dtype=np.float64).reshape(-1, 3)
    return np.asarray(ant - lever_offsets(opk_deg, lever_m), dtype=np.float64)


def kappa_from_track_deg(east_m: FloatArray, north_m: FloatArray, offset_deg: float = 0.0) -> (
    FloatArray
):
    """κ for a nadir camera whose image x axis points along the direction of travel.

    With ω = φ = 0 the first row of ``M`` (the camera x axis in object axes) is (cos κ, sin κ),
    so κ is the track angle counter-clockwise from east. Positions are in order along the
    flight; each image uses the direction from its neighbours (central difference, one-sided at
    the ends). ``offset_deg`` turns the camera on its mount (e.g. 90 when y points forward).
    """
    e = np.asarray(east_m, dtype=np.float64)
    n = np.asarray(north_m, dtype=np.float64)
    if e.size < 2:
        return np.full(e.size, offset_deg)
    de = np.gradient(e)
    dn = np.gradient(n)
    k = np.degrees(np.arctan2(dn, de)) + offset_deg
    return np.asarray((k + 180.0) % 360.0 - 180.0, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class LeverArmEstimate:
    """The lever arm estimated from images oriented on ground control.

    Attributes:
        mean_m: mean of the inliers, camera frame.
        sigma_m: standard deviation of the inliers per axis.
        per_image_m: (n, 3) estimate from each image.
        residual_m: (n,) distance of each image's estimate from the mean.
        outlier: (n,) images left out of the mean (more than 3 robust σ from the median).
    """

    mean_m: FloatArray
    sigma_m: FloatArray
    per_image_m: FloatArray
    residual_m: FloatArray
    outlier: npt.NDArray[np.bool_]

    @property
    def inliers(self) -> int:
        return int(np.sum(~self.outlier))


def estimate_lever_arm(
    antenna_m: FloatArray, camera_m: FloatArray, opk_deg: FloatArray
) -> LeverArmEstimate:
    """``L_i = M_i · (antenna_i − camera_i)``, then mean and σ with outliers flagged.

    Raises:
        InputError: fewer than two images.
    """
    ant = np.asarray(antenna_m, dtype=np.float64).reshape(-1, 3)
    cam = np.asarray(camera_m, dtype=np.float64).reshape(-1, 3)
    if ant.shape[0] < 2:
        raise InputError("lever-arm estimation needs at least two oriented images")
    m = rotation_matrices(opk_deg)
    per = np.einsum("nij,nj->ni", m, ant - cam)
    med = np.median(per, axis=0)
    dev = np.linalg.norm(per - med, axis=1)
    mad = 1.4826 * float(np.median(dev))
    limit = max(OUTLIER_SIGMAS * mad, 1e-3)
    outlier = dev > limit
    inl = per[~outlier] if np.any(~outlier) else per
    mean = inl.mean(axis=0)
    sigma = inl.std(axis=0, ddof=1) if inl.shape[0] > 1 else np.zeros(3)
    return LeverArmEstimate(
        mean, sigma, per, np.linalg.norm(per - mean, axis=1), np.asarray(outlier, bool)
    )


# -- exterior orientation files -------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ExteriorOrientation:
    """One image's exterior orientation: projection centre and ω φ κ (degrees)."""

    name: str
    x_m: float
    y_m: float
    z_m: float
    omega_deg: float
    phi_deg: float
    kappa_deg: float


def parse_eo(text: str, source: str = "EO") -> list[ExteriorOrientation]:
    """Exterior orientations from CSV/TXT: ``name, X, Y, Z, omega, phi, kappa`` per line.

    Separators: comma, semicolon, tab or spaces. Lines starting with ``#`` and a header line
    (whose coordinates are not numbers) are skipped.
    """
    out: list[ExteriorOrientation] = []
    for lineno, line in enumerate(io.StringIO(text), start=1):
        s = line.strip()
        if not s or s.startswith(("#", "%", "//")):
            continue
        delim = next((d for d in (",", ";", "\t") if d in s), None)
        fields = next(csv.reader([s], delimiter=delim)) if delim else s.split()
        fields = [f.strip() for f in fields if f.strip() != ""]
        if len(fields) < 7:
            raise InputError(f"{source}:{lineno}: expected name, X, Y, Z, omega, phi, kappa")
        try:
            vals = [float(v) for v in fields[1:7]]
        except ValueError as err:
            if not out:
                continue  # header line
            raise InputError(f"{source}:{lineno}: not a number in {s!r}") from err
        if not all(math.isfinite(v) for v in vals):
            raise InputError(f"{source}:{lineno}: non-finite value in {s!r}")
        out.append(ExteriorOrientation(fields[0], *vals))
    if not out:
        raise InputError(f"{source}: no exterior orientations")
    return out


def read_eo(path: str | Path) -> list[ExteriorOrientation]:
    """Read an exterior-orientation file (see :func:`parse_eo`)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig", errors="replace")
    except OSError as err:
        raise InputError(f"{p}: cannot read: {err}") from err
    return parse_eo(text, p.name)
