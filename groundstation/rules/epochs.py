"""Epochs: the logging interval learned from epoch times, gaps (dropouts) and where a time lies.

One rule for the monitor (from its recent epoch spacings), inspect, the RINEX marks table and
the solver: the interval is the most common spacing to the millisecond; a spacing longer than
:data:`DROPOUT_FACTOR` intervals is a dropout of ``round(spacing / interval) - 1`` epochs (at
least one).
"""

from __future__ import annotations

import bisect
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

DROPOUT_FACTOR = 1.5
"""A gap between epochs longer than this many nominal intervals is a dropout."""


def interval_from_spacings(spacings_ns: Iterable[int]) -> int | None:
    """The most common positive spacing, to the ms (RXM-RAWX epochs jitter by ns); the
    shorter one on a tie; None without any."""
    counts = Counter(round(d / 1e6) * 1_000_000 for d in spacings_ns)
    counts.pop(0, None)
    for k in [k for k in counts if k < 0]:
        del counts[k]
    return max(counts, key=lambda k: (counts[k], -k)) if counts else None


VECTOR_MIN = 2000
"""From this many epochs on, :func:`nominal_interval_ns` counts with numpy (a 10-hour 5 Hz
flight has 180 000 epochs: 0.6 s in a Python loop)."""


def nominal_interval_ns(epoch_t_gps_ns: Sequence[int]) -> int | None:
    """The logging interval of sorted epoch times (:func:`interval_from_spacings`), if any."""
    if len(epoch_t_gps_ns) >= VECTOR_MIN:
        import numpy as np  # the same rule on arrays: rint rounds half to even like round()

        t = np.asarray(epoch_t_gps_ns, dtype=np.int64)
        ms = np.rint(np.diff(t) / 1e6).astype(np.int64)
        values, counts = np.unique(ms[ms > 0], return_counts=True)
        if not values.size:
            return None
        return int(values[counts == counts.max()].min()) * 1_000_000  # the shorter on a tie
    return interval_from_spacings(
        b - a for a, b in zip(epoch_t_gps_ns, epoch_t_gps_ns[1:], strict=False)
    )


def is_dropout(spacing_ns: int, interval_ns: int) -> bool:
    """Whether two consecutive received epochs this far apart have epochs missing between."""
    return 2 * spacing_ns > 3 * interval_ns  # DROPOUT_FACTOR, in integers


def missing_epochs(spacing_ns: int, interval_ns: int) -> int:
    """How many epochs a dropout of this spacing lost (at least one)."""
    return max(1, round(spacing_ns / interval_ns) - 1)


@dataclass(frozen=True, slots=True)
class Gap:
    """Missing epochs between two received ones."""

    after_t_gps_ns: int
    before_t_gps_ns: int
    missing_epochs: int

    @property
    def duration_s(self) -> float:
        """Seconds between the received epochs around the gap."""
        return (self.before_t_gps_ns - self.after_t_gps_ns) / 1e9


def find_gaps(epoch_t_gps_ns: Sequence[int], interval_ns: int | None) -> list[Gap]:
    """Every dropout in sorted epoch times."""
    if not interval_ns:
        return []
    return [
        Gap(a, b, missing_epochs(b - a, interval_ns))
        for a, b in zip(epoch_t_gps_ns, epoch_t_gps_ns[1:], strict=False)
        if is_dropout(b - a, interval_ns)
    ]


@dataclass(frozen=True, slots=True)
class GapInfo:
    """Where a time lies in the epoch sequence."""

    in_dropout: bool
    outside: bool
    gap_ns: int | None


def locate(t_gps_ns: int, epochs: Sequence[int], interval_ns: int | None) -> GapInfo:
    """Whether ``t_gps_ns`` falls inside a dropout, or outside the epochs altogether."""
    if not epochs:
        return GapInfo(False, True, None)
    i = bisect.bisect_right(epochs, t_gps_ns)
    if i == 0 or i == len(epochs):
        if i and epochs[-1] == t_gps_ns:
            return GapInfo(False, False, 0)
        return GapInfo(False, True, None)
    gap = epochs[i] - epochs[i - 1]
    dropout = interval_ns is not None and is_dropout(gap, interval_ns)
    return GapInfo(dropout, False, gap)
