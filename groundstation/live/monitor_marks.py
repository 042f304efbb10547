"""The monitor's time marks: counts, lost and duplicate marks, pulse width, several marks in one
epoch, marks that fall inside a link dropout.

Pairing, numbering, duplicates and lost marks are :class:`groundstation.rules.marks.MarkTracker`'s,
the rule RINEX, inspect and the solver apply to the recording.
"""

from __future__ import annotations

import bisect

from groundstation import events as kinds
from groundstation.config import MonitorSettings
from groundstation.gpstime import NS_PER_S
from groundstation.live.monitor_alerts import Alerts
from groundstation.live.monitor_link import LINK_HISTORY_NS, Link
from groundstation.records import Event, MarkStatus, TimeMark
from groundstation.rules.marks import (
    LOST_CAUSE_TEXT,
    LOST_ON_LINK,
    Mark,
    MarkTracker,
    count_jump,
    lost_cause,
    lost_times,
)

MAX_PULSE_MS = 10_000  # a longer "pulse" pairs edges of different exposures
EPOCH_SLOTS_KEPT = 4096


class Marks:
    """Mark state, fed with TIM-TM2 records and told of the link's measured gaps."""

    def __init__(self, th: MonitorSettings, alerts: Alerts, link: Link) -> None:
        self.th = th
        self.alerts = alerts
        self.link = link
        link.on_gap = self.on_gap
        self.rule = MarkTracker()
        self.last_mark: TimeMark | None = None
        self.recovered = 0
        self.in_dropout = 0
        self.multi_in_epoch = 0
        self._mark_times: list[int] = []  # falling-edge GPS ns, sorted
        self._epoch_slots: dict[int, int] = {}
        self.last_pulse_ms: float | None = None
        self._last_missed_ns: int | None = None
        self._missed_acked = 0  # rule.missed when the operator last acknowledged
        self._last_edge_ns: int | None = None  # the previous mark's time
        self.lost_on_link = 0
        self.not_reported = 0

    def on_mark(self, m: TimeMark, now_ns: int, events: list[Event]) -> None:
        if m.new_rising and m.rising_t_gps_ns is not None and m.falling_t_gps_ns is not None:
            width = (m.rising_t_gps_ns - m.falling_t_gps_ns) / 1e6
            if 0 <= width < MAX_PULSE_MS:
                self.last_pulse_ms = width
        up = self.rule.feed(m)
        if up.duplicate:  # the same exposure reported as new again
            events.append(Event(kinds.MARK_DUPLICATE, now_ns, f"duplicate time mark {m.count}",
                                "warning", {"count": m.count, "t_gps_ns": m.falling_t_gps_ns}))
        for mark in up.new:
            self._new_mark(m, mark, up.recovered, now_ns, events)

    def _new_mark(
        self, m: TimeMark, mark: Mark, recovered: bool, now_ns: int, events: list[Event]
    ) -> None:
        self.last_mark = m
        if recovered:
            self.recovered += 1
        jump = count_jump(mark)
        edge = mark.falling_t_gps_ns if mark.falling_t_gps_ns is not None else (
            mark.rising_t_gps_ns)
        if jump is not None:
            last, number = jump
            self._last_missed_ns = now_ns
            causes = [lost_cause(t, self._holes(edge), self.link.damage_times,
                                 self.link.interval_ns)
                      for t in lost_times(self._last_edge_ns, edge, mark.lost_before)]
            on_link = sum(c == LOST_ON_LINK for c in causes)
            self.lost_on_link += on_link
            self.not_reported += len(causes) - on_link
            cause = LOST_ON_LINK if on_link else next(iter(set(causes)), LOST_ON_LINK)
            events.append(Event(
                kinds.MARK_MISSED, now_ns, f"{mark.lost_before} time mark(s) "
                f"{LOST_CAUSE_TEXT[cause]} (count {last} -> {number})", "warning",
                {"from_count": last, "to_count": number, "missed": mark.lost_before,
                 "lost_on_link": on_link, "not_reported": len(causes) - on_link},
            ))
            unacked = self.rule.missed - self._missed_acked
            since = "since the last acknowledgement" if self._missed_acked else "this session"
            self.alerts.raise_(
                kinds.ALERT_MARKS_MISSED,
                f"{unacked} time mark(s) missed {since} (last: count {last} -> {number}); "
                "acknowledge to clear",
                now_ns, events, {"missed": self.rule.missed, "unacknowledged": unacked},
            )
        if edge is not None:
            self._last_edge_ns = edge
        ft = mark.falling_t_gps_ns
        if ft is None:
            return  # no exposure time to place among the epochs
        link = self.link
        bisect.insort(self._mark_times, ft)
        if link.last_epoch_ns is not None and self._mark_times[0] < (
            link.last_epoch_ns - LINK_HISTORY_NS
        ):  # only marks a gap still to be measured can fall into are needed
            del self._mark_times[: bisect.bisect_left(self._mark_times,
                                                     link.last_epoch_ns - LINK_HISTORY_NS)]
        if link.interval_ns:
            slot = ft // link.interval_ns
            n = self._epoch_slots.get(slot, 0) + 1
            self._epoch_slots[slot] = n
            if n == 2:
                self.multi_in_epoch += 1
            if len(self._epoch_slots) > EPOCH_SLOTS_KEPT:
                for k in sorted(self._epoch_slots)[: EPOCH_SLOTS_KEPT // 2]:
                    del self._epoch_slots[k]
        # A mark during an ongoing dropout, or inside an already measured one.
        if link.ongoing_dropout(now_ns) is not None and link.last_epoch_ns is not None and (
            ft > link.last_epoch_ns
        ):
            return  # decided when the dropout ends (on_gap)
        iv = link.interval_ns or 0
        for d in reversed(link.dropouts):
            if d.start_t_gps_ns - iv < ft < d.end_t_gps_ns + iv:
                self._mark_in_dropout(ft, now_ns, events)
                break

    def _holes(self, edge: int | None) -> list[tuple[int, int]]:
        """The holes in the received epochs so far (last before, first after), one still open
        included (no epoch since the last one, at this mark's time)."""
        link = self.link
        iv = link.interval_ns or 0
        holes = [(d.start_t_gps_ns - iv, d.end_t_gps_ns + iv) for d in link.dropouts]
        if (link.last_epoch_ns is not None and edge is not None
                and edge - link.last_epoch_ns > 1.5 * iv):
            holes.append((link.last_epoch_ns, 1 << 62))
        return holes

    def on_gap(self, prev: int, t: int, now_ns: int, events: list[Event]) -> None:
        """Marks already received whose exposure falls in a measured hole sit on an
        interpolation gap."""
        lo = bisect.bisect_right(self._mark_times, prev)
        hi = bisect.bisect_left(self._mark_times, t)
        for mt in self._mark_times[lo:hi]:
            self._mark_in_dropout(mt, now_ns, events)

    def _mark_in_dropout(self, ft: int, now_ns: int, events: list[Event]) -> None:
        self.in_dropout += 1
        events.append(Event(
            kinds.MARK_IN_DROPOUT, now_ns,
            "time mark inside a link dropout: its photo sits on an interpolation gap",
            "warning", {"t_gps_ns": ft},
        ))

    def evaluate(self, now_ns: int, events: list[Event]) -> None:
        """The missed-marks alert stays until the operator acknowledges it (an operator who
        looked away must still learn of it); with ``marks_missed_hold_s`` > 0 it also clears
        after that long without a new loss."""
        hold = self.th.marks_missed_hold_s
        if (hold > 0 and self._last_missed_ns is not None
                and now_ns - self._last_missed_ns >= hold * NS_PER_S):
            self.alerts.clear(kinds.ALERT_MARKS_MISSED, now_ns, events,
                              ok=f"no time mark missed for {hold:g} s")

    def acknowledge(self, alert: str, by: str, now_ns: int, events: list[Event]) -> None:
        """An operator's acknowledgement (``operator.ack``): clears the missed-marks alert; the
        next loss raises it again, counting from here."""
        if alert not in ("", kinds.ALERT_MARKS_MISSED):
            return
        acked = self.rule.missed - self._missed_acked
        self._missed_acked = self.rule.missed
        who = f" by {by}" if by else ""
        self.alerts.clear(kinds.ALERT_MARKS_MISSED, now_ns, events,
                          ok=f"{acked} missed time mark(s) acknowledged{who}")

    def status(self, t_last_ns: int) -> MarkStatus:
        lm = self.last_mark
        first = self.link.first_epoch_ns
        minutes = (t_last_ns - first) / 60e9 if first else 0.0
        return MarkStatus(
            marks=self.rule.marks,
            last_count=lm.count if lm else None,
            last_falling_t_gps_ns=lm.falling_t_gps_ns if lm else None,
            last_pulse_width_ms=self.last_pulse_ms,
            missed=self.rule.missed,
            duplicates=self.rule.duplicates,
            in_dropout=self.in_dropout,
            multi_in_epoch=self.multi_in_epoch,
            rate_per_min=self.rule.marks / minutes if minutes > 0 else 0.0,
            last_acc_ns=lm.acc_ns if lm else None,
            lost_on_link=self.lost_on_link,
            not_reported=self.not_reported,
        )
