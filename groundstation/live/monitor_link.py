"""The monitor's link: the epoch interval, dropouts (seen from the clock while they last, measured
exactly when data returns), byte and frame rates, damage, completeness, source outages, and bytes
that arrive without a valid frame among them.

The interval and the dropout rule are :mod:`groundstation.rules.epochs`'s, the same inspect, the
RINEX marks table and the solver apply to the recording.
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Callable

from groundstation import events as kinds
from groundstation.config import MonitorSettings
from groundstation.gpstime import NS_PER_S
from groundstation.live.monitor_alerts import Alerts
from groundstation.records import Dropout, Event, LinkStatus, RawEpoch
from groundstation.rules.epochs import interval_from_spacings, is_dropout, missing_epochs

RATE_WINDOW_NS = 5 * NS_PER_S
INTERVAL_HISTORY = 25
RECENT_DROPOUTS = 50
LINK_HISTORY_NS = 600 * NS_PER_S  # epochs kept for the completeness windows and the timeline
NO_FRAMES_MIN_BYTES = 64  # a few stray bytes after the last frame are no evidence of anything
NOISY_GARBAGE_SHARE = 0.5
"""Between two readings of the pipeline's counters (every status interval), bytes more than
half garbage are noise, whatever stray frame checked out among them; less, with frames, is
the link decoding (a damaged frame or two leave some garbage)."""

GapCallback = Callable[[int, int, int, list[Event]], None]
"""Called with (last epoch before, first epoch after, now_ns, events) for each measured gap."""


class Link:
    """Link state, fed with bytes, pipeline counters and epochs."""

    def __init__(self, th: MonitorSettings, alerts: Alerts) -> None:
        self.th = th
        self.alerts = alerts
        self.on_gap: GapCallback | None = None
        self.interval_ns: int | None = None
        self._diffs: deque[int] = deque(maxlen=INTERVAL_HISTORY)
        self._epoch_times: deque[int] = deque()  # GPS ns, for completeness windows
        self._epoch_host: deque[int] = deque()  # host ns of the same epochs
        self.epochs = 0
        self._epochs_before = 0  # epochs before the receiver's time last jumped
        self.first_epoch_ns: int | None = None
        self.last_epoch_ns: int | None = None
        self.last_epoch_host_ns: int | None = None
        self._early: list[int] = []  # epochs seen before the interval was known
        # the recent dropouts (a long session on a shared channel has thousands) and a count
        self.dropouts: deque[Dropout] = deque(maxlen=RECENT_DROPOUTS)
        # the last epoch before each stretch of damaged data seen (lost marks' causes)
        self.damage_times: deque[tuple[int, int]] = deque(maxlen=RECENT_DROPOUTS)
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
        self.implausible = 0  # frames whose time cannot belong to the session (the decoder's)
        self.source_connected: bool | None = None
        self.source_problem = ""  # why the source is down (the source.lost message)
        self.watch_since_ns: int | None = None  # the first clock tick: silence counts from here
        self.source_outages = 0
        self.nmea_sentences = 0
        self._frameless_since_ns: int | None = None  # first byte after the last frame progress
        self._frameless_bytes = 0
        self._frameless_nmea = 0
        # while no_frames is raised: since when the counters have shown frames decoding
        # without noise (it clears after no_frames_s of that, not at the first frame)
        self._decoding_since_ns: int | None = None
        self._bytes_at_counters = 0

    # -- bytes and frames -----------------------------------------------------------------

    def on_bytes(self, n: int, t_host_ns: int) -> None:
        self.bytes_in += n
        self.last_byte_ns = t_host_ns
        self._bytes.append((t_host_ns, n))
        if self._frameless_since_ns is None:
            self._frameless_since_ns = t_host_ns
        self._frameless_bytes += n

    def frames_progress(self, now_ns: int, events: list[Event]) -> None:
        """Valid frames arrived: no frameless span to time. A raised ``no_frames`` alert is
        not cleared here: one stray frame that checks out amid noise is not the link decoding
        again (:meth:`on_counters` and :meth:`check_frames` hold the clear)."""
        self._frameless_since_ns = None
        self._frameless_bytes = 0
        self._frameless_nmea = 0

    def on_damage(self) -> None:
        """Damaged data came after the last epoch (the pipeline's :class:`DamagedData`)."""
        if self.last_epoch_ns is not None:
            self.damage_times.append((self.last_epoch_ns, self.last_epoch_ns))

    def on_counters(
        self, bad_checksum: int, garbage_bytes: int, frames: int | None, nmea: int,
        connected: bool | None, now_ns: int, events: list[Event],
    ) -> None:
        """The pipeline's own counters (framer damage, frames, NMEA, source state)."""
        new_garbage = garbage_bytes - self.garbage
        new_bytes = self.bytes_in - self._bytes_at_counters
        self._bytes_at_counters = self.bytes_in
        self.damaged = bad_checksum
        self.garbage = garbage_bytes
        frames = self.frames if frames is None else frames
        new_frames = frames - self.frames
        if new_frames > 0:
            self.frames_progress(now_ns, events)
        self.frames = frames
        if kinds.ALERT_NO_FRAMES in self.alerts.active and new_bytes > 0:
            noisy = (new_garbage >= NO_FRAMES_MIN_BYTES
                     and new_garbage > NOISY_GARBAGE_SHARE * new_bytes)
            if noisy or new_frames <= 0:
                self._decoding_since_ns = None  # still (or again) noise: the hold restarts
            elif self._decoding_since_ns is None:
                self._decoding_since_ns = now_ns
        if self._frameless_since_ns is not None:
            self._frameless_nmea += max(0, nmea - self.nmea_sentences)
        self.nmea_sentences = nmea
        if connected is not None:
            self.source_connected = connected

    def on_source_event(self, kind: str, message: str = "") -> None:
        if kind == kinds.SOURCE_LOST:
            self.source_connected = False
            self.source_problem = message
        elif kind == kinds.SOURCE_CONNECTED:
            self.source_connected = True
        elif kind == kinds.SOURCE_OUTAGE:
            self.source_outages += 1
            self.source_connected = True

    def check_frames(self, now_ns: int, events: list[Event]) -> None:
        """Raise ``no_frames`` when bytes arrive for ``no_frames_s`` without one valid UBX
        frame among them; clear it once frames have been decoding without noise for
        ``no_frames_s`` (hysteresis: noise with a stray valid frame neither clears it nor
        raises it again)."""
        run = self._decoding_since_ns
        if run is not None and (now_ns - run) / NS_PER_S >= self.th.no_frames_s:
            self._decoding_since_ns = None
            self.alerts.clear(kinds.ALERT_NO_FRAMES, now_ns, events)
        if self._decoding_since_ns is not None:
            return  # decoding again, in the hold: a short frameless span is no new alert
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
        self.alerts.raise_(
            kinds.ALERT_NO_FRAMES,
            f"no valid frames for {span_s:.0f} s although {self._frameless_bytes} bytes "
            f"arrived: likely cause: {cause}",
            now_ns, events,
            {"bytes": self._frameless_bytes, "nmea_sentences": self._frameless_nmea,
             "likely_cause": "nmea_only" if self._frameless_nmea else "baud_or_noise"},
        )

    # -- epochs ---------------------------------------------------------------------------

    def on_epoch(self, ep: RawEpoch, now_ns: int, events: list[Event]) -> bool:
        """Take an epoch; False when it adds nothing (no time yet, a repeat, out of order)."""
        if ep.gps_week == 0:
            return False  # no time yet (cold start)
        t = ep.t_gps_ns
        self._frames.append((now_ns, 1))
        if self.last_epoch_ns is not None and t <= self.last_epoch_ns:
            return False  # a repeat (RXM-RAW and RXM-RAWX both enabled) or out of order
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
                self.interval_ns = interval_from_spacings(self._diffs)
            if self.interval_ns is not None:
                for a, b in zip(self._early, self._early[1:], strict=False):
                    self._check_gap(a, b, now_ns, events)
                self._early.clear()
        else:
            if len(self._diffs) == INTERVAL_HISTORY and self.epochs % INTERVAL_HISTORY == 0:
                self.interval_ns = interval_from_spacings(self._diffs) or self.interval_ns
            if prev is not None:
                self._check_gap(prev, t, now_ns, events)
        if self._ongoing_since_ns is not None:
            self._ongoing_since_ns = None
            self.alerts.clear(kinds.ALERT_DROPOUT_LONG, now_ns, events)
        return True

    def restart_epochs(self) -> None:
        """The receiver's time jumped (a ``decoder.time_jump`` event): the epoch sequence, its
        interval and the completeness windows start again with the next epoch. The counts of
        epochs, dropouts and missing epochs go on."""
        self.interval_ns = None
        self._diffs.clear()
        self._epoch_times.clear()
        self._epoch_host.clear()
        self._early.clear()
        self._epochs_before = self.epochs
        self.first_epoch_ns = None
        self.last_epoch_ns = None
        self.last_epoch_host_ns = None

    def _check_gap(self, prev: int, t: int, now_ns: int, events: list[Event]) -> None:
        assert self.interval_ns is not None
        d = t - prev
        if not is_dropout(d, self.interval_ns):
            return
        missing = missing_epochs(d, self.interval_ns)
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
            kinds.LINK_DROPOUT, now_ns,
            f"link dropout: {missing} epoch(s) missing ({drop.duration_s:.1f} s)",
            "warning",
            {"start_t_gps_ns": drop.start_t_gps_ns, "end_t_gps_ns": drop.end_t_gps_ns,
             "missing_epochs": missing, "duration_s": drop.duration_s},
        ))
        if self.on_gap is not None:
            self.on_gap(prev, t, now_ns, events)

    def ongoing_dropout(self, now_ns: int) -> Dropout | None:
        """The dropout under way (no epoch for longer than the interval allows), if any."""
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

    def evaluate(self, now_ns: int, events: list[Event]) -> None:
        """Alerts from elapsed time: a dropout under way, no data (also: :meth:`check_frames`)."""
        th = self.th
        ongoing = self.ongoing_dropout(now_ns)
        if ongoing is not None and self._ongoing_since_ns is None:
            self._ongoing_since_ns = now_ns
            events.append(Event(
                kinds.LINK_DROPOUT_STARTED, now_ns,
                "link dropout: no epoch since "
                f"{(now_ns - (self.last_epoch_host_ns or now_ns)) / 1e9:.1f} s",
                "warning", {"start_t_gps_ns": ongoing.start_t_gps_ns},
            ))
        if ongoing is not None and ongoing.duration_s >= th.dropout_alert_s:
            self.alerts.raise_(kinds.ALERT_DROPOUT_LONG,
                               f"link dropout longer than {th.dropout_alert_s:g} s", now_ns,
                               events, {"start_t_gps_ns": ongoing.start_t_gps_ns})
        if self.watch_since_ns is None:
            self.watch_since_ns = now_ns
        # Silence counts from the last byte, or from the start when none came yet: a source
        # that connects and never sends must not look alive.
        last = self.last_byte_ns if self.last_byte_ns is not None else self.watch_since_ns
        silent_s = (now_ns - last) / 1e9
        if silent_s >= th.no_data_s:
            since = ("since the start: nothing received yet" if self.last_byte_ns is None
                     else f"for {th.no_data_s:g} s or more")
            self.alerts.raise_(kinds.ALERT_NO_DATA, f"no data from the source {since}",
                               now_ns, events)
            alert = self.alerts.active[kinds.ALERT_NO_DATA]
            alert.message = f"no data from the source for {silent_s:.0f} s" + (
                " (nothing received since the start)" if self.last_byte_ns is None else "")
        else:
            self.alerts.clear(kinds.ALERT_NO_DATA, now_ns, events,
                              ok=f"data arriving again ({self.bytes_in:,} bytes so far)")

    # -- status ---------------------------------------------------------------------------

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
            got = self.epochs - self._epochs_before
        else:
            span = min(int(window_s * NS_PER_S), end - self.first_epoch_ns)
            start = end - span
            got = len(self._epoch_times) - bisect.bisect_left(list(self._epoch_times), start)
        expected = span // self.interval_ns + 1
        return min(1.0, got / expected) if expected else None

    def status(self, now_ns: int) -> LinkStatus:
        return LinkStatus(
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
            current_dropout=self.ongoing_dropout(now_ns),
            recent_dropouts=tuple(self.dropouts),
            source_connected=self.source_connected,
            source_outages=self.source_outages,
            implausible_frames=self.implausible,
        )
