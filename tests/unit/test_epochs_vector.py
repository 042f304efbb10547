"""The interval rule gives the same answer on the numpy path (long recordings) as in Python."""

from __future__ import annotations

import random

from groundstation.rules import epochs


def test_vector_interval_equals_the_loop_rule() -> None:
    for seed in range(60):
        rng = random.Random(seed)
        t = [rng.randrange(0, 10**12)]
        for _ in range(epochs.VECTOR_MIN + rng.randrange(500)):
            # jitter, half-millisecond ties (rounded half to even), dropouts, duplicates
            t.append(t[-1] + rng.choice([200_000_000, 199_500_000, 200_500_000, 1_000_000_000,
                                         0, rng.randrange(0, 3 * 10**9)]))
        loop = epochs.interval_from_spacings(b - a for a, b in zip(t, t[1:], strict=False))
        assert epochs.nominal_interval_ns(t) == loop
    assert epochs.nominal_interval_ns([7] * epochs.VECTOR_MIN) is None
