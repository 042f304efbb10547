"""Limits that must hold whatever a peer, the clock or the user does.

- The recording server's bookkeeping of what it sent costs ``O(log n)`` comparisons a query,
  not a sort of every range so far (20 000 one-byte queries took 22 s of CPU): counted here
  with integers that count their own comparisons, no timing.
- A backward step of the wall clock postpones neither the next part (rotation by duration)
  nor the next flush.
- A configuration bound is printed as a person writes it (``1048576 (1 MiB)``, not
  ``1.04858e+06``), for every numeric key of every command.
"""

from __future__ import annotations

import itertools
import math
import random
import re
from pathlib import Path
from typing import Any

import pytest

from groundstation.config import (
    DAEMON_SCHEMA,
    DASHBOARD_SCHEMA,
    ROUTER_SCHEMA,
    SOLVER_SCHEMA,
    WATCH_SCHEMA,
    convert,
)
from groundstation.errors import ConfigError
from groundstation.live.serve import SentRanges
from groundstation.storage.session import SessionRecorder

# -- the recording server's ranges --------------------------------------------------------------


class Counted(int):
    """An int that counts the comparisons made with it (bisect, sort, min and max use them)."""

    compares = 0

    def _count(self) -> None:
        Counted.compares += 1

    def __lt__(self, other: Any) -> bool:
        self._count()
        return int(self) < int(other)

    def __le__(self, other: Any) -> bool:
        self._count()
        return int(self) <= int(other)

    def __gt__(self, other: Any) -> bool:
        self._count()
        return int(self) > int(other)

    def __ge__(self, other: Any) -> bool:
        self._count()
        return int(self) >= int(other)


@pytest.mark.parametrize("order", ["forward", "reverse", "shuffled"])
def test_sent_ranges_cost_log_n_comparisons_a_query(order: str) -> None:
    n = 4000
    offsets = [2 * k for k in range(n)]  # one byte at every other offset: nothing merges
    if order == "reverse":
        offsets.reverse()
    elif order == "shuffled":
        random.Random(7).shuffle(offsets)
    sent = SentRanges()
    Counted.compares = 0
    for off in offsets:
        sent.add(Counted(off), Counted(off + 1))
    assert len(sent) == n
    # two binary searches a query: 2 * log2(n) each, and a few to merge
    bound = n * (2 * math.ceil(math.log2(n)) + 4)
    assert Counted.compares <= bound, (Counted.compares, bound)  # before: ~n * n / 2


def test_sent_ranges_merge_like_a_set_of_bytes() -> None:
    rng = random.Random(3)
    for _ in range(200):
        size = rng.randint(1, 300)
        sent, covered = SentRanges(), set()
        for _ in range(rng.randint(1, 40)):
            a = rng.randrange(size)
            b = min(size, a + rng.randint(1, 40))
            sent.add(a, b)
            covered |= set(range(a, b))
            # disjoint, sorted, never touching (touching ranges merge)
            assert all(e < s for e, s in zip(sent.ends, sent.starts[1:], strict=False))
            assert set(itertools.chain.from_iterable(
                range(s, e) for s, e in zip(sent.starts, sent.ends, strict=True))) == covered
        assert sent.covers(size) == (covered == set(range(size)))


# -- the recorder's clock stepping back -------------------------------------------------------

T0_NS = 1_700_000_000_000_000_000
S = 1_000_000_000


class SteppingClock:
    def __init__(self) -> None:
        self.now = T0_NS

    def __call__(self) -> int:
        return self.now


def test_a_clock_stepped_back_postpones_neither_rotation_nor_flush(tmp_path: Path) -> None:
    clock = SteppingClock()
    rec = SessionRecorder(tmp_path, "st1", rotate_duration_ns=10 * S, clock=clock,
                          flush_interval_ns=S // 2)
    rec.open()
    rec.write_raw(b"a" * 100, clock.now)
    clock.now += 4 * S
    rec.write_raw(b"b" * 100, clock.now)
    assert rec.maybe_flush()
    clock.now -= 3600 * S  # NTP (or an operator) steps the clock back an hour
    rec.write_raw(b"c" * 100, clock.now)
    clock.now += S  # 5 s of the file gone by
    assert rec.maybe_flush()  # before: not for an hour
    assert rec.file_count == 1
    clock.now += 5 * S  # 10 s gone by: the next part
    rec.write_raw(b"d" * 100, clock.now)
    assert rec.file_count == 2  # before: an hour and 10 s after the start
    assert rec.clock_steps_back == 1
    rec.close()


# -- configuration bounds ----------------------------------------------------------------------

SCHEMAS = {"run": DAEMON_SCHEMA, "solver": SOLVER_SCHEMA, "watch": WATCH_SCHEMA,
           "dashboard": DASHBOARD_SCHEMA, "router": ROUTER_SCHEMA}
NUMERIC = [(f"{scope}:{section}.{name}", spec)
           for scope, schema in SCHEMAS.items() for section, keys in schema.items()
           for name, spec in keys.items()
           if spec.kind in ("int", "float") and (spec.lo is not None or spec.hi is not None)]


@pytest.mark.parametrize(("name", "spec"), NUMERIC, ids=[n for n, _ in NUMERIC])
def test_configuration_bounds_read_as_written(name: str, spec: Any) -> None:
    key = name.split(":", 1)[1]
    beyond = (spec.hi * 2 + 1) if spec.hi is not None else (spec.lo - 1)
    value = int(beyond) if spec.kind == "int" else float(beyond)
    with pytest.raises(ConfigError) as info:
        convert(spec, key, value)
    text = str(info.value)
    rule = text.split("must be ", 1)[1].split(", got", 1)[0]
    assert not re.search(r"\de[+-]?\d", rule), text  # no 1.04858e+06
    for bound in (spec.lo, spec.hi):
        if bound is not None:  # every bound printed reads back exactly
            assert any(float(tok) == bound for tok in re.findall(r"-?\d+(?:\.\d+)?", rule)), text


def test_a_byte_bound_says_its_unit() -> None:
    spec = DAEMON_SCHEMA["source"]["read_size_bytes"]
    with pytest.raises(ConfigError, match=r"<= 1048576 \(1 MiB\), got 2000000"):
        convert(spec, "source.read_size_bytes", 2_000_000)
