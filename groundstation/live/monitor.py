"""Sans-I/O real-time monitor: pipeline items and an injected ``now_ns`` in, status and events out.

It watches what the operator must act on during a flight:

- the link: the epoch interval learned from the stream, dropouts (runs of missing epochs, seen
  from the clock while they last and measured exactly when data returns), byte and frame rates,
  damage, epoch completeness, source outages;
- the satellites: C/N0, elevation/azimuth, lock time, slips, unresolved half cycles, seconds of
  clean continuous phase and the number of "PPK-ready" satellites;
- the time marks: count continuity (missed marks), edges, pulse width, several marks in one
  epoch, marks that fall inside a dropout;
- the bytes themselves: bytes that keep arriving while no frame checks out for
  ``no_frames_s`` raise ``no_frames`` naming the likely cause (wrong baud rate or noise; the
  receiver sending NMEA only when that is what the framer recognises);
- alerts with configured thresholds, raised and cleared as events.

Nothing here does I/O or reads a clock: :class:`MonitorSink` adapts it to the live pipeline.
"""

from __future__ import annotations

import bisect
import errno
import statistics
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from groundstation.config import MonitorSettings
from groundstation.gpstime import NS_PER_S
from groundstation.records import (
    STATUS_SCHEMA_VERSION,
    Dropout,
    Event,
    Item,
    LinkStatus,
    MarkStatus,
    PipelineStatus,
    RawChunk,
    RawEpoch,
    Record,
    SatStatus,
    Status,
    SvInfo,
    TimeMark,
)

RATE_WINDOW_NS = 5 * NS_PER_S
INTERVAL_HISTORY = 25
RECENT_DROPOUTS = 50
SAT_LOST_AFTER_EPOCHS = 5  # RTKLIB's default maxout
RECENT_MARKS = 32
LINK_HISTORY_NS = 600 * NS_PER_S  # epochs kept for the completeness windows and the timeline
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
NO_FRAMES_MIN_BYTES = 64  # a few stray bytes after the last frame are no evidence of anything


MonitorThresholds = MonitorSettings
"""The alert thresholds are the ``[monitor]`` settings themselves (one definition, in config)."""


@dataclass(slots=True)
class _Sat:
    sv: str
    first_seen_ns: int
    last_seen_ns: int
    lock_since_ns: int
    clean_since_ns: int | None
    cno: int = 0
    mes_qi: int | None = None
    half: bool = False
    slips: int = 0
    last_slip_ns: int | None = None
    elev: int | None = None
    azim: int | None = None
    used: bool | None = None
    has_phase: bool = True
    absent: int = 0  # consecutive received epochs without this satellite


@dataclass(slots=True)
class _Alert:
    name: str
    message: str
    since_ns: int
    data: dict[str, Any] = field(default_factory=dict)


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
        # link
        self.interval_ns: int | None = None
        self._diffs: deque[int] = deque(maxlen=INTERVAL_HISTORY)
        self._epoch_times: deque[int] = deque()  # GPS ns, for completeness windows
        self._epoch_host: deque[int] = deque()  # host ns of the same epochs
        self.epochs = 0
        self.first_epoch_ns: int | None = None
        self.last_epoch_ns: int | None = None
        self.last_epoch_host_ns: int | None = None
        self._early: list[int] = []  # epochs seen before the interval was known
        # the recent dropouts (a long session on a shared channel has thousands) and a count
        self.dropouts: deque[Dropout] = deque(maxlen=RECENT_DROPOUTS)
        self.dropout_count = 0
        self.missing_epochs = 0
        self._ongoing_since_ns: int | None = None  # host time the ongoing dropout was declared
        self.last_byte_ns: int | None = None
        self._bytes: deque[tuple[int, int]] = deque()
        self._frames: deque[tuple[int, int]] = deque()
        self.bytes_in = 0
        self.frames = 0
        self.damaged = 0
        self.garbage = 0
        self.source_connected: bool | None = None
        self.source_outages = 0
        self.nmea_sentences = 0
        self._frameless_since_ns: int | None = None  # first byte after the last frame progress
        self._frameless_bytes = 0
        self._frameless_nmea = 0
        # satellites
        self.sats: dict[str, _Sat] = {}
        self._svinfo: dict[str, tuple[int, int, bool]] = {}
        # marks
        self.marks = 0
        self.last_mark: TimeMark | None = None
        self._recent_falling: deque[int] = deque(maxlen=RECENT_MARKS)
        self.marks_recovered = 0
        self._last_count: dict[int, int] = {}
        self.missed = 0
        self.duplicates = 0
        self.marks_in_dropout = 0
        self.multi_in_epoch = 0
        self._mark_times: list[int] = []  # falling-edge GPS ns, sorted
        self._mark_epoch_slots: dict[int, int] = {}
        self.last_pulse_ms: float | None = None
        self._last_missed_ns: int | None = None
        # alerts and status
        self.alerts: dict[str, _Alert] = {}
        self.recorder_behind = False
        self.disk_free_mb: float | None = None
        self.recording: dict[str, Any] = {}
        self._next_status_ns: int | None = None

    # -- input ----------------------------------------------------------------------------

    def observe(self, item: Item | Record, now_ns: int) -> list[Event]:
        """Take one pipeline item; return the events it causes."""
        events: list[Event] = []
        if isinstance(item, RawEpoch):
            self._frames_progress(now_ns, events)
            self._on_epoch(item, now_ns, events)
        elif isinstance(item, TimeMark):
            self._frames_progress(now_ns, events)
            self._on_mark(item, now_ns, events)
        elif isinstance(item, SvInfo):
            for s in item.sats:
                self._svinfo[s.label] = (s.elev_deg, s.azim_deg, s.used)
        elif isinstance(item, Event):
            self._on_event(item, now_ns, events)
        elif isinstance(item, RawChunk):
            self.on_bytes(len(item.data), item.t_host_ns)
        elif isinstance(item, PipelineStatus):  # the pipeline's own counters
            self.damaged = item.bad_checksum
            self.garbage = item.garbage_bytes
            if item.frames > self.frames:
                self._frames_progress(now_ns, events)
            self.frames = item.frames
            nmea = item.nmea_sentences
            if self._frameless_since_ns is not None:
                self._frameless_nmea += max(0, nmea - self.nmea_sentences)
            self.nmea_sentences = nmea
            if item.source_connected is not None:
                self.source_connected = item.source_connected
        return events

    def on_bytes(self, n: int, t_host_ns: int) -> None:
        self.bytes_in += n
        self.last_byte_ns = t_host_ns
        self._bytes.append((t_host_ns, n))
        if self._frameless_since_ns is None:
            self._frameless_since_ns = t_host_ns
        self._frameless_bytes += n

    def _frames_progress(self, now_ns: int, events: list[Event]) -> None:
        """Valid frames arrived: the bytes make sense again."""
        self._frameless_since_ns = None
        self._frameless_bytes = 0
        self._frameless_nmea = 0
        self._clear("no_frames", now_ns, events)

    def _check_frames(self, now_ns: int, events: list[Event]) -> None:
        """Bytes arriving for ``no_frames_s`` without one valid UBX frame among them."""
        since, last = self._frameless_since_ns, self.last_byte_ns
        if since is None or last is None or self._frameless_bytes < NO_FRAMES_MIN_BYTES:
            return
        span_s = (last - since) / NS_PER_S
        if span_s < self.th.no_frames_s:
            return
        if self._frameless_nmea:
            cause = ("the receiver sends NMEA only (UBX output is off: run "
                     "`groundstation configure` with the receiver's profile)")
        else:
            cause = ("wrong baud rate (bytes arrive but no frame checks out), "
                     "or noise on the line")
        self._raise(
            "no_frames",
            f"no valid frames for {span_s:.0f} s although {self._frameless_bytes} bytes "
            f"arrived: likely cause: {cause}",
            now_ns, events,
            {"bytes": self._frameless_bytes, "nmea_sentences": self._frameless_nmea,
             "likely_cause": "nmea_only" if self._frameless_nmea else "baud_or_noise"},
        )

    def set_disk_free(self, free_mb: float) -> None:
        self.disk_free_mb = free_mb

    # -- link -----------------------------------------------------------------------------

    def _on_epoch(self, ep: RawEpoch, now_ns: int, events: list[Event]) -> None:
        if ep.gps_week == 0:
            return  # no time yet (cold start)
        t = ep.t_gps_ns
        self._frames.append((now_ns, 1))
        if self.last_epoch_ns is not None and t <= self.last_epoch_ns:
            return  # a repeat (RXM-RAW and RXM-RAWX both enabled) or out of order
        prev = self.last_epoch_ns
        self.epochs += 1
        if self.first_epoch_ns is None:
            self.first_epoch_ns = t
        self.last_epoch_ns = t
        self.last_epoch_host_ns = now_ns
        self._epoch_times.append(t)
        self._epoch_host.append(now_ns)
        while self._epoch_times and self._epoch_times[0] < t - LINK_HISTORY_NS:
            self._epoch_times.popleft()
            self._epoch_host.popleft()
        if prev is not None:
            self._diffs.append(t - prev)
        if self.interval_ns is None:
            self._early.append(t)
            if len(self._diffs) >= 4:
                self.interval_ns = self._learn_interval()
                for a, b in zip(self._early, self._early[1:], strict=False):
                    self._check_gap(a, b, now_ns, events)
                self._early.clear()
        else:
            if len(self._diffs) == INTERVAL_HISTORY and self.epochs % INTERVAL_HISTORY == 0:
                self.interval_ns = self._learn_interval()
            if prev is not None:
                self._check_gap(prev, t, now_ns, events)
        if self._ongoing_since_ns is not None:
            self._ongoing_since_ns = None
            self._clear("dropout_long", now_ns, events)
        self._on_epoch_sats(ep, now_ns, events)

    def _learn_interval(self) -> int:
        med = statistics.median_low(self._diffs)
        return max(10_000_000, round(med / 10_000_000) * 10_000_000)

    def _check_gap(self, prev: int, t: int, now_ns: int, events: list[Event]) -> None:
        assert self.interval_ns is not None
        d = t - prev
        if d <= self.interval_ns * 3 // 2:
            return
        missing = max(1, round(d / self.interval_ns) - 1)
        drop = Dropout(
            start_t_gps_ns=prev + self.interval_ns,
            end_t_gps_ns=t - self.interval_ns,
            missing_epochs=missing,
            duration_s=(d - self.interval_ns) / 1e9,
        )
        self.dropouts.append(drop)
        self.dropout_count += 1
        self.missing_epochs += missing
        events.append(Event(
            "link.dropout", now_ns,
            f"link dropout: {missing} epoch(s) missing ({drop.duration_s:.1f} s)",
            "warning",
            {"start_t_gps_ns": drop.start_t_gps_ns, "end_t_gps_ns": drop.end_t_gps_ns,
             "missing_epochs": missing, "duration_s": drop.duration_s},
        ))
        # Marks already received whose exposure falls in the hole sit on an interpolation gap.
        lo = bisect.bisect_right(self._mark_times, prev)
        hi = bisect.bisect_left(self._mark_times, t)
        for mt in self._mark_times[lo:hi]:
            self._mark_in_dropout(mt, now_ns, events)

    def _ongoing_dropout(self, now_ns: int) -> Dropout | None:
        if (self.interval_ns is None or self.last_epoch_host_ns is None
                or self.last_epoch_ns is None):
            return None
        late = now_ns - self.last_epoch_host_ns
        threshold = self.interval_ns + max(self.interval_ns // 2, 300_000_000)
        if late <= threshold:
            return None
        missing = max(1, late // self.interval_ns)
        return Dropout(
            start_t_gps_ns=self.last_epoch_ns + self.interval_ns,
            end_t_gps_ns=self.last_epoch_ns + missing * self.interval_ns,
            missing_epochs=missing,
            duration_s=(late - self.interval_ns) / 1e9 if late > self.interval_ns else 0.0,
            ongoing=True,
        )

    # -- satellites -----------------------------------------------------------------------

    def _on_epoch_sats(self, ep: RawEpoch, now_ns: int, events: list[Event]) -> None:
        # A satellite counts as lost only when it is missing from epochs that did arrive: a link
        # dropout says nothing about the receiver's tracking (RTKLIB keeps ambiguities across
        # an outage of up to 5 epochs, and the receiver flags a slip when lock really broke).
        t = ep.t_gps_ns
        seen = set()
        for s in ep.sats:
            label = s.label if s.sig_id == 0 else f"{s.label}/{s.sig_id}"
            seen.add(label)
            sat = self.sats.get(label)
            has_phase = s.cp_valid and s.carrier_phase_cyc != 0.0 and (
                s.mes_qi is None or s.mes_qi >= 5
            )
            if sat is None or sat.absent > SAT_LOST_AFTER_EPOCHS:
                sat = _Sat(label, t, t, t, t if has_phase else None)
                self.sats[label] = sat
            sat.absent = 0
            if s.slip and t != sat.first_seen_ns:
                sat.slips += 1
                sat.last_slip_ns = t
                sat.lock_since_ns = t
                sat.clean_since_ns = t if has_phase and not s.half_cycle_unresolved else None
                events.append(Event(
                    "sat.slip", now_ns, f"{label}: cycle slip", "info",
                    {"sv": label, "t_gps_ns": t, "slips": sat.slips},
                ))
            if s.half_cycle_unresolved != sat.half:
                sat.half = s.half_cycle_unresolved
                kind = "sat.half_cycle_set" if sat.half else "sat.half_cycle_cleared"
                what = "half-cycle ambiguity unresolved" if sat.half else "half cycle resolved"
                events.append(Event(kind, now_ns, f"{label}: {what}", "info",
                                    {"sv": label, "t_gps_ns": t}))
            if not has_phase or s.half_cycle_unresolved:
                sat.clean_since_ns = None
            elif sat.clean_since_ns is None:
                sat.clean_since_ns = t
            sat.has_phase = has_phase
            sat.last_seen_ns = t
            sat.cno = s.cno_dbhz
            sat.mes_qi = s.mes_qi
        for label, sat in list(self.sats.items()):
            if label not in seen:
                sat.absent += 1
                if sat.absent > SAT_LOST_AFTER_EPOCHS:
                    del self.sats[label]

    # -- marks ----------------------------------------------------------------------------

    def _on_mark(self, m: TimeMark, now_ns: int, events: list[Event]) -> None:
        if m.new_rising and m.rising_t_gps_ns is not None and m.falling_t_gps_ns is not None:
            width = (m.rising_t_gps_ns - m.falling_t_gps_ns) / 1e6
            if 0 <= width < 10_000:
                self.last_pulse_ms = width
        ft = m.falling_t_gps_ns
        if ft is None:
            return
        if ft in self._recent_falling:
            if m.new_falling:  # the same exposure reported as new again
                self.duplicates += 1
                events.append(Event("mark.duplicate", now_ns, f"duplicate time mark {m.count}",
                                    "warning", {"count": m.count, "t_gps_ns": ft}))
            return
        # A falling edge not seen before: from its own record, or from the rising-edge record
        # that repeats it when the falling-edge record was lost on the link.
        self._recent_falling.append(ft)
        self.marks += 1
        if not m.new_falling:
            self.marks_recovered += 1
        self.last_mark = m
        # ``count`` counts rising edges: a record that carries this mark's rising edge has the
        # mark's own number, a falling-edge-only record the number before it. A jump between
        # consecutive marks' numbers is marks whose every record was lost.
        number = m.count if m.new_rising else (m.count + 1) & 0xFFFF
        last = self._last_count.get(m.channel)
        self._last_count[m.channel] = number
        if last is not None:
            step = (number - last) & 0xFFFF
            if 1 < step < 0x8000:
                self.missed += step - 1
                self._last_missed_ns = now_ns
                events.append(Event(
                    "mark.missed", now_ns, f"{step - 1} time mark(s) missed "
                    f"(count {last} -> {number})", "warning",
                    {"from_count": last, "to_count": number, "missed": step - 1},
                ))
                self._raise("marks_missed", f"{self.missed} time marks missed", now_ns, events,
                            {"missed": self.missed})
        bisect.insort(self._mark_times, ft)
        if self.last_epoch_ns is not None and self._mark_times[0] < (
            self.last_epoch_ns - LINK_HISTORY_NS
        ):  # only marks a gap still to be measured can fall into are needed
            del self._mark_times[: bisect.bisect_left(self._mark_times,
                                                     self.last_epoch_ns - LINK_HISTORY_NS)]
        if self.interval_ns:
            slot = ft // self.interval_ns
            n = self._mark_epoch_slots.get(slot, 0) + 1
            self._mark_epoch_slots[slot] = n
            if n == 2:
                self.multi_in_epoch += 1
            if len(self._mark_epoch_slots) > 4096:
                for k in sorted(self._mark_epoch_slots)[:2048]:
                    del self._mark_epoch_slots[k]
        # A mark during an ongoing dropout, or inside an already measured one.
        if self._ongoing_dropout(now_ns) is not None and self.last_epoch_ns is not None and (
            ft > self.last_epoch_ns
        ):
            return  # decided when the dropout ends (_check_gap)
        for d in reversed(self.dropouts):
            if d.start_t_gps_ns - (self.interval_ns or 0) < ft < d.end_t_gps_ns + (
                self.interval_ns or 0
            ):
                self._mark_in_dropout(ft, now_ns, events)
                break

    def _mark_in_dropout(self, ft: int, now_ns: int, events: list[Event]) -> None:
        self.marks_in_dropout += 1
        events.append(Event(
            "mark.in_dropout", now_ns,
            "time mark inside a link dropout: its photo sits on an interpolation gap",
            "warning", {"t_gps_ns": ft},
        ))

    # -- events from elsewhere ------------------------------------------------------------

    def _on_event(self, ev: Event, now_ns: int, events: list[Event]) -> None:
        if ev.kind == "recorder.file_opened":
            self.recording["file"] = ev.data.get("path")
            self.session_id = str(ev.data.get("session_id") or self.session_id)
        elif ev.kind == "source.lost":
            self.source_connected = False
        elif ev.kind == "source.connected":
            self.source_connected = True
        elif ev.kind == "source.outage":
            self.source_outages += 1
            self.source_connected = True
        elif ev.kind == "zenoh.disconnected":
            self._raise("zenoh_disconnected", ev.message, now_ns, events)
        elif ev.kind == "zenoh.connected":
            self._clear("zenoh_disconnected", now_ns, events)
        elif ev.kind == "recorder.write_failed":
            name = "disk_full" if ev.data.get("errno") in DISK_FULL_ERRNOS else "recording_failed"
            self._raise(name, ev.message, now_ns, events,
                        {"error": ev.data.get("error", ""), "errno": ev.data.get("errno", 0)})
        elif ev.kind == "recorder.dropped":
            for name in ("disk_full", "recording_failed"):
                alert = self.alerts.get(name)
                if alert is not None:  # the alert now says what is being lost
                    alert.message = f"{alert.message.split('; ')[0]}; {ev.message}"
        elif ev.kind == "recorder.recovered":
            self._clear("disk_full", now_ns, events)
            self._clear("recording_failed", now_ns, events)
        elif ev.kind.endswith(".behind") and ev.kind.startswith("recorder"):
            self.recorder_behind = True
            self._raise("recorder_behind", ev.message, now_ns, events)
        elif ev.kind.endswith(".caught_up") and ev.kind.startswith("recorder"):
            self.recorder_behind = False
            self._clear("recorder_behind", now_ns, events)

    # -- alerts ---------------------------------------------------------------------------

    def _raise(
        self, name: str, message: str, now_ns: int, events: list[Event],
        data: dict[str, Any] | None = None,
    ) -> None:
        alert = self.alerts.get(name)
        if alert is not None:
            alert.message = message
            return
        self.alerts[name] = _Alert(name, message, now_ns, data or {})
        events.append(Event("alert.raised", now_ns, message, "warning",
                            {"alert": name, **(data or {})}))

    def _clear(self, name: str, now_ns: int, events: list[Event]) -> None:
        alert = self.alerts.pop(name, None)
        if alert is None:
            return
        events.append(Event("alert.cleared", now_ns, f"cleared: {alert.message}", "info",
                            {"alert": name, "duration_s": (now_ns - alert.since_ns) / 1e9}))

    def _evaluate_alerts(self, now_ns: int, events: list[Event]) -> None:
        th = self.th
        ongoing = self._ongoing_dropout(now_ns)
        if ongoing is not None and self._ongoing_since_ns is None:
            self._ongoing_since_ns = now_ns
            events.append(Event(
                "link.dropout_started", now_ns,
                "link dropout: no epoch since "
                f"{(now_ns - (self.last_epoch_host_ns or now_ns)) / 1e9:.1f} s",
                "warning", {"start_t_gps_ns": ongoing.start_t_gps_ns},
            ))
        if ongoing is not None and ongoing.duration_s >= th.dropout_alert_s:
            self._raise("dropout_long", f"link dropout longer than {th.dropout_alert_s:g} s",
                        now_ns, events, {"start_t_gps_ns": ongoing.start_t_gps_ns})
        if self.last_byte_ns is not None:
            if (now_ns - self.last_byte_ns) / 1e9 >= th.no_data_s:
                self._raise("no_data", f"no data for {th.no_data_s:g} s or more", now_ns, events)
            else:
                self._clear("no_data", now_ns, events)
        if self.epochs and self.first_epoch_ns is not None and self.last_epoch_ns is not None:
            warmed_up = self.last_epoch_ns - self.first_epoch_ns >= th.clean_phase_s * NS_PER_S
            ready, tracked, half = self._sat_counts()
            if warmed_up and ready < th.ppk_ready_min:
                self._raise("ppk_ready_low",
                            f"only {ready} satellites with clean phase for "
                            f"{th.clean_phase_s:g} s (need {th.ppk_ready_min})",
                            now_ns, events, {"ppk_ready": ready})
            elif ready >= th.ppk_ready_min:
                self._clear("ppk_ready_low", now_ns, events)
            frac = half / tracked if tracked else 0.0
            if frac > th.half_cycle_fraction_max:
                self._raise("half_cycle_high",
                            f"{half} of {tracked} satellites with unresolved half cycles",
                            now_ns, events, {"fraction": round(frac, 3)})
            else:
                self._clear("half_cycle_high", now_ns, events)
        self._check_frames(now_ns, events)
        if (self._last_missed_ns is not None
                and now_ns - self._last_missed_ns >= th.marks_missed_hold_s * NS_PER_S):
            self._clear("marks_missed", now_ns, events)
        if self.disk_free_mb is not None:
            if self.disk_free_mb < th.disk_free_min_mb:
                self._raise("disk_low", f"disk space low: {self.disk_free_mb:.0f} MB free",
                            now_ns, events, {"free_mb": round(self.disk_free_mb, 1)})
            else:
                self._clear("disk_low", now_ns, events)

    def _sat_counts(self) -> tuple[int, int, int]:
        """(PPK-ready, tracked with phase, half-cycle unresolved) over the current satellites."""
        if self.last_epoch_ns is None:
            return 0, 0, 0
        t = self.last_epoch_ns
        ready = tracked = half = 0
        need = int(self.th.clean_phase_s * NS_PER_S)
        for label, sat in self.sats.items():
            if "/" in label or label[0] == "S":
                continue  # one signal per satellite; SBAS gives no usable phase
            tracked += 1
            half += sat.half
            el = self._svinfo.get(label, (None, None, None))[0]
            above = el is None or el >= self.th.elevation_mask_deg
            if above and sat.clean_since_ns is not None and t - sat.clean_since_ns >= need:
                ready += 1
        return ready, tracked, half

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

    def _rate(self, q: deque[tuple[int, int]], now_ns: int) -> float:
        while q and q[0][0] < now_ns - RATE_WINDOW_NS:
            q.popleft()
        return sum(n for _, n in q) / (RATE_WINDOW_NS / 1e9) if q else 0.0

    def _completeness(self, window_s: float | None) -> float | None:
        if self.interval_ns is None or self.last_epoch_ns is None or self.first_epoch_ns is None:
            return None
        end = self.last_epoch_ns
        if window_s is None:
            span = end - self.first_epoch_ns
            got = self.epochs
        else:
            span = min(int(window_s * NS_PER_S), end - self.first_epoch_ns)
            start = end - span
            got = len(self._epoch_times) - bisect.bisect_left(list(self._epoch_times), start)
        expected = span // self.interval_ns + 1
        return min(1.0, got / expected) if expected else None

    def status(self, now_ns: int) -> Status:
        ongoing = self._ongoing_dropout(now_ns)
        ready, tracked, half = self._sat_counts()
        t_last = self.last_epoch_ns or 0
        sats = []
        for label, s in sorted(self.sats.items()):
            el, az, used = self._svinfo.get(label.split("/")[0], (None, None, None))
            slip_age = (t_last - s.last_slip_ns) / 1e9 if s.last_slip_ns is not None else None
            if not s.has_phase:
                state = "code_only"
            elif s.half:
                state = "half_cycle"
            elif slip_age is not None and slip_age < 30:
                state = "slipped"
            else:
                state = "clean"
            sats.append(SatStatus(
                sv=label, cno_dbhz=s.cno, elev_deg=el, azim_deg=az,
                lock_s=(t_last - s.lock_since_ns) / 1e9,
                clean_phase_s=(t_last - s.clean_since_ns) / 1e9 if s.clean_since_ns is not None
                else 0.0,
                half_cycle_unresolved=s.half, slips=s.slips, last_slip_age_s=slip_age,
                mes_qi=s.mes_qi, used=used, state=state,  # type: ignore[arg-type]
            ))
        link = LinkStatus(
            epoch_interval_s=self.interval_ns / 1e9 if self.interval_ns else None,
            epochs=self.epochs,
            first_epoch_t_gps_ns=self.first_epoch_ns,
            last_epoch_t_gps_ns=self.last_epoch_ns,
            last_byte_age_s=(now_ns - self.last_byte_ns) / 1e9 if self.last_byte_ns else None,
            bytes_per_s=self._rate(self._bytes, now_ns),
            frames_per_s=self._rate(self._frames, now_ns),
            bytes_in=self.bytes_in,
            frames=self.frames,
            damaged_frames=self.damaged,
            garbage_bytes=self.garbage,
            completeness_10s=self._completeness(10.0),
            completeness_60s=self._completeness(60.0),
            completeness_session=self._completeness(None),
            dropouts=self.dropout_count,
            missing_epochs=self.missing_epochs,
            current_dropout=ongoing,
            recent_dropouts=tuple(self.dropouts),
            source_connected=self.source_connected,
            source_outages=self.source_outages,
        )
        lm = self.last_mark
        minutes = (t_last - self.first_epoch_ns) / 60e9 if self.first_epoch_ns else 0.0
        marks = MarkStatus(
            marks=self.marks,
            last_count=lm.count if lm else None,
            last_falling_t_gps_ns=lm.falling_t_gps_ns if lm else None,
            last_pulse_width_ms=self.last_pulse_ms,
            missed=self.missed,
            duplicates=self.duplicates,
            in_dropout=self.marks_in_dropout,
            multi_in_epoch=self.multi_in_epoch,
            rate_per_min=self.marks / minutes if minutes > 0 else 0.0,
            last_acc_ns=lm.acc_ns if lm else None,
        )
        return Status(
            schema=STATUS_SCHEMA_VERSION,
            station=self.station,
            t_host_ns=now_ns,
            session_id=self.session_id,
            link=link,
            sats=tuple(sats),
            ppk_ready=ready,
            tracked=tracked,
            half_cycle_fraction=round(half / tracked, 3) if tracked else 0.0,
            marks=marks,
            alerts=tuple(sorted(a.message for a in self.alerts.values())),
            recording=dict(self.recording),
        )
