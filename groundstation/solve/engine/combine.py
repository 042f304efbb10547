"""Forward and backward solutions combined into one, with a full-covariance check of each fix.

RTKLIB's "combined" solution type runs the filter forward and backward over the data and merges
the two per epoch (``combres`` in demo5's ``postpos.c``): where one run has the better quality
its epoch is taken whole; where both have the same quality the positions are averaged with
their covariances (the smoother ``x = xf + Qf (Qf + Qb)^-1 (xb - xf)``). demo5 keeps such an
epoch "fixed" only when the two fixed positions agree to 4 sigma on each ECEF axis separately,
with the variances of that axis alone.

That test is loose: 4 sigma on each axis separately is a false-alarm rate of about 2e-4 for
a correct pair, and it ignores the correlations between the axes. This module makes the same
merge with the test done on the 3-D difference ``d = xf - xb`` against the full covariance
``Qf + Qb`` (``d' (Qf + Qb)^-1 d``, chi-square with 3 degrees of freedom) at the conventional 1 %
level; demo5's per-axis test stays in force as well. Everything else is demo5's ``combres``
(positions within 0.5 mm of demo5's own combined output at p99 on the real flight below; the
``.pos`` carries the covariances to 0.1 mm).

Why this is right for every flight: two fixes of the same epoch that are inconsistent at 1 %
cannot both be right, and the combination has no way to tell which one is wrong; averaging them
gives a position that is neither and calls it fixed. Measured (``benchmarks/RESULTS.md``, issue
13 session 4): on the real 2018-10-09 M8P flight the epochs this test rejects fit the GPS L1
carrier phase 3-4 times worse than the rest (median RMS of the fractional double-difference
residuals 0.13-0.19 cycles against 0.04) for both the forward and the backward position, so they
are not centimetre positions whichever run is taken; on the simulated LEA-6T flights (severity
1, seeds 1-3, and severity 2 seed 2) one of 17 549 epochs where both fixes are within 3 cm of the
truth fails it.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

CHI2_3DOF_1PCT = 11.345
"""Chi-square quantile, 3 degrees of freedom, 99 %: the consistency limit of two fixes."""

DEMO5_SIGMAS = 4.0
"""demo5's own per-axis limit (``valcomb``: ``d^2 <= 16 var`` on each ECEF axis)."""

DTTOL_S = 0.025
"""Two solutions within this time are the same epoch (RTKLIB's ``DTTOL``)."""

# RTKLIB's ``pri[]`` in combres: the lower wins (fix and PPP 1, float 2, ..., none 7).
_PRIORITY = {0: 7, 1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 1, 7: 6}
Q_FIX, Q_FLOAT = 1, 2
_EPOCH = dt.datetime(1980, 1, 6)


@dataclass(frozen=True, slots=True)
class Solutions:
    """The solution lines of one ``.pos`` (xyz format, no velocity), sorted by time."""

    t_s: FloatArray
    lines: list[str]
    xyz: FloatArray
    q: npt.NDArray[np.int64]
    cov: FloatArray  # (n, 3, 3) ECEF


@dataclass(slots=True)
class CombineStats:
    """What the combination did.

    Attributes:
        epochs: solutions written.
        both_fixed: epochs fixed in both runs.
        demo5_rejected: of those, the ones demo5's per-axis test makes float.
        chi2_rejected: the further ones the full-covariance test makes float.
        one_run_only: epochs only one run has.
    """

    epochs: int = 0
    both_fixed: int = 0
    demo5_rejected: int = 0
    chi2_rejected: int = 0
    one_run_only: int = 0
    rule: str = field(default="")

    def as_dict(self) -> dict[str, object]:
        return {
            "epochs": self.epochs, "both_fixed": self.both_fixed,
            "demo5_rejected": self.demo5_rejected, "chi2_rejected": self.chi2_rejected,
            "one_run_only": self.one_run_only, "rule": self.rule,
        }


RULE = (
    "demo5's combres (better quality taken whole, equal quality smoothed); a fix of both runs "
    f"stays fixed only if d'(Qf+Qb)^-1 d <= {CHI2_3DOF_1PCT} (chi-square 3 dof, 1 %) and "
    f"each axis within {DEMO5_SIGMAS:g} sigma (demo5)"
)


def _signed_square(v: FloatArray) -> FloatArray:
    # RTKLIB writes an off-diagonal covariance q as sign(q) sqrt(|q|).
    return np.sign(v) * v * v


def parse_solutions(text: str) -> tuple[list[str], Solutions]:
    """Header lines and sorted solution rows of an RTKLIB xyz ``.pos`` text.

    Raises:
        ValueError: a solution line that is not ``date time x y z Q ns sdx sdy sdz sdxy sdyz
            sdzx age ratio`` (another output format: the caller falls back to the engine's own
            combination).
    """
    head: list[str] = []
    lines: list[str] = []
    t: list[float] = []
    vals: list[list[float]] = []
    days: dict[str, dt.datetime] = {}
    for ln in text.splitlines():
        if ln.startswith("%") or not ln.strip():
            if not lines:
                head.append(ln)
            continue
        f = ln.split()
        if len(f) != 15 or "/" not in f[0]:
            raise ValueError(f"not an xyz solution line without velocity: {ln[:60]!r}")
        day = days.get(f[0])
        if day is None:  # one parse per date, not per line (an hour at 5 Hz is 18 000)
            day = days[f[0]] = dt.datetime.strptime(f[0], "%Y/%m/%d")
        hh, mm, ss = f[1].split(":")
        t.append((day - _EPOCH).total_seconds() + int(hh) * 3600 + int(mm) * 60 + float(ss))
        vals.append([float(x) for x in f[2:13]])
        lines.append(ln)
    order = np.argsort(np.asarray(t), kind="stable")
    a = np.asarray(vals, dtype=np.float64).reshape(-1, 11)[order]
    sd = a[:, 5:11]
    cov = np.empty((a.shape[0], 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = sd[:, 0] ** 2, sd[:, 1] ** 2, sd[:, 2] ** 2
    cov[:, 0, 1] = cov[:, 1, 0] = _signed_square(sd[:, 3])
    cov[:, 1, 2] = cov[:, 2, 1] = _signed_square(sd[:, 4])
    cov[:, 2, 0] = cov[:, 0, 2] = _signed_square(sd[:, 5])
    rows = Solutions(np.asarray(t)[order], [lines[i] for i in order], a[:, 0:3],
                 a[:, 3].astype(np.int64), cov)
    return head, rows


def _sq(v: float) -> float:
    return float(np.sign(v) * np.sqrt(abs(v)))


def _line(template: str, x: FloatArray, q: int, cov: FloatArray) -> str:
    """``template``'s time, satellites, age and ratio with a new position, quality, covariance
    (RTKLIB's ``outsol`` xyz layout: ``%14.4f`` x3, ``%3d`` x2, ``%8.4f`` x6, ``%6.2f %6.1f``)."""
    f = template.split()
    return (
        f"{f[0]} {f[1]} {x[0]:14.4f} {x[1]:14.4f} {x[2]:14.4f} {q:3d} {int(f[6]):3d} "
        f"{np.sqrt(cov[0, 0]):8.4f} {np.sqrt(cov[1, 1]):8.4f} {np.sqrt(cov[2, 2]):8.4f} "
        f"{_sq(cov[0, 1]):8.4f} {_sq(cov[1, 2]):8.4f} {_sq(cov[2, 0]):8.4f} "
        f"{float(f[13]):6.2f} {float(f[14]):6.1f}"
    )


def consistent(d: FloatArray, cov: FloatArray) -> tuple[bool, bool]:
    """(demo5's per-axis test passes, the full-covariance test passes) for the difference ``d``
    of two fixed positions whose covariances sum to ``cov``."""
    var = np.diag(cov)
    demo5 = bool(np.all(d * d <= DEMO5_SIGMAS**2 * var))
    try:
        chi2 = float(d @ np.linalg.solve(cov, d))
    except np.linalg.LinAlgError:
        return demo5, demo5
    return demo5, chi2 <= CHI2_3DOF_1PCT


def combine_text(forward: str, backward: str) -> tuple[str, CombineStats]:
    """The combined ``.pos`` text of a forward and a backward solution (same options otherwise).

    The header is the forward run's with its "solution" line saying combined.

    Raises:
        ValueError: a solution line not in RTKLIB's xyz layout without velocity.
    """
    head, f = parse_solutions(forward)
    _, b = parse_solutions(backward)
    stats = CombineStats(rule=RULE)
    out: list[str] = [
        "% solution  : Combined (forward and backward combined by groundstation)"
        if ln.startswith("% solution") else ln for ln in head
    ]
    i = j = 0
    while i < f.t_s.size or j < b.t_s.size:
        if j >= b.t_s.size or (i < f.t_s.size and f.t_s[i] < b.t_s[j] - DTTOL_S):
            out.append(f.lines[i])
            i += 1
            stats.one_run_only += 1
            continue
        if i >= f.t_s.size or b.t_s[j] < f.t_s[i] - DTTOL_S:
            out.append(b.lines[j])
            j += 1
            stats.one_run_only += 1
            continue
        qf, qb = int(f.q[i]), int(b.q[j])
        pf, pb = _PRIORITY.get(qf, 7), _PRIORITY.get(qb, 7)
        if pf != pb:
            out.append(f.lines[i] if pf < pb else b.lines[j])
        else:
            q = qf
            s = f.cov[i] + b.cov[j]
            if q == Q_FIX:
                stats.both_fixed += 1
                demo5_ok, chi2_ok = consistent(f.xyz[i] - b.xyz[j], s)
                if not demo5_ok:
                    stats.demo5_rejected += 1
                    q = Q_FLOAT
                elif not chi2_ok:
                    stats.chi2_rejected += 1
                    q = Q_FLOAT
            try:
                gain = f.cov[i] @ np.linalg.inv(s)
            except np.linalg.LinAlgError:  # demo5 skips an epoch it cannot smooth
                i += 1
                j += 1
                continue
            x = f.xyz[i] + gain @ (b.xyz[j] - f.xyz[i])
            cov = f.cov[i] - gain @ f.cov[i]
            out.append(_line(f.lines[i], x, q, cov))
        i += 1
        j += 1
    stats.epochs = len(out) - len(head)
    return "\n".join(out) + "\n", stats


def combine_files(forward: Path, backward: Path, out: Path) -> CombineStats:
    """:func:`combine_text` of two ``.pos`` files, written to ``out``."""
    text, stats = combine_text(
        forward.read_text(encoding="ascii", errors="replace"),
        backward.read_text(encoding="ascii", errors="replace"),
    )
    out.write_text(text, encoding="ascii", errors="replace")
    return stats
