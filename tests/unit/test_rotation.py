"""The rotation rule solved for a writer's per-message check (``RotationPolicy.limits``) says
exactly what ``RotationPolicy.due`` says, for every limit alone and together."""

from __future__ import annotations

import itertools

from groundstation.storage.rotation import RotationPolicy


def test_limits_agree_with_due() -> None:
    policies = [
        RotationPolicy(size, duration, chunk, max_chunks)
        for size, duration, chunk, max_chunks in itertools.product(
            (0, 5000), (0, 1000), (512, 4096), (0, 1, 3, 43_200))
    ]
    checked = due_seen = 0
    for policy in policies:
        for size, closed, started in itertools.product((0, 4999, 5000, 9000), (0, 1, 2, 3, 5),
                                                       (0, 10_000)):
            due_now, data_limit, time_limit = policy.limits(
                size_bytes=size, closed_chunks=closed, started_ns=started)
            for data, now in itertools.product((0, 511, 512, 1023, 1024, 2048, 12_288, 10**6),
                                               (started, started + 999, started + 1000,
                                                started + 10**12)):
                due = policy.due(size_bytes=size, data_bytes=data, closed_chunks=closed,
                                 started_ns=started, now_ns=now)
                assert due == (due_now or data >= data_limit or now >= time_limit), (
                    policy, size, closed, started, data, now)
                checked += 1
                due_seen += due
    assert 0 < due_seen < checked  # both answers occur
