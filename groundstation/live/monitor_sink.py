"""The monitor as a pipeline sink: feeds :class:`Monitor` with items and the wall clock.

It takes the raw chunks (byte counts and times), the records the monitor's rules need, the
other stages' events and the pipeline's counters (:data:`MONITOR_INPUTS`). It also samples the
free space of the recording directory, and publishes the monitor's status (1 Hz) and events to
the other sinks (the recorder and the Zenoh publisher take them); they never come back to it.
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from groundstation import events as kinds
from groundstation.live.fanout import Inbox, InboxClosed, Publish
from groundstation.live.monitor import ALERT_CLEAR_AFTER_S, ALERT_RAISE_AFTER_S, Monitor
from groundstation.records import (
    DamagedData,
    Event,
    Item,
    PipelineStatus,
    RawChunk,
    RawEpoch,
    Status,
    SvInfo,
    TimeMark,
)

log = logging.getLogger("groundstation.monitor")

TICK_S = 0.1
DISK_CHECK_S = 5.0
LINGER_S = 0.1
"""Bursts of at least 100 ms (at most 200 ms, ``fanout.LINGER_LATE``), one tick: the monitor's
rules work on 100 ms and longer, and marks reach Zenoh through the publisher, not through it."""

SILENCE_TICKED_MIN_S = 60.0
"""Replay: across a silence in the data's time the monitor is ticked every 100 ms for at least
this long (longer when an alert threshold or hold is longer), then once at the end of the
silence. Beyond every threshold the ticks would only repeat the same alerts and status; a week
without data ticked in 100 ms steps held the daemon for minutes, took gigabytes and kept it deaf
to SIGTERM (issue 27)."""

MONITOR_INPUTS: frozenset[type] = frozenset(
    (RawChunk, RawEpoch, TimeMark, SvInfo, Event, PipelineStatus, DamagedData)
)
"""What the monitor's rules read; nothing else is routed to it."""


class MonitorSink:
    """Runs a :class:`Monitor` inside the live pipeline.

    Args:
        monitor: the state machine.
        disk_path: directory whose free space is watched (the recording directory).
        clock: UNIX ns clock.
        data_clock: replay: time is the host reception time the items carry, and the monitor
            is ticked every 100 ms of that time between items, as the live daemon did.
    """

    name = "monitor"
    accepts = MONITOR_INPUTS

    def __init__(
        self,
        monitor: Monitor,
        *,
        disk_path: Path | None = None,
        clock: Callable[[], int] = time.time_ns,
        data_clock: bool = False,
    ) -> None:
        self.monitor = monitor
        self.disk_path = disk_path
        self._clock = clock
        self.data_clock = data_clock
        self._next_tick_ns: int | None = None
        self._data_now: int | None = None
        th = monitor.th
        horizon_s = max(SILENCE_TICKED_MIN_S, th.dropout_alert_s, th.no_data_s, th.no_frames_s,
                        th.marks_missed_hold_s, ALERT_RAISE_AFTER_S + ALERT_CLEAR_AFTER_S)
        self._silence_ticked_ns = int((horizon_s + 2 * monitor.status_interval_s) * 1e9)
        self.ticks_skipped = 0
        """Replay ticks left out inside silences longer than the monitor's horizon."""
        self._next_disk_check = 0.0
        self.last_status: Status | None = None

    def _check_disk(self) -> None:
        if self.disk_path is None or time.monotonic() < self._next_disk_check:
            return
        self._next_disk_check = time.monotonic() + DISK_CHECK_S
        try:
            usage = shutil.disk_usage(self.disk_path)
        except OSError as err:
            log.debug("disk usage of %s: %s", self.disk_path, err)
            return
        self.monitor.set_disk_free(usage.free / 1e6)

    def _now(self, item: Item | None, publish: Publish) -> int | None:
        if not self.data_clock:
            return self._clock()
        if not isinstance(item, RawChunk):
            # Only the recorded bytes carry the recording's time (records follow their chunk).
            # The replaying pipeline's own events and counters carry today's wall clock: taken
            # as data time they made every view see minutes of silence ("last byte 630 s ago",
            # no_data, a dropout) that the recording does not hold.
            return self._data_now
        t = getattr(item, "t_host_ns", None) if item is not None else None
        if not isinstance(t, int) or t <= 0:
            return self._data_now
        step = int(TICK_S * 1e9)
        if self._next_tick_ns is None:
            self._next_tick_ns = t + step
        # The ticks the live daemon made while this stretch of data arrived: every TICK_S of
        # data time, also when the chunks come closer together than that (a 115 200-baud
        # file is timed at ~90 ms a chunk; ticking only across gaps gave one status a burst),
        # up to the monitor's horizon into a silence, then the last one before the data.
        limit = (self._data_now if self._data_now is not None else t) + self._silence_ticked_ns
        while self._next_tick_ns < t:
            if self._next_tick_ns > limit:
                skip = (t - 1 - self._next_tick_ns) // step
                self._next_tick_ns += skip * step
                self.ticks_skipped += skip
                limit = t
            self._emit(*self.monitor.tick(self._next_tick_ns), publish)
            self._next_tick_ns += step
        self._data_now = max(t, self._data_now or t)
        return self._data_now

    def _emit(self, status: Status | None, events: list[Event],
              publish: Publish) -> None:
        for ev in events:
            if ev.kind == kinds.ALERT_RAISED:  # the journal shows what the operator must act on
                log.warning("alert: %s", ev.message)
            elif ev.kind == kinds.ALERT_CLEARED:
                log.info("alert cleared: %s", ev.message)
            publish(ev)
        if status is not None:
            self.last_status = status
            publish(status)

    def steps(self, items: list[Item], publish: Publish) -> None:
        """A burst of items through the monitor, then one clock tick (an empty burst: the
        tick alone). Ticking once per burst rather than per item is what keeps the monitor's
        cost per 115 200-baud chunk low; in replay the ticks between items still happen every
        100 ms of their time."""
        now: int | None = None
        for item in items:
            now = self._now(item, publish)
            if now is None:
                continue
            if type(item) is RawChunk:
                self.monitor.on_bytes(len(item.data), item.t_host_ns)
            else:
                self._emit(None, self.monitor.observe(item, now), publish)
        if not items:
            now = self._now(None, publish)
        if now is None:
            return
        self._check_disk()
        self._emit(*self.monitor.tick(now), publish)

    async def consume(self, inbox: Inbox, publish: Publish) -> None:
        while True:
            try:
                items = await inbox.get_all(timeout_s=TICK_S, linger_s=LINGER_S)
            except InboxClosed:
                break
            self.steps(items, publish)
        end = self._data_now if self.data_clock and self._data_now else self._clock()
        final = self.monitor.status(end)
        self.last_status = final
        publish(final)
