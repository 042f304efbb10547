"""The graded trajectory on disk: an RTKLIB ``.pos`` other tools read, and its grades beside it.

``integrity.pos`` is RTKLIB's xyz solution layout (GPST, covariance columns as RTKLIB writes
them, ``sign(c) sqrt(|c|)`` off the diagonal) with Q 1 only where the grade is fixed; the
grade and the check that decided each epoch are in ``integrity.csv``.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from groundstation.solve.integrity.assess import IntegrityResult
from groundstation.solve.integrity.grade import CHECK_NAMES, GRADE_NAMES

_EPOCH = dt.datetime(1980, 1, 6)


def _time(t_gps_ns: int) -> str:
    s, ns = divmod(int(t_gps_ns), 10**9)
    d = _EPOCH + dt.timedelta(seconds=s)
    return f"{d:%Y/%m/%d %H:%M:%S}.{ns // 1000:06d}"


def _sq(v: float) -> float:
    return float(np.sign(v) * np.sqrt(abs(v)))


def write_pos(path: Path, r: IntegrityResult) -> None:
    """``path`` (``.pos``) and ``path`` with ``.csv`` (grades) for the result ``r``."""
    lines = [
        "% program   : groundstation integrity stage",
        "% solution  : graded (Q=1 fixed and checked; Q=2 float or a fix that failed its check)",
        ("%  GPST                      x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns   sdx(m)"
         "   sdy(m)   sdz(m)  sdxy(m)  sdyz(m)  sdzx(m) age(s)  ratio"),
    ]
    for t, x, c, q in zip(r.t_gps_ns.tolist(), r.ecef_m.tolist(), r.cov, r.quality.tolist(),
                          strict=True):
        lines.append(
            f"{_time(t)} {x[0]:14.4f} {x[1]:14.4f} {x[2]:14.4f} {q:3d} {0:3d} "
            f"{np.sqrt(max(c[0, 0], 0)):8.4f} {np.sqrt(max(c[1, 1], 0)):8.4f} "
            f"{np.sqrt(max(c[2, 2], 0)):8.4f} {_sq(c[0, 1]):8.4f} {_sq(c[1, 2]):8.4f} "
            f"{_sq(c[2, 0]):8.4f} {0.0:6.2f} {0.0:6.1f}"
        )
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    rows = ["gps_time,grade,check"]
    rows += [f"{_time(t)},{GRADE_NAMES[int(g)]},{CHECK_NAMES[int(k)]}"
             for t, g, k in zip(r.t_gps_ns.tolist(), r.grade.tolist(), r.check.tolist(),
                                strict=True)]
    path.with_suffix(".csv").write_text("\n".join(rows) + "\n", encoding="ascii")
