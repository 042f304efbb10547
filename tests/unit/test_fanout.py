"""Fanout: typed routing (a sink gets only what it accepts, never its own output) and the
overflow policies (drop-oldest sinks count drops, the recorder never drops)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
from streams import flight_stream

from groundstation.config import FileSourceSettings, RecorderSettings, Settings, ZenohSettings
from groundstation.live.daemon import run_daemon
from groundstation.live.fanout import Fanout, Inbox, InboxClosed, Overflow, Publish, SinkSpec
from groundstation.live.sources import backoff_delay_s
from groundstation.records import Event, Item, RawChunk, Status, TimeMark
from groundstation.storage import iter_messages


def chunk(i: int) -> RawChunk:
    return RawChunk(bytes([i]), 1_000 + i)


def mark(i: int) -> TimeMark:
    return TimeMark(0, i, i * 10, None, True, False, 1, True, 5, 2_000 + i)


async def drain(inbox: Inbox) -> list[Item]:
    out: list[Item] = []
    while len(inbox):
        out.extend(await inbox.get_all())
    return out


def test_drop_oldest_counts_and_reports() -> None:
    async def main() -> None:
        fan = Fanout(clock=lambda: 123)
        mon = fan.add_inbox("monitor", 3, Overflow.DROP_OLDEST, (RawChunk, Event))
        spy = fan.add_inbox("spy", 1000, Overflow.NEVER_DROP, (RawChunk, Event))
        for i in range(10):
            fan.publish(chunk(i))
        assert len(mon) == 3  # the bound holds
        got = [await mon.get() for _ in range(len(mon))]
        assert got == [chunk(7), chunk(8), chunk(9)]  # the newest survive (the event dropped)
        assert mon.dropped == 8
        events = [i for i in await drain(spy) if isinstance(i, Event)]
        assert [e.kind for e in events] == ["fanout.dropped"]  # rate-limited: one event
        assert events[0].data["sink"] == "monitor"

    asyncio.run(main())


def test_never_drop_keeps_everything_and_raises_behind_then_caught_up() -> None:
    async def main() -> None:
        fan = Fanout(clock=lambda: 1)
        rec = fan.add_inbox("recorder", 4, Overflow.NEVER_DROP, (RawChunk, Event))
        for i in range(20):
            fan.publish(chunk(i))  # never blocks, even far beyond the bound
        assert rec.dropped == 0 and rec.behind and rec.over_limit > 0
        fan.close()
        items: list[Item] = []
        while True:
            try:
                items.extend(await rec.get_all())
            except InboxClosed:
                break
        assert [i for i in items if isinstance(i, RawChunk)] == [chunk(i) for i in range(20)]
        kinds = [i.kind for i in items if isinstance(i, Event)]
        assert kinds == ["recorder.behind"]  # caught_up is raised but the inbox is closed
        assert not rec.behind and rec.delivered == len(items)

    asyncio.run(main())


def test_get_times_out_with_none_and_close_ends() -> None:
    async def main() -> None:
        fan = Fanout()
        box = fan.add_inbox("x", 2, Overflow.DROP_OLDEST, (RawChunk,))
        assert await box.get(timeout_s=0.01) is None
        assert await box.get_all(timeout_s=0.01) == []
        fan.publish(chunk(1))
        fan.close(["x"])
        assert await box.get() == chunk(1)
        with pytest.raises(InboxClosed):
            await box.get()
        with pytest.raises(InboxClosed):
            await box.get_all()
        fan.publish(chunk(2))  # closed inboxes ignore items
        assert len(box) == 0

    asyncio.run(main())


def test_get_all_lingers_for_more_but_not_past_a_quarter_of_the_bound_or_close() -> None:
    async def main() -> None:
        fan = Fanout()
        box = fan.add_inbox("rec", 8, Overflow.NEVER_DROP, (RawChunk,))
        loop = asyncio.get_running_loop()

        async def trickle(n: int) -> None:
            for i in range(n):
                fan.publish(chunk(i))
                await asyncio.sleep(0)

        # a trickle: one wake-up takes the burst that came while lingering
        task = asyncio.create_task(trickle(1))
        got = await box.get_all(linger_s=0.2)
        await task
        assert got == [chunk(0)]  # nothing more came: the linger ran out
        # a quarter of the bound (2 items) ends the linger at once
        loop.call_soon(fan.publish, chunk(1))
        loop.call_soon(fan.publish, chunk(2))
        t0 = loop.time()
        got = await box.get_all(linger_s=30.0)
        assert got == [chunk(1), chunk(2)] and loop.time() - t0 < 30.0
        # closing ends the linger too, and what is queued is delivered first
        loop.call_soon(fan.publish, chunk(3))
        loop.call_soon(fan.close)
        assert await box.get_all(linger_s=30.0) == [chunk(3)]
        with pytest.raises(InboxClosed):
            await box.get_all(linger_s=30.0)

    asyncio.run(main())


def test_a_sink_gets_only_the_types_it_accepts() -> None:
    async def main() -> None:
        fan = Fanout()
        raw = fan.add_inbox("raw", 100, Overflow.NEVER_DROP, (RawChunk,))
        marks = fan.add_inbox("marks", 100, Overflow.DROP_OLDEST, (TimeMark, Event))
        nothing = fan.add_inbox("nothing", 100, Overflow.DROP_OLDEST, ())
        ev = Event("source.outage", 5, "gone")
        for item in (chunk(1), mark(1), ev, chunk(2), mark(2)):
            fan.publish(item)
        assert await drain(raw) == [chunk(1), chunk(2)]
        assert await drain(marks) == [mark(1), ev, mark(2)]
        assert len(nothing) == 0

    asyncio.run(main())


def test_a_sink_never_gets_its_own_output_back() -> None:
    async def main() -> None:
        fan = Fanout()
        mon = fan.add_inbox("monitor", 100, Overflow.DROP_OLDEST, (Event, RawChunk))
        rec = fan.add_inbox("recorder", 100, Overflow.NEVER_DROP, (Event, RawChunk))
        from_monitor, from_recorder = fan.publisher("monitor"), fan.publisher("recorder")
        slip = Event("sat.slip", 1, "G05 slipped")
        full = Event("recorder.write_failed", 2, "disk full", "error")
        from_monitor(slip)
        from_recorder(full)
        fan.publish(chunk(1))  # from the source: everyone
        assert await drain(mon) == [full, chunk(1)]
        assert await drain(rec) == [slip, chunk(1)]

    asyncio.run(main())


def test_duplicate_inbox_names_are_refused() -> None:
    fan = Fanout()
    fan.add_inbox("a", 1, Overflow.DROP_OLDEST, (Event,))
    with pytest.raises(ValueError, match="'a'"):
        fan.add_inbox("a", 1, Overflow.DROP_OLDEST, (Event,))


class Echo:
    """A sink that answers every mark with an event and counts what it receives."""

    name = "echo"
    accepts = frozenset((TimeMark, Event, Status))

    def __init__(self) -> None:
        self.got: list[Item] = []

    async def consume(self, inbox: Inbox, publish: Publish) -> None:
        while True:
            try:
                items = await inbox.get_all()
            except InboxClosed:
                return
            for item in items:
                self.got.append(item)
                if isinstance(item, TimeMark):
                    publish(Event("echo.mark", item.t_host_ns, f"mark {item.count}"))


class Collect:
    name = "collect"
    accepts = frozenset((Event, RawChunk))

    def __init__(self) -> None:
        self.got: list[Item] = []

    async def consume(self, inbox: Inbox, publish: Publish) -> None:
        while True:
            try:
                self.got.extend(await inbox.get_all())
            except InboxClosed:
                return


def test_pipeline_routes_by_declared_types_and_not_back_to_the_producer(tmp_path: Path) -> None:
    """A real pipeline run (file source, recorder, monitor): the echo's events reach the
    collector, the recorder and the monitor but never the echo itself; the echo never sees raw
    chunks or epochs, the collector never sees marks; the monitor's events are recorded once."""
    data, _ = flight_stream(30)
    src = tmp_path / "in.ubx"
    src.write_bytes(data)
    echo, collect = Echo(), Collect()
    settings = Settings(source=FileSourceSettings(path=src, read_size_bytes=97),
                        recorder=RecorderSettings(out_dir=tmp_path / "out"),
                        zenoh=ZenohSettings(enabled=False))
    summary = asyncio.run(run_daemon(settings, sinks=(
        SinkSpec(echo, 1000, Overflow.NEVER_DROP), SinkSpec(collect, 1000, Overflow.NEVER_DROP),
    )))
    n_marks = sum(1 for i in echo.got if isinstance(i, TimeMark))
    assert n_marks == 12
    assert {type(i) for i in echo.got} <= {TimeMark, Event, Status}
    assert not any(isinstance(i, Event) and i.kind == "echo.mark" for i in echo.got)
    assert sum(len(i.data) for i in collect.got if isinstance(i, RawChunk)) == len(data)
    echoed = [i for i in collect.got if isinstance(i, Event) and i.kind == "echo.mark"]
    assert len(echoed) == n_marks
    recorded = [json.loads(m.data) for m in iter_messages(summary.files[0])
                if m.topic == "/groundstation/event"]
    kinds = [e["kind"] for e in recorded]
    assert kinds.count("echo.mark") == n_marks  # recorded once each, not echoed back
    assert len(recorded) == len({(e["kind"], e["t_host_ns"], e["message"]) for e in recorded})


def test_backoff_is_jittered_and_capped() -> None:
    assert backoff_delay_s(0, 0.1, 1.0, lambda: 0.0) == pytest.approx(0.05)
    assert backoff_delay_s(0, 0.1, 1.0, lambda: 1.0) == pytest.approx(0.1)
    assert backoff_delay_s(10, 0.1, 1.0, lambda: 0.999) <= 1.0
    assert backoff_delay_s(10, 0.1, 1.0, lambda: 0.0) == pytest.approx(0.5)


def test_a_linger_ends_on_the_first_item_after_it_not_on_a_timer(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The sink wakes in its producer's pass: the first put once the linger is over ends it
    (the fallback timer is pushed out of reach here, so only the put can end it)."""
    import groundstation.live.fanout as fanout_mod

    monkeypatch.setattr(fanout_mod, "LINGER_LATE", 10_000.0)

    async def main() -> None:
        fan = Fanout()
        box = fan.add_inbox("rec", 100, Overflow.NEVER_DROP, (RawChunk,))
        fan.publish(chunk(0))
        task = asyncio.create_task(box.get_all(linger_s=0.01))
        await asyncio.sleep(0.05)  # the linger is over; nothing has ended it yet
        assert not task.done()
        fan.publish(chunk(1))
        got = await asyncio.wait_for(task, timeout=30)  # a guard against hanging, not a timing
        assert got == [chunk(0), chunk(1)]

    asyncio.run(main())
