"""The antenna trajectory every position source yields: :class:`Trajectory`, RTKLIB's quality
codes and their names, and the grade an unchecked quality stands for.

Imported by the sources (:mod:`.positions`), the ``.pos`` reader (:mod:`.posfile`), the engines'
dynamics pass and everything after them; it imports none of them.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation.errors import InputError
from groundstation.solve.arrays import read_npz, write_npz
from groundstation.solve.integrity import grade as gr

Q_FIX, Q_FLOAT, Q_SBAS, Q_DGPS, Q_SINGLE, Q_PPP = 1, 2, 3, 4, 5, 6
QUALITY_NAMES = {1: "fix", 2: "float", 3: "sbas", 4: "dgps", 5: "single", 6: "ppp", 0: "none"}

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Trajectory:
    """Antenna positions at the epochs of a solution, sorted by time.

    Attributes:
        t_gps_ns: epoch times, ns since the GPS epoch (int64, strictly increasing).
        ecef_m: (n, 3) WGS84 ECEF positions.
        quality: RTKLIB Q per epoch (1 fix, 2 float, 3 sbas, 4 dgps, 5 single, 6 ppp).
        sd_enu_m: (n, 3) standard deviations east, north, up (NaN when unknown).
        ns: satellites used (0 when unknown).
        ratio: ambiguity validation ratio (NaN when unknown).
        source: where it came from (file name or engine).
        metre_level: the receiver's own fix, not a carrier-phase solution.
        grade: grade code per epoch from the integrity stage
            (:data:`groundstation.solve.integrity.grade.GRADE_NAMES`); None: derived from the
            quality (:meth:`grades`).
        check: the check that decided each epoch's grade (``CHECK_NAMES`` code); None: none.
    """

    t_gps_ns: IntArray
    ecef_m: FloatArray
    quality: IntArray
    sd_enu_m: FloatArray
    ns: IntArray
    ratio: FloatArray
    source: str
    metre_level: bool = False
    notes: tuple[str, ...] = ()
    grade: IntArray | None = None
    check: IntArray | None = None

    def __len__(self) -> int:
        return int(self.t_gps_ns.size)

    def grades(self) -> IntArray:
        """Grade code per epoch: the integrity stage's, or from the quality where it did not
        run (a fix is then fixed-unchecked: nothing checked it)."""
        if self.grade is not None:
            return self.grade
        return grades_of_quality(self.quality)

    def checks(self) -> IntArray:
        """Check code per epoch (:data:`~groundstation.solve.integrity.grade.CHECK_NAMES`)."""
        if self.check is not None:
            return self.check
        return np.where(self.quality == Q_FIX, gr.C_UNCHECKED, 0).astype(np.int64)

    @property
    def fixed_fraction(self) -> float:
        return float(np.mean(self.quality == Q_FIX)) if len(self) else 0.0


def grades_of_quality(quality: IntArray) -> IntArray:
    """Grade codes of RTKLIB qualities nothing has checked."""
    q = np.asarray(quality)
    out = np.full(q.shape, gr.NONE, dtype=np.int64)
    out[q == Q_FIX] = gr.FIXED_UNCHECKED
    out[q == Q_FLOAT] = gr.FLOAT
    out[(q >= Q_SBAS) & (q <= Q_PPP)] = gr.SINGLE
    return out


def make_trajectory(
    t_gps_ns: Sequence[int] | IntArray,
    ecef_m: Sequence[Sequence[float]] | FloatArray,
    quality: Sequence[int] | IntArray,
    *,
    sd_enu_m: FloatArray | None = None,
    ns: IntArray | None = None,
    ratio: FloatArray | None = None,
    source: str = "",
    metre_level: bool = False,
    notes: Iterable[str] = (),
    grade: IntArray | None = None,
    check: IntArray | None = None,
) -> Trajectory:
    """A :class:`Trajectory` from columns, sorted by time, duplicate epochs dropped (first kept)."""
    t = np.asarray(t_gps_ns, dtype=np.int64)
    n = t.size
    xyz = np.asarray(ecef_m, dtype=np.float64).reshape(n, 3)
    q = np.asarray(quality, dtype=np.int64).reshape(n)
    sd = np.full((n, 3), np.nan) if sd_enu_m is None else np.asarray(sd_enu_m, float).reshape(n, 3)
    nsv = np.zeros(n, np.int64) if ns is None else np.asarray(ns, np.int64).reshape(n)
    rat = np.full(n, np.nan) if ratio is None else np.asarray(ratio, float).reshape(n)
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.ones(n, bool)
    keep[1:] = np.diff(t) > 0
    idx = order[keep]
    return Trajectory(
        t[keep], xyz[idx], q[idx], sd[idx], nsv[idx], rat[idx], source, metre_level, tuple(notes),
        None if grade is None else np.asarray(grade, np.int64).reshape(n)[idx],
        None if check is None else np.asarray(check, np.int64).reshape(n)[idx],
    )




def save_npz(traj: Trajectory, path: Path) -> None:
    """Write ``traj`` as a NumPy ``.npz`` (plain arrays, no pickled objects: :func:`load_npz`)."""
    arrays: dict[str, Any] = {
        "t_gps_ns": traj.t_gps_ns, "ecef_m": traj.ecef_m, "quality": traj.quality,
        "sd_enu_m": traj.sd_enu_m, "ns": traj.ns, "ratio": traj.ratio,
        "source": np.array(traj.source), "metre_level": np.array(traj.metre_level),
        "notes": np.array(traj.notes, dtype=np.str_),
    }
    if traj.grade is not None:
        arrays["grade"] = traj.grade
    if traj.check is not None:
        arrays["check"] = traj.check
    write_npz(path, arrays)


def load_npz(path: Path) -> Trajectory:
    """A trajectory :func:`save_npz` wrote.

    Raises:
        InputError: unreadable, or not a trajectory (a key missing or of the wrong shape).
    """
    a = read_npz(path, "a trajectory")
    try:
        n = int(a["t_gps_ns"].size)
        return make_trajectory(
            a["t_gps_ns"], a["ecef_m"], a["quality"], sd_enu_m=a["sd_enu_m"], ns=a["ns"],
            ratio=a["ratio"], source=str(a["source"]), metre_level=bool(a["metre_level"]),
            notes=[str(v) for v in a["notes"].reshape(-1)],
            grade=a["grade"].reshape(n) if "grade" in a else None,
            check=a["check"].reshape(n) if "check" in a else None)
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"{path}: not a trajectory this program wrote ({err!r})") from err
