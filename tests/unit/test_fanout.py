"""Fanout overflow policies: drop-oldest sinks count drops, the recorder never drops."""

from __future__ import annotations

import asyncio

import pytest

from groundstation.live.fanout import Fanout, InboxClosed, Overflow
from groundstation.live.sources import backoff_delay_s
from groundstation.records import Event


def test_drop_oldest_counts_and_reports() -> None:
    async def main() -> None:
        fan = Fanout(clock=lambda: 123)
        events: list[Event] = []
        mon = fan.add_inbox("monitor", 3, Overflow.DROP_OLDEST)
        fan.add_inbox("spy", 1000, Overflow.NEVER_DROP)
        spy = fan.inboxes[1]
        for i in range(10):
            fan.publish(i)
        assert len(mon) == 3  # the bound holds
        got = [await mon.get() for _ in range(len(mon))]
        assert got == [7, 8, 9]  # the newest survive (the drop event itself was dropped)
        assert mon.dropped == 8
        while len(spy):
            item = await spy.get()
            if isinstance(item, Event):
                events.append(item)
        assert [e.kind for e in events] == ["fanout.dropped"]  # rate-limited: one event
        assert events[0].data["sink"] == "monitor"

    asyncio.run(main())


def test_never_drop_keeps_everything_and_raises_behind_then_caught_up() -> None:
    async def main() -> None:
        fan = Fanout(clock=lambda: 1)
        rec = fan.add_inbox("recorder", 4, Overflow.NEVER_DROP)
        for i in range(20):
            fan.publish(i)  # never blocks, even far beyond the bound
        assert rec.dropped == 0 and rec.behind and rec.over_limit > 0
        fan.close()
        items = []
        while True:
            try:
                items.append(await rec.get())
            except InboxClosed:
                break
        ints = [i for i in items if isinstance(i, int)]
        assert ints == list(range(20))
        kinds = [i.kind for i in items if isinstance(i, Event)]
        assert kinds[0] == "recorder.behind"
        assert not rec.behind

    asyncio.run(main())


def test_get_times_out_with_none_and_close_ends() -> None:
    async def main() -> None:
        fan = Fanout()
        box = fan.add_inbox("x", 2, Overflow.DROP_OLDEST)
        assert await box.get(timeout_s=0.01) is None
        fan.publish("a")
        fan.close(["x"])
        assert await box.get() == "a"
        with pytest.raises(InboxClosed):
            await box.get()
        fan.publish("late")  # closed inboxes ignore items
        assert len(box) == 0

    asyncio.run(main())


def test_backoff_is_jittered_and_capped() -> None:
    assert backoff_delay_s(0, 0.1, 1.0, lambda: 0.0) == pytest.approx(0.05)
    assert backoff_delay_s(0, 0.1, 1.0, lambda: 1.0) == pytest.approx(0.1)
    assert backoff_delay_s(10, 0.1, 1.0, lambda: 0.999) <= 1.0
    assert backoff_delay_s(10, 0.1, 1.0, lambda: 0.0) == pytest.approx(0.5)
