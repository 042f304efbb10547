"""Sans-I/O real-time monitor: pipeline items and an injected ``now_ns`` in, status and events out.

It watches what the operator must act on during a flight, one concern per module:

- the link (:mod:`.monitor_link`): the epoch interval, dropouts, byte and frame rates, damage,
  epoch completeness, source outages, and bytes that keep arriving while no frame checks out
  (``no_frames``, naming the likely cause: wrong baud rate or noise; NMEA only);
- the satellites (:mod:`.monitor_sats`): C/N0, elevation/azimuth, lock time, slips, unresolved
  half cycles, seconds of clean continuous phase and the number of "PPK-ready" satellites;
- the time marks (:mod:`.monitor_marks`): received, missed and duplicate marks, pulse width,
  several marks in one epoch, marks that fall inside a dropout;
- alerts (:mod:`.monitor_alerts`) with configured thresholds, raised and cleared as events.

This class routes items to them, reacts to other parts' events and assembles the status. The
rules themselves (epochs, phase, marks) live in :mod:`groundstation.rules`, shared with the
offline tools. Nothing here does I/O or reads a clock: :class:`MonitorSink` adapts it to the
live pipeline.
"""

from __future__ import annotations

import errno
from typing import Any

from groundstation import events as kinds
from groundstation.config import MonitorSettings
from groundstation.gpstime import NS_PER_S
from groundstation.live.monitor_alerts import Alerts
from groundstation.live.monitor_link import Link
from groundstation.live.monitor_marks import Marks
from groundstation.live.monitor_sats import Satellites
from groundstation.records import (
    STATUS_SCHEMA_VERSION,
    DamagedData,
    Event,
    Item,
    PipelineStatus,
    RawChunk,
    RawEpoch,
    Record,
    Status,
    SvInfo,
    TimeMark,
)

DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)

HALF_CYCLE_WARMUP_S = 30.0
"""No half-cycle alert in a session's first 30 s: every satellite starts with its half cycle
unresolved until the receiver has decoded a subframe of it (6 s at best, up to 30 s)."""
PPK_WARMUP_CLEAN_PHASES = 2.0
"""No PPK-ready alert before twice ``clean_phase_s``: a satellite's clean-phase clock starts only
once its half cycle is resolved, so at exactly ``clean_phase_s`` none can be ready yet."""
ALERT_RAISE_AFTER_S = 10.0
"""A hovering condition (half cycles, PPK-ready count) must hold this long before its alert."""
ALERT_CLEAR_AFTER_S = 30.0
"""... and be gone this long before the alert clears (the hysteresis of :meth:`Alerts.hold`)."""
SOURCE_DOWN_AFTER_S = 1.0
"""A source reconnecting within a second (a USB radio replugged) raises no alert."""

MonitorThresholds = MonitorSettings
"""The alert thresholds are the ``[monitor]`` settings themselves (one definition, in config)."""


class Monitor:
    """The monitor's state machine.

    Feed it with :meth:`observe` (any pipeline item, with the current time) and call
    :meth:`tick` regularly (a few times a second); both return the events to publish, and
    :meth:`tick` returns a :class:`Status` once per status interval.
    """

    def __init__(
        self,
        station: str = "",
        thresholds: MonitorSettings | None = None,
        *,
        session_id: str = "",
        status_interval_s: float = 1.0,
    ) -> None:
        self.station = station
        self.th = thresholds or MonitorSettings()
        self.status_interval_s = status_interval_s
        self.session_id = session_id
        self.alerts = Alerts()
        self.link = Link(self.th, self.alerts)
        self.sats = Satellites(self.th)
        self.mark_watch = Marks(self.th, self.alerts, self.link)
        self.recorder_behind = False
        self.disk_free_mb: float | None = None
        self.recording: dict[str, Any] = {}
        self._next_status_ns: int | None = None

    # -- counters the tests and the final report read --------------------------------------

    @property
    def interval_ns(self) -> int | None:
        return self.link.interval_ns

    @property
    def epochs(self) -> int:
        return self.link.epochs

    @property
    def missing_epochs(self) -> int:
        return self.link.missing_epochs

    @property
    def marks(self) -> int:
        return self.mark_watch.rule.marks

    @property
    def missed(self) -> int:
        return self.mark_watch.rule.missed

    @property
    def duplicates(self) -> int:
        return self.mark_watch.rule.duplicates

    @property
    def marks_recovered(self) -> int:
        return self.mark_watch.recovered

    @property
    def marks_in_dropout(self) -> int:
        return self.mark_watch.in_dropout

    # -- input ----------------------------------------------------------------------------

    def observe(self, item: Item | Record, now_ns: int) -> list[Event]:
        """Take one pipeline item; return the events it causes."""
        events: list[Event] = []
        if isinstance(item, RawEpoch):
            self.link.frames_progress(now_ns, events)
            if self.link.on_epoch(item, now_ns, events):
                self.sats.on_epoch(item, now_ns, events)
        elif isinstance(item, TimeMark):
            self.link.frames_progress(now_ns, events)
            self.mark_watch.on_mark(item, now_ns, events)
        elif isinstance(item, SvInfo):
            self.sats.on_svinfo(item)
        elif isinstance(item, Event):
            self._on_event(item, now_ns, events)
        elif isinstance(item, RawChunk):
            self.on_bytes(len(item.data), item.t_host_ns)
        elif isinstance(item, DamagedData):  # where the link garbled bytes, to the epoch
            self.link.on_damage()
        elif isinstance(item, PipelineStatus):  # the pipeline's own counters
            self.link.on_counters(
                item.bad_checksum, item.garbage_bytes, item.frames, item.nmea_sentences,
                item.source_connected, now_ns, events,
            )
            self.link.implausible = item.implausible
        return events

    def on_bytes(self, n: int, t_host_ns: int) -> None:
        self.link.on_bytes(n, t_host_ns)

    def set_disk_free(self, free_mb: float) -> None:
        self.disk_free_mb = free_mb

    # -- events from elsewhere ------------------------------------------------------------

    def _on_event(self, ev: Event, now_ns: int, events: list[Event]) -> None:
        alerts = self.alerts
        if ev.kind == kinds.RECORDER_FILE_OPENED:
            self.recording["file"] = ev.data.get("path")
            self.session_id = str(ev.data.get("session_id") or self.session_id)
        elif ev.kind in (kinds.SOURCE_LOST, kinds.SOURCE_CONNECTED, kinds.SOURCE_OUTAGE):
            self.link.on_source_event(ev.kind, ev.message)
        elif ev.kind == kinds.DECODER_TIME_JUMP:
            # The receiver's time jumped (rules/plausible): the epoch sequence and the
            # satellites' lock and clean-phase times start again from the new time.
            self.link.restart_epochs()
            self.sats = Satellites(self.th)
        elif ev.kind == kinds.OPERATOR_ACK:
            self.mark_watch.acknowledge(str(ev.data.get("alert", "")),
                                        str(ev.data.get("by", "")), now_ns, events)
        elif ev.kind == kinds.STATION_CONFLICT:
            # named in its message, as the views name their own finding of it (the dashboard
            # shows one or the other)
            alerts.raise_(kinds.ALERT_STATION_CONFLICT,
                          f"{kinds.ALERT_STATION_CONFLICT}: {ev.message}", now_ns, events)
        elif ev.kind == kinds.STATION_CONFLICT_ENDED:
            alerts.clear(kinds.ALERT_STATION_CONFLICT, now_ns, events, ok=ev.message)
        elif ev.kind == kinds.ZENOH_DISCONNECTED:
            alerts.raise_(kinds.ALERT_ZENOH_DISCONNECTED, ev.message, now_ns, events)
        elif ev.kind == kinds.ZENOH_CONNECTED:
            alerts.clear(kinds.ALERT_ZENOH_DISCONNECTED, now_ns, events, ok=ev.message)
        elif ev.kind in (kinds.RECORDER_WRITE_FAILED, kinds.RECORDER_VANISHED):
            full = ev.data.get("errno") in DISK_FULL_ERRNOS
            name = kinds.ALERT_DISK_FULL if full else kinds.ALERT_RECORDING_FAILED
            alerts.raise_(name, ev.message, now_ns, events,
                          {"error": ev.data.get("error", ""), "errno": ev.data.get("errno", 0)})
        elif ev.kind == kinds.RECORDER_DROPPED:
            for name in (kinds.ALERT_DISK_FULL, kinds.ALERT_RECORDING_FAILED):
                alert = alerts.active.get(name)
                if alert is not None:  # the alert now says what is being lost
                    alert.message = f"{alert.message.split('; ')[0]}; {ev.message}"
        elif ev.kind == kinds.RECORDER_RECOVERED:
            alerts.clear(kinds.ALERT_DISK_FULL, now_ns, events, ok="recording again")
            alerts.clear(kinds.ALERT_RECORDING_FAILED, now_ns, events, ok="recording again")
        elif kinds.sink_of(ev.kind, kinds.BEHIND_SUFFIX) == "recorder":
            self.recorder_behind = True
            alerts.raise_(kinds.ALERT_RECORDER_BEHIND, ev.message, now_ns, events)
        elif kinds.sink_of(ev.kind, kinds.CAUGHT_UP_SUFFIX) == "recorder":
            self.recorder_behind = False
            alerts.clear(kinds.ALERT_RECORDER_BEHIND, now_ns, events,
                         ok="the recorder has caught up")

    # -- alerts from elapsed time ---------------------------------------------------------

    def _evaluate_alerts(self, now_ns: int, events: list[Event]) -> None:
        th, alerts, link = self.th, self.alerts, self.link
        link.evaluate(now_ns, events)
        alerts.hold(
            kinds.ALERT_SOURCE_DOWN, link.source_connected is False, now_ns, events,
            message=f"source down: {link.source_problem or 'not connected'} (retrying)",
            ok="source connected", raise_after_s=SOURCE_DOWN_AFTER_S, clear_after_s=0.0,
        )
        if link.epochs and link.first_epoch_ns is not None and link.last_epoch_ns is not None:
            # Session time in GPS time (data time): right for live and replay alike.
            age_s = (link.last_epoch_ns - link.first_epoch_ns) / NS_PER_S
            ready, tracked, half, _ = self.sats.counts(link.last_epoch_ns)
            alerts.hold(
                kinds.ALERT_PPK_READY_LOW,
                age_s >= PPK_WARMUP_CLEAN_PHASES * th.clean_phase_s and ready < th.ppk_ready_min,
                now_ns, events,
                message=f"only {ready} satellites with clean phase for {th.clean_phase_s:g} s "
                f"(need {th.ppk_ready_min})",
                ok=f"PPK ready: {ready} satellites with clean phase for {th.clean_phase_s:g} s",
                raise_after_s=ALERT_RAISE_AFTER_S, clear_after_s=ALERT_CLEAR_AFTER_S,
                data={"ppk_ready": ready},
            )
            frac = half / tracked if tracked else 0.0
            alerts.hold(
                kinds.ALERT_HALF_CYCLE_HIGH,
                age_s >= HALF_CYCLE_WARMUP_S and frac > th.half_cycle_fraction_max,
                now_ns, events,
                message=f"{half} of {tracked} satellites with unresolved half cycles",
                ok=f"half cycles resolved: {tracked - half} of {tracked} satellites",
                raise_after_s=ALERT_RAISE_AFTER_S, clear_after_s=ALERT_CLEAR_AFTER_S,
                data={"fraction": round(frac, 3)},
            )
        link.check_frames(now_ns, events)
        self.mark_watch.evaluate(now_ns, events)
        if self.disk_free_mb is not None:
            if self.disk_free_mb < th.disk_free_min_mb:
                alerts.raise_(kinds.ALERT_DISK_LOW,
                              f"disk space low: {self.disk_free_mb:.0f} MB free", now_ns, events,
                              {"free_mb": round(self.disk_free_mb, 1)})
            else:
                alerts.clear(kinds.ALERT_DISK_LOW, now_ns, events,
                             ok=f"disk space: {self.disk_free_mb:.0f} MB free")

    # -- output ---------------------------------------------------------------------------

    def tick(self, now_ns: int) -> tuple[Status | None, list[Event]]:
        """Advance the clock: alerts from elapsed time, and the status when it is due."""
        events: list[Event] = []
        self._evaluate_alerts(now_ns, events)
        interval = int(self.status_interval_s * NS_PER_S)
        if self._next_status_ns is None:
            self._next_status_ns = now_ns + interval
            return None, events
        if now_ns < self._next_status_ns:
            return None, events
        self._next_status_ns += interval
        if self._next_status_ns <= now_ns:  # we were late; do not burst
            self._next_status_ns = now_ns + interval
        return self.status(now_ns), events

    def status(self, now_ns: int) -> Status:
        ready, tracked, half, below = self.sats.counts(self.link.last_epoch_ns)
        t_last = self.link.last_epoch_ns or 0
        return Status(
            schema=STATUS_SCHEMA_VERSION,
            station=self.station,
            t_host_ns=now_ns,
            session_id=self.session_id,
            link=self.link.status(now_ns),
            sats=self.sats.statuses(t_last),
            ppk_ready=ready,
            tracked=tracked,
            half_cycle_fraction=round(half / tracked, 3) if tracked else 0.0,
            marks=self.mark_watch.status(t_last),
            alerts=self.alerts.messages(),
            recording=dict(self.recording),
            ppk_ready_min=self.th.ppk_ready_min,
            ppk_clean_phase_s=self.th.clean_phase_s,
            below_mask=below,
            elevation_mask_deg=self.th.elevation_mask_deg,
            unidentified=self.sats.unidentified,
        )
