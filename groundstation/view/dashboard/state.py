"""What the web dashboard knows about each station, folded from bus payloads (sans-I/O).

:class:`StationView` takes the daemon's payloads (status, events, time marks, session,
liveliness) with the receiving clock injected, and :meth:`StationView.snapshot` turns them into
the JSON document the page draws: the latest status plus a 10-minute link timeline (epochs
received against expected per bucket, dropouts, source outages, marks), the marks panel, the
PPK-readiness figures, alerts, recent events and the session.
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import quote

from groundstation import events as kinds
from groundstation import gpstime, messages
from groundstation.geodesy import ecef_to_llh, enu_rotation
from groundstation.storage.naming import session_start_ns
from groundstation.view.summary import (
    go_no_go_text,
    ppk_label,
    ppk_thresholds,
    session_finished,
    tracked_text,
    unidentified_text,
)

STALE_AFTER_S = 3.0
"""No status for longer than this and the station is shown as stale."""
DATA_RATE_STATUSES = 10
"""Statuses over which the pace of the daemon's data clock against the wall clock is measured."""
DATA_RATE_MIN_SPAN_S = 0.5
"""Below this much receiving time between them, statuses came in one burst: no pace measured."""
TIMELINE_SPAN_S = 600
TIMELINE_BUCKET_S = 5
EVENTS_KEPT = 40
DROPOUTS_KEPT = 1000
MARKS_KEPT = 3000
"""Up to 5 marks a second over the timeline span."""
LEAF_KINDS = {"status": "status", "q/status": "status", "event": "event",
              "timemark": "timemark", "q/timemarks": "timemark", "session": "session",
              "rtk": "rtk"}
"""Key leaf -> the message kind it must carry."""
NOT_SHOWN = frozenset({"ubx", "epoch", "alive", "obs"})
RTK_KEPT = 6000
"""Live positions kept for the track (20 min at 5 Hz)."""
RTK_TRACK_POINTS = 800
"""At most this many points of the track go to the page (every k-th, the latest always)."""
RTK_WINDOW = 300
"""Live positions the fixed share is counted over (60 s at 5 Hz)."""

NS = gpstime.NS_PER_S


@dataclass(frozen=True, slots=True)
class FileInfo:
    """What the local file system says about the recording (when the daemon is local)."""

    size_bytes: int | None
    disk_free_bytes: int | None
    disk_total_bytes: int | None


def no_file_info(_path: str) -> FileInfo:
    """The file-system probe for a remote daemon: nothing known."""
    return FileInfo(None, None, None)


@dataclass(slots=True)
class _Span:
    start_gps_ns: int
    end_gps_ns: int | None  # None: still going on
    missing_epochs: int = 0


@dataclass
class StationView:
    """The dashboard's state for one station. Not thread-safe: the server holds a lock.

    Attributes:
        station: station name.
        status: the latest status payload.
        status_rx_s: receiving monotonic time of that status.
        alive: liveliness of the daemon (None: never heard of it).
        session: the latest ``session`` payload.
        report: the latest ``solution`` payload with a report (status ok).
        version: bumped on every change (the server pushes when it moves).
    """

    station: str
    status: dict[str, Any] | None = None
    status_rx_s: float | None = None
    alive: bool | None = None
    session: dict[str, Any] | None = None
    report: dict[str, Any] | None = None
    version: int = 0
    events: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=EVENTS_KEPT))
    marks: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=MARKS_KEPT))
    """(falling_t_gps_ns, index) of received exposures (falling edges)."""
    marks_received: int = 0
    last_mark: dict[str, Any] | None = None
    _mark_indices: set[int] = field(default_factory=set)
    _mark_times: set[int] = field(default_factory=set)
    session_changed: bool = False
    """Set when a status names a new session (the hub then fetches its marks again)."""
    _dropouts_since_status: list[int] = field(default_factory=lambda: [0, 0])
    """Dropouts and missing epochs reported by events after the latest status."""
    marks_in_dropout: set[int] = field(default_factory=set)
    dropouts: dict[int, _Span] = field(default_factory=dict)
    """Closed dropouts by first missing epoch (from status and ``link.dropout`` events)."""
    pending_dropout_gps_ns: int | None = None
    """Start of a dropout announced by ``link.dropout_started``, not yet in a status."""
    outages: list[_Span] = field(default_factory=list)
    """Source outages (host times mapped to GPS time through ``host_minus_gps_ns``)."""
    host_minus_gps_ns: int | None = None
    _offsets: deque[int] = field(default_factory=lambda: deque(maxlen=20))
    _data_clock: deque[tuple[float, int]] = field(
        default_factory=lambda: deque(maxlen=DATA_RATE_STATUSES))
    """(receiving time, data time) of the latest statuses: how fast the daemon's clock runs
    against ours (1 live; N for a ``replay --speed N``, which runs on the recording's time)."""
    _session_id: str | None = None
    instances: set[str] = field(default_factory=set)
    """Liveliness ids of the daemons alive for this station (more than one: a conflict)."""
    rejected: int = 0
    """Payloads dropped as bad (:mod:`groundstation.messages`): counted, shown, never fatal."""
    last_rejection: str = ""
    rtk: dict[str, Any] | None = None
    """The latest live position (``.../rtk``)."""
    rtk_track: deque[tuple[int, float, float, str]] = field(
        default_factory=lambda: deque(maxlen=RTK_KEPT))
    """(GPS ns, east, north, quality) of the live positions, metres from the first one."""
    rtk_qualities: deque[str] = field(default_factory=lambda: deque(maxlen=RTK_WINDOW))
    _rtk_origin: tuple[float, float, float] | None = None
    _rtk_rotation: tuple[tuple[float, float, float], ...] = ()

    # -- folding ---------------------------------------------------------------------------

    def on_payload(self, key_expr: str, payload: bytes, now_s: float) -> bool:
        """Fold one bus payload; True if it changed the view (a bad one is counted in
        :attr:`rejected`, which changes the view too)."""
        leaf = key_expr.split("/", 2)[-1]
        if leaf in NOT_SHOWN:
            return False
        expected = LEAF_KINDS.get(leaf)  # None (a key the hub does not subscribe): any kind
        try:
            msg = messages.parse(payload, expected)
        except messages.BadMessage as err:
            self.rejected += 1
            self.last_rejection = f"{leaf}: {err}"[:200]
            self.version += 1
            return True
        kind = msg.get("type")
        if kind == "status":
            self._on_status(msg, now_s)
        elif kind == "event":
            self._on_event(msg)
        elif kind == "timemark":
            self._on_mark(msg)
        elif kind == "session":
            self.session = msg
        elif kind == "rtk":
            self._on_rtk(msg)
        elif kind == "solution":
            if msg.get("status") != "ok" or not isinstance(msg.get("report"), str):
                return False
            self.report = msg  # the latest solved recording's report
        else:
            return False
        self.version += 1
        return True

    def on_alive(self, alive: bool, instance: str = "") -> None:
        """A daemon's liveliness token (``alive/<instance>``) appeared or went away; two at
        once are two daemons claiming this station (a ``station_conflict`` alert)."""
        if alive:
            self.instances.add(instance)
        else:
            self.instances.discard(instance)
        self.alive = bool(self.instances)
        self.version += 1

    def conflict_alert(self) -> str | None:
        """The dashboard's own alert when more than one daemon claims the station."""
        n = len(self.instances)
        if n < 2:
            return None
        return (f"station_conflict: {n} daemons publish as station {self.station!r}; "
                "what is shown mixes them")

    def finished(self) -> bool:
        """The daemon said the session its status is about has finished (no more data will
        come for it: the view reads "finished", its alerts are those at the end)."""
        return session_finished(self.status, self.session)

    def _reset_session(self, session_id: str) -> None:
        """A new daemon session: what belonged to the previous one goes."""
        self._session_id = session_id
        self.session_changed = True
        self.session = None  # the previous daemon's "finished"
        self.rtk, self._rtk_origin = None, None  # the previous flight's live track
        self.rtk_track.clear()
        self.rtk_qualities.clear()
        self.marks.clear()
        self._mark_indices.clear()
        self._mark_times.clear()
        self.marks_received = 0
        self.last_mark = None
        self.marks_in_dropout.clear()
        self.dropouts.clear()
        self.pending_dropout_gps_ns = None
        self.outages.clear()
        # the previous session's clock: a replay of an older recording runs on older times
        self._offsets.clear()
        self.host_minus_gps_ns = None
        self._data_clock.clear()

    def _on_status(self, msg: dict[str, Any], now_s: float) -> None:
        sid = msg.get("session_id")
        if isinstance(sid, str) and sid != self._session_id:
            if self._session_id is not None:
                self._reset_session(sid)
            self._session_id = sid
        self.status = msg
        self.status_rx_s = now_s
        self._dropouts_since_status = [0, 0]
        link = msg.get("link") or {}
        last = link.get("last_epoch_t_gps_ns")
        t_host = msg.get("t_host_ns")
        if isinstance(last, int) and isinstance(t_host, int) and not link.get("current_dropout"):
            self._offsets.append(t_host - last)
            self.host_minus_gps_ns = min(self._offsets)  # the least delayed reception
        if isinstance(t_host, int):
            self._data_clock.append((now_s, t_host))
        for d in link.get("recent_dropouts") or []:
            self._add_dropout(d)
        pending = self.pending_dropout_gps_ns
        if pending is not None and isinstance(last, int) and last >= pending:
            self.pending_dropout_gps_ns = None  # data came back; the dropout is closed
        if link.get("source_connected") is False and not self._outage_open():
            start = self._host_to_gps(int(t_host)) if isinstance(t_host, int) else None
            if start is not None:
                self.outages.append(_Span(start, None))

    def _add_dropout(self, d: dict[str, Any]) -> None:
        start, end = d.get("start_t_gps_ns"), d.get("end_t_gps_ns")
        if isinstance(start, int) and isinstance(end, int):
            self.dropouts[start] = _Span(start, end, int(d.get("missing_epochs") or 0))
            if len(self.dropouts) > DROPOUTS_KEPT:  # a flaky link: keep the newest
                for old in sorted(self.dropouts)[: len(self.dropouts) - DROPOUTS_KEPT]:
                    del self.dropouts[old]

    def _outage_open(self) -> bool:
        return bool(self.outages) and self.outages[-1].end_gps_ns is None

    def _host_to_gps(self, t_host_ns: int) -> int | None:
        if self.host_minus_gps_ns is None:
            return None
        return t_host_ns - self.host_minus_gps_ns

    def _on_event(self, msg: dict[str, Any]) -> None:
        self.events.append(msg)
        kind = msg.get("kind")
        data = msg.get("data") or {}
        if kind == kinds.LINK_DROPOUT_STARTED:
            start = data.get("start_t_gps_ns")
            if isinstance(start, int):
                self.pending_dropout_gps_ns = start
        elif kind == kinds.LINK_DROPOUT:
            if data.get("start_t_gps_ns") not in self.dropouts:
                self._dropouts_since_status[0] += 1
                self._dropouts_since_status[1] += int(data.get("missing_epochs") or 0)
            self._add_dropout(data)
            self.pending_dropout_gps_ns = None
        elif kind == kinds.MARK_IN_DROPOUT:
            t = data.get("t_gps_ns")
            if isinstance(t, int):
                self.marks_in_dropout.add(t)
        elif kind == kinds.SOURCE_LOST:
            start = data.get("start_ns")
            gps = self._host_to_gps(int(start)) if isinstance(start, int) else None
            if gps is not None and not self._outage_open():
                self.outages.append(_Span(gps, None))
        elif kind == kinds.SOURCE_OUTAGE:
            start, end = data.get("start_ns"), data.get("end_ns")
            a = self._host_to_gps(int(start)) if isinstance(start, int) else None
            b = self._host_to_gps(int(end)) if isinstance(end, int) else None
            if a is not None and b is not None:
                if self._outage_open():
                    self.outages[-1] = _Span(a, b)
                else:
                    self.outages.append(_Span(a, b))
        elif kind == kinds.SOURCE_CONNECTED and self._outage_open():
            t = msg.get("t_host_ns")
            gps = self._host_to_gps(int(t)) if isinstance(t, int) else None
            self.outages[-1].end_gps_ns = gps if gps is not None else self.outages[-1].start_gps_ns

    def _on_rtk(self, msg: dict[str, Any]) -> None:
        self.rtk = msg
        q = str(msg.get("quality"))
        self.rtk_qualities.append(q)
        xyz = msg.get("ecef_m")
        if not isinstance(xyz, list) or len(xyz) != 3:
            return
        if self._rtk_origin is None:  # the track's origin and its east/north/up, once
            self._rtk_origin = (float(xyz[0]), float(xyz[1]), float(xyz[2]))
            lat, lon, _ = ecef_to_llh(*self._rtk_origin)
            self._rtk_rotation = enu_rotation(lat, lon)
        o, r = self._rtk_origin, self._rtk_rotation
        d = [float(xyz[i]) - o[i] for i in range(3)]
        east = sum(r[0][i] * d[i] for i in range(3))
        north = sum(r[1][i] * d[i] for i in range(3))
        self.rtk_track.append((int(msg["t_gps_ns"]), round(east, 2), round(north, 2), q))

    def _rtk_panel(self) -> dict[str, Any] | None:
        """The live position: the latest message, the fixed share of the last minute, the track
        (east/north metres, quality) and where each mark fell on it, with the quality there."""
        if self.rtk is None:
            return None
        track = list(self.rtk_track)
        step = max(1, len(track) // RTK_TRACK_POINTS)
        shown = track[::step] + ([track[-1]] if track and (len(track) - 1) % step else [])
        times = [t for t, *_ in track]
        marks = []
        for t, _ in self.marks:
            i = bisect.bisect_left(times, t)
            near = [j for j in (i - 1, i) if 0 <= j < len(track)]
            if near:
                j = min(near, key=lambda k: abs(times[k] - t))
                if abs(times[j] - t) <= NS:  # within a second of a live position
                    marks.append([track[j][1], track[j][2], track[j][3]])
        recent = list(self.rtk_qualities)
        return {"latest": self.rtk,
                "fixed_share": (sum(q == "fix" for q in recent) / len(recent)
                                if recent else None),
                "window_s": len(recent) / 5,
                "track": [[e, n, q] for _, e, n, q in shown], "marks": marks}

    def _on_mark(self, msg: dict[str, Any]) -> None:
        idx = msg.get("index")
        idx = idx if isinstance(idx, int) else -1
        if idx >= 0:
            if idx in self._mark_indices:
                return  # the queryable and the subscription overlap
            self._mark_indices.add(idx)
        self.last_mark = msg
        # One exposure may come as two TIM-TM2 (falling edge, then rising edge): count edges.
        t = msg.get("falling_t_gps_ns")
        if isinstance(t, int) and t not in self._mark_times:
            self._mark_times.add(t)
            self.marks.append((t, idx))
            self.marks_received += 1

    # -- reading -------------------------------------------------------------------------------

    def stale(self, now_s: float) -> bool:
        """No status yet, or none for more than :data:`STALE_AFTER_S`."""
        return self.status_rx_s is None or now_s - self.status_rx_s > STALE_AFTER_S

    def status_age_s(self, now_s: float) -> float | None:
        return None if self.status_rx_s is None else max(0.0, now_s - self.status_rx_s)

    def data_rate(self) -> float:
        """How many seconds of the daemon's data time pass per second here: 1 for a live
        daemon, N for ``replay --speed N`` (its monitor runs on the recording's times);
        measured over the latest statuses, 1 until they span :data:`DATA_RATE_MIN_SPAN_S`."""
        if len(self._data_clock) < 2:
            return 1.0
        (rx0, t0), (rx1, t1) = self._data_clock[0], self._data_clock[-1]
        if rx1 - rx0 < DATA_RATE_MIN_SPAN_S or t1 <= t0:
            return 1.0
        rate = (t1 - t0) / NS / (rx1 - rx0)
        return 1.0 if 0.8 <= rate <= 1.25 else rate  # live: reception jitter, not a pace

    def gps_now_ns(self, now_s: float) -> int | None:
        """GPS time at ``now_s`` on the daemon's data clock, from the latest status.

        Between statuses it runs on the local monotonic clock at the data clock's pace
        (:meth:`data_rate`), at most :data:`STALE_AFTER_S` of data time beyond the status, so
        that a dead daemon's timeline stops moving instead of filling with gaps. It is never
        before the newest time mark of the session (a mark arrives before the next status:
        its age is 0, not negative).
        """
        st = self.status
        if st is None or self.status_rx_s is None:
            return None
        link = st.get("link") or {}
        last = link.get("last_epoch_t_gps_ns")
        t_host = st.get("t_host_ns")
        if self.host_minus_gps_ns is not None and isinstance(t_host, int):
            at_status = t_host - self.host_minus_gps_ns
        elif isinstance(last, int):
            at_status = last
        else:
            return None
        ahead = min(max(0.0, now_s - self.status_rx_s) * self.data_rate(), STALE_AFTER_S)
        now = at_status + int(ahead * NS)
        newest_mark = self.marks[-1][0] if self.marks else None
        return now if newest_mark is None else max(now, newest_mark)

    def snapshot(
        self, now_s: float, *, file_info: Callable[[str], FileInfo] = no_file_info,
        ppk_ready_min: int | None = None,
    ) -> dict[str, Any]:
        """The JSON document the page draws for this station.

        ``ppk_ready_min`` overrides the daemon's threshold (which its status carries) for the
        gauge's green line."""
        st = self.status or {}
        need, clean_s = ppk_thresholds(st.get("ppk_ready_min"), st.get("ppk_clean_phase_s"))
        link = dict(st.get("link") or {})
        # dropouts closed since the status (its current_dropout is then history)
        more, missing = self._dropouts_since_status
        if more:
            link["dropouts"] = int(link.get("dropouts") or 0) + more
            link["missing_epochs"] = int(link.get("missing_epochs") or 0) + missing
            link["current_dropout"] = None
        gps_now = self.gps_now_ns(now_s)
        interval = link.get("epoch_interval_s")
        out: dict[str, Any] = {
            "station": self.station,
            "has_status": self.status is not None,
            "stale": self.stale(now_s),
            "status_age_s": self.status_age_s(now_s),
            "alive": self.alive,
            "finished": self.finished(),
            "rejected": self.rejected,
            "last_rejection": self.last_rejection,
            "session_id": st.get("session_id"),
            "t_host_ns": st.get("t_host_ns"),
            "link": link,
            "rate_hz": round(1 / interval, 2) if interval else None,
            "sats": st.get("sats") or [],
            "ppk": {
                "ready": st.get("ppk_ready"), "tracked": st.get("tracked"),
                "tracked_text": tracked_text(st),
                "unidentified_text": unidentified_text(st.get("unidentified")),
                "min": need if ppk_ready_min is None else ppk_ready_min,
                "clean_phase_s": clean_s, "label": ppk_label(clean_s),
                "half_cycle_fraction": st.get("half_cycle_fraction"),
            },
            "alerts": self._alerts(st),
            "events": list(self.events)[-15:][::-1],
            "timeline": self.timeline(gps_now),
            "marks": self._marks_panel(st, gps_now),
            "data_clock": self.data_clock(gps_now),
            "session": self._session_panel(st, file_info),
            "report": self._report_panel(),
            "rtk": self._rtk_panel(),
        }
        return out

    def data_clock(self, gps_now: int | None) -> dict[str, Any] | None:
        """The data's own time now (the receiver's, on the daemon's data clock): ``utc`` as
        the header shows it and ``unix_ms``, which the page compares with the computer's
        clock (a replay or a simulated flight runs hours or years apart from it). None before
        the first epoch."""
        if gps_now is None:
            return None
        return {"utc": gpstime.gps_to_datetime(gps_now).strftime("%H:%M:%S"),
                "unix_ms": gpstime.gps_to_unix_ns(gps_now) // 1_000_000}

    def _alerts(self, st: dict[str, Any]) -> list[str]:
        alerts = [str(a) for a in st.get("alerts") or []]
        own = self.conflict_alert()
        if own is not None and not any(a.startswith("station_conflict") for a in alerts):
            alerts.insert(0, own)
        return alerts

    def _marks_panel(self, st: dict[str, Any], gps_now: int | None) -> dict[str, Any]:
        ms = dict(st.get("marks") or {})
        last_t = ms.get("last_falling_t_gps_ns")
        lm = self.last_mark
        if lm is not None:
            t = lm.get("falling_t_gps_ns")
            if isinstance(t, int) and (not isinstance(last_t, int) or t > last_t):
                last_t = t  # the time mark arrives before the next status
                ms["last_count"] = lm.get("count")
        ms["received"] = self.marks_received
        ms["last_t_gps_ns"] = last_t
        ms["last_utc"] = (gpstime.gps_to_datetime(last_t).strftime("%H:%M:%S.%f")[:-3]
                          if isinstance(last_t, int) else None)
        ms["last_age_s"] = (round(max(0, gps_now - last_t) / NS, 1)
                            if isinstance(last_t, int) and gps_now is not None else None)
        return ms

    def _report_panel(self) -> dict[str, Any] | None:
        """The latest report the solver announced (served by the dashboard at ``/report``)."""
        r = self.report
        if r is None:
            return None
        flight = str(r.get("flight") or "")
        go = r.get("go_no_go")
        verdict = None
        if isinstance(go, dict):
            try:
                verdict = {"ok": go.get("fixed") == go.get("marks") and bool(go.get("marks")),
                           "text": go_no_go_text(go)}
            except (TypeError, ValueError, KeyError, OverflowError):
                verdict = None  # a message the page cannot put in words: the link stays
        return {"url": "/report?station=" + quote(self.station), "flight": flight.split("/")[-1],
                "pdf": bool(r.get("report_pdf")), "t_host_ns": r.get("t_host_ns"),
                "verdict": verdict}

    def _session_panel(
        self, st: dict[str, Any], file_info: Callable[[str], FileInfo]
    ) -> dict[str, Any]:
        rec = st.get("recording") or {}
        sess = self.session or {}
        if st.get("session_id") and sess.get("session_id") not in (None, st.get("session_id")):
            sess = {}  # about another session than the status
        files = [str(f) for f in sess.get("files") or []]
        path = rec.get("file") or (files[-1] if files else None)
        sid = st.get("session_id") or sess.get("session_id")
        started = _session_start_unix_ns(sid) if isinstance(sid, str) else None
        t_host = st.get("t_host_ns")
        info = file_info(str(path)) if path else no_file_info("")
        return {
            "id": sid,
            "file": path,
            "state": sess.get("state") or ("recording" if path else None),
            "duration_s": ((t_host - started) / NS
                           if isinstance(t_host, int) and started is not None else None),
            "bytes_in": (st.get("link") or {}).get("bytes_in"),
            "size_bytes": rec.get("bytes", info.size_bytes),
            "disk_free_bytes": info.disk_free_bytes,
            "disk_total_bytes": info.disk_total_bytes,
        }

    def timeline(
        self, gps_now: int | None, span_s: int = TIMELINE_SPAN_S,
        bucket_s: int = TIMELINE_BUCKET_S,
    ) -> dict[str, Any]:
        """The last ``span_s`` of the link, in GPS time, as offsets in seconds from its start.

        ``buckets``: per ``bucket_s`` the epochs expected (after the first epoch, at the learned
        rate) and received (expected minus those inside dropouts); ``dropouts``, ``outages``:
        ``[start_s, end_s, ...]``; ``marks``: ``[t_s, in_dropout]``.
        """
        link = (self.status or {}).get("link") or {}
        first = link.get("first_epoch_t_gps_ns")
        interval_s = link.get("epoch_interval_s")
        n = span_s // bucket_s
        empty: dict[str, Any] = {"span_s": span_s, "bucket_s": bucket_s, "start_t_gps_ns": None,
                 "first_s": None, "now_s": None, "buckets": [], "dropouts": [],
                 "outages": [], "marks": []}
        if gps_now is None or not isinstance(first, int) or not interval_s:
            return empty
        interval = round(interval_s * NS)
        start = gps_now - span_s * NS
        # Align the buckets to the session grid so they do not shimmer as time moves.
        start -= (start - first) % (bucket_s * NS)

        def rel(t: int) -> float:
            return round((t - start) / NS, 3)

        drops: list[tuple[int, int, bool, int]] = []  # start, end (inclusive slots), ongoing
        for d in self.dropouts.values():
            if d.end_gps_ns is not None and d.end_gps_ns >= start:
                drops.append((d.start_gps_ns, d.end_gps_ns, False, d.missing_epochs))
        cur = link.get("current_dropout")
        ongoing_start = self.pending_dropout_gps_ns
        if isinstance(cur, dict) and isinstance(cur.get("start_t_gps_ns"), int):
            ongoing_start = (cur["start_t_gps_ns"] if ongoing_start is None
                             else min(ongoing_start, cur["start_t_gps_ns"]))
        if ongoing_start is not None and ongoing_start not in self.dropouts:
            end = max(ongoing_start, gps_now - interval)
            drops.append((ongoing_start, end, True, (end - ongoing_start) // interval + 1))
        drops.sort()

        last_epoch = link.get("last_epoch_t_gps_ns")
        data_end = gps_now if ongoing_start is not None else (
            last_epoch if isinstance(last_epoch, int) else gps_now)
        buckets = []
        for i in range(n + 1):
            a = start + i * bucket_s * NS
            b = a + bucket_s * NS
            expected = _slots(first, interval, max(a, first), min(b, data_end + 1))
            missing = sum(_slots(first, interval, max(a, ds), min(b, de + 1))
                          for ds, de, _, _ in drops)
            buckets.append([expected, max(0, expected - missing)])
        outages = [[rel(max(o.start_gps_ns, start)),
                    rel(o.end_gps_ns if o.end_gps_ns is not None else gps_now),
                    o.end_gps_ns is None]
                   for o in self.outages
                   if (o.end_gps_ns is None or o.end_gps_ns >= start)]
        marks = [[rel(t), t in self.marks_in_dropout] for t, _ in self.marks if t >= start]
        return {
            "span_s": span_s, "bucket_s": bucket_s, "start_t_gps_ns": start,
            "first_s": rel(first), "now_s": rel(gps_now), "buckets": buckets,
            "dropouts": [[rel(max(ds, start)), rel(de + interval), ongoing, missing]
                         for ds, de, ongoing, missing in drops],
            "outages": outages, "marks": marks,
        }


def _slots(first: int, interval: int, a: int, b: int) -> int:
    """Epoch slots ``first + k*interval`` (k >= 0) in ``[a, b)``."""
    if b <= a:
        return 0
    k0 = max(0, -(-(a - first) // interval))
    k1 = max(0, -(-(b - first) // interval))
    return max(0, k1 - k0)


def _session_start_unix_ns(session_id: str) -> int | None:
    """Session ids carry the UTC start second (``storage/naming.py`` owns the format)."""
    return session_start_ns(session_id)
