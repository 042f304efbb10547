"""The live terminal view of a station, fed only by Zenoh: link, satellites, marks, alerts.

:class:`WatchState` folds bus payloads (status, events, time marks) into what is shown;
:func:`render` turns it into a rich renderable; :func:`run_watch` subscribes and refreshes.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from groundstation import gpstime, messages
from groundstation.bus import Bus, key
from groundstation.config import Settings, ZenohSettings
from groundstation.view.summary import (
    ppk_label,
    ppk_thresholds,
    session_finished,
    tracked_text,
    unidentified_text,
)

DEFAULT_STATION = str(next(f.default for f in fields(Settings) if f.name == "station"))
"""The station name when none is configured (the daemon's, so watch finds it)."""
STALE_AFTER_S = 3.0
TIMELINE_S = 300
TIMELINE_COLS = 60

STATE_STYLE = {
    "clean": "bold green",
    "half_cycle": "bold yellow",
    "slipped": "bold red",
    "code_only": "dim",
}


SHOWN = {"status": "status", "q/status": "status", "timemark": "timemark",
         "q/timemarks": "timemark", "event": "event", "session": "session", "rtk": "rtk"}
"""Key leaf -> the message kind it carries, for what this view shows."""
RTK_WINDOW = 300
"""Live positions the fixed share is counted over (60 s at 5 Hz)."""
SESSION_MARK_LEAD_NS = 10 * 1_000_000_000
"""A time mark arrives before the status that counts it: at most this far after its epochs."""


@dataclass
class WatchState:
    """What the view knows, updated from bus payloads (thread-safe through ``lock``)."""

    station: str
    status: dict[str, Any] | None = None
    status_rx_s: float | None = None
    marks: list[dict[str, Any]] = field(default_factory=list)
    events: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=8))
    session: dict[str, Any] | None = None
    alive: bool | None = None
    received: int = 0
    instances: set[str] = field(default_factory=set)
    rejected: int = 0
    """Payloads dropped: not a valid message (:mod:`groundstation.messages`), or a status the
    screen cannot show."""
    last_rejection: str = ""
    rtk: dict[str, Any] | None = None
    """The latest live position (``groundstation rtk`` or the demo's engine)."""
    rtk_qualities: deque[str] = field(default_factory=lambda: deque(maxlen=RTK_WINDOW))
    lock: threading.Lock = field(default_factory=threading.Lock)

    def _reject(self, key_expr: str, why: str) -> None:
        with self.lock:
            self.rejected += 1
            self.last_rejection = f"{key_expr}: {why}"[:200]

    def on_payload(self, key_expr: str, payload: bytes, now_s: float | None = None) -> None:
        """Fold one payload; a bad one is counted in :attr:`rejected` and dropped."""
        expected = SHOWN.get(key_expr.split("/", 2)[-1])
        if expected is None:
            return  # epochs, raw UBX, solutions: not shown here
        try:
            msg = messages.parse(payload, expected)
        except messages.BadMessage as err:
            self._reject(key_expr, str(err))
            return
        kind = msg.get("type")
        if kind in ("status", "event"):
            try:  # one the screen cannot draw would stop the view at its next refresh
                _draw(_status_body(msg, [], [], None, None, stale=False) if kind == "status"
                      else event_line(msg))
            except Exception as err:
                self._reject(key_expr, f"{kind} not drawable: {type(err).__name__}: {err}")
                return
        now_s = time.monotonic() if now_s is None else now_s
        with self.lock:
            self.received += 1
            if kind == "status":
                self._new_session(msg)
                self.status = msg
                self.status_rx_s = now_s
            elif kind == "timemark":
                self._add_mark(msg)
            elif kind == "event":
                self.events.append(msg)
            elif kind == "session":
                self.session = msg
            elif kind == "rtk":
                self.rtk = msg
                self.rtk_qualities.append(str(msg.get("quality")))

    def _new_session(self, status: dict[str, Any]) -> None:
        """A status naming another session (a restarted daemon, the next ``replay``): the
        previous session's marks and its "finished" go. Marks that came just before this
        first status and lie within its epochs are the new session's own: they stay."""
        sid = status.get("session_id")
        old = self.status.get("session_id") if self.status is not None else None
        if self.status is None or sid == old:
            return
        link = status.get("link") or {}
        first, last = link.get("first_epoch_t_gps_ns"), link.get("last_epoch_t_gps_ns")

        def ours(m: dict[str, Any]) -> bool:
            t = m.get("falling_t_gps_ns")
            return (isinstance(t, int) and isinstance(first, int) and isinstance(last, int)
                    and first <= t <= last + SESSION_MARK_LEAD_NS)

        self.marks = [m for m in self.marks if ours(m)]
        self.session = None

    def _add_mark(self, msg: dict[str, Any]) -> None:
        idx, t = msg.get("index"), msg.get("falling_t_gps_ns")
        if isinstance(idx, int) and any(m.get("index") == idx and m.get("falling_t_gps_ns") == t
                                        for m in self.marks[-50:]):
            return  # already had it (queryable and subscription overlap); the same index at
            # another time is the next session's mark, come before its first status
        self.marks.append(msg)

    def on_alive(self, key_expr: str, alive: bool) -> None:
        """A daemon's token ``.../alive/<id>``: more than one alive is a station conflict."""
        instance = key_expr.split("/alive", 1)[-1].lstrip("/")
        with self.lock:
            if alive:
                self.instances.add(instance)
            else:
                self.instances.discard(instance)
            self.alive = bool(self.instances)

    def stale(self, now_s: float | None = None) -> bool:
        now_s = time.monotonic() if now_s is None else now_s
        return self.status_rx_s is None or now_s - self.status_rx_s > STALE_AFTER_S


def _bar(value: float, lo: float, hi: float, width: int = 12) -> str:
    frac = min(1.0, max(0.0, (value - lo) / (hi - lo)))
    full = int(frac * width)
    return "█" * full + "░" * (width - full)


def _fmt(v: Any, spec: str = "", none: str = "-") -> str:
    return none if v is None else format(v, spec)


def timeline(link: dict[str, Any], cols: int = TIMELINE_COLS, span_s: int = TIMELINE_S) -> Text:
    """One character per ``span_s/cols`` seconds: green received, red a dropout in it, blank
    before the session started."""
    last = link.get("last_epoch_t_gps_ns")
    first = link.get("first_epoch_t_gps_ns") or last
    text = Text()
    if last is None:
        return Text("no epochs yet", style="dim")
    bucket_ns = span_s * 1_000_000_000 // cols
    start = last - span_s * 1_000_000_000
    bad = [0] * cols
    drops = list(link.get("recent_dropouts") or [])
    if link.get("current_dropout"):
        drops.append(link["current_dropout"])
    for d in drops:
        a = max(d["start_t_gps_ns"], start)
        b = min(d["end_t_gps_ns"], last + bucket_ns)
        if b < start:
            continue
        for i in range((a - start) // bucket_ns, min(cols, (b - start) // bucket_ns + 1)):
            if 0 <= i < cols:
                bad[i] += 1
    for i, b in enumerate(bad):
        if start + (i + 1) * bucket_ns <= first:
            text.append("·", style="dim")
        else:
            text.append("▇" if not b else "▁", style="green" if not b else "bold red")
    return text


def event_line(e: dict[str, Any]) -> Text:
    """One event as the EVENTS panel shows it. Any value may be ``null`` (``messages.py``
    allows it for every field): an event without a host time shows ``--:--:--``."""
    t = e.get("t_host_ns")
    when = (time.strftime("%H:%M:%S", time.localtime(t / 1e9)) if isinstance(t, int)
            else "--:--:--")
    return Text(f"{when} {e.get('kind') or '?':<22} {e.get('message') or ''}\n",
                style="yellow" if e.get("severity") == "warning" else "")


def _draw(renderable: RenderableType) -> None:
    """Render off screen (a trial: rich builds lazily, so a bad value fails only here)."""
    import io

    Console(file=io.StringIO(), width=120, color_system=None).print(renderable)


def render(state: WatchState, now_s: float | None = None) -> RenderableType:
    """The whole screen for the current state."""
    with state.lock:
        st = state.status
        stale = state.stale(now_s)
        marks = list(state.marks)
        events = list(state.events)
        session = state.session
        alive = state.alive
        rejected, why = state.rejected, state.last_rejection
        daemons = len(state.instances)
        rtk, rtk_q = state.rtk, list(state.rtk_qualities)
    title = Text(f"groundstation watch · {station_label(state.station)}", style="bold")
    if st is None:
        msg = "waiting for status on " + key(state.station, "status")
        body: RenderableType = Text(msg, style="yellow")
    else:
        body = _status_body(st, marks, events, session, alive, stale=stale)
    standing = (st or {}).get("alerts") or []
    if daemons > 1 and not any(str(a).startswith("station_conflict") for a in standing):
        # (the daemons' own station_conflict alert, when it is in ALERTS, says it already)
        body = Group(Text(f" station_conflict: {daemons} daemons publish as station "
                          f"{state.station!r} ", style="bold white on red"), body)
    if rtk is not None:
        body = Group(body, rtk_line(rtk, rtk_q))
    if rejected:
        body = Group(body, Text(f"{rejected} bad messages dropped (last: {why})",
                                style="bold yellow"))
    if st is None:
        return Panel(body, title=title)
    alerts = st.get("alerts") or []
    border = ("cyan" if session_finished(st, session) else "red" if stale or alerts else "green")
    return Panel(body, title=title, border_style=border)


RTK_STYLE = {"fix": "bold green", "float": "bold yellow", "dgps": "yellow", "single": "red",
             "none": "dim"}


def rtk_line(msg: dict[str, Any], recent: list[str]) -> Text:
    """The live position in one line: quality, its share over the last minute, ratio,
    satellites, base age, sigma; the operator's alert when the fix is lost during photos."""
    q = str(msg.get("quality"))
    line = Text(" live RTK ")
    line.append(f" {q} ", style=RTK_STYLE.get(q, "dim"))
    if recent:
        line.append(f"  fixed {sum(r == 'fix' for r in recent) / len(recent):.0%} of the last "
                    f"{len(recent) / 5:.0f} s")
    if q == "none":
        line.append(f"  ({msg.get('why') or 'no position'})", style="dim")
    else:
        age = msg.get("age_s")
        ratio = float(msg.get("ratio") or 0)
        # fix-and-hold says 999.9; 0: no ambiguity resolution tried at this epoch
        held = ("  ambiguities held" if ratio >= 999 else f"  ratio {ratio:.1f}" if ratio > 0
                else "")
        line.append(f"{held}  sats {msg.get('sats')}"
                    + (f"  base age {age:.1f} s" if isinstance(age, (int, float)) else ""))
        sd = msg.get("sd_enu_m")
        if isinstance(sd, list) and len(sd) == 3:
            line.append("  σ e/n/u " + "/".join(f"{float(v) * 100:.1f}" for v in sd) + " cm")
    if msg.get("alert") == "fix_lost":
        line.append("  FIX LOST while photos are taken", style="bold white on red")
    return line


def _status_body(st: dict[str, Any], marks: list[dict[str, Any]],
                 events: list[dict[str, Any]], session: dict[str, Any] | None,
                 alive: bool | None, *, stale: bool) -> RenderableType:
    """The screen below the title for one status."""
    link = st["link"]
    head = Text()
    # A normal end of session is not a failure: the daemon said "finished" before it went
    # (for the session this status is about), and nothing more will come for it.
    finished = session_finished(st, session)
    if finished:
        head.append(" SESSION FINISHED ", style="bold black on cyan")
    elif stale:
        head.append(" STALE: no status for more than 3 s ", style="bold white on red")
        if alive is False:
            head.append(" daemon gone ", style="bold white on red")
    else:
        head.append(" LIVE ", style="bold black on green")
    sess = (session or {}).get("files") or []
    head.append(f"  session {st.get('session_id') or '-'}")
    if sess:
        head.append(f"  file {sess[-1]}", style="dim")

    cur = link.get("current_dropout")
    comp = link.get("completeness_60s")
    link_line = Text()
    link_line.append("LINK ", style="bold")
    interval = link.get("epoch_interval_s")
    link_line.append(f"{1 / interval:.0f} Hz  " if interval else "rate ?  ")
    link_line.append(f"60 s {_fmt(comp and comp * 100, '.1f')}%  ",
                     style="green" if comp and comp > 0.98 else "bold red")
    sess_comp = link.get("completeness_session")
    link_line.append(f"session {_fmt(sess_comp and sess_comp * 100, '.1f')}%  ")
    link_line.append(f"{link.get('bytes_per_s', 0):.0f} B/s  ")
    link_line.append(f"dropouts {link.get('dropouts', 0)} ({link.get('missing_epochs', 0)} "
                     "epochs)  ")
    link_line.append(f"damaged {link.get('damaged_frames', 0)}  ")
    age = link.get("last_byte_age_s")
    link_line.append(f"last byte {_fmt(age, '.1f')} s ago")
    if cur and not finished:
        link_line.append(f"  DROPOUT NOW {cur['duration_s']:.1f} s", style="bold white on red")
    if link.get("source_connected") is False:
        link_line.append("  SOURCE LOST", style="bold white on red")

    sats = Table(expand=False, box=None, padding=(0, 1))
    for col in ("SV", "el", "az", "C/N0", "", "lock s", "clean s", "slips", "½", "state"):
        sats.add_column(col, justify="right" if col not in ("SV", "", "state") else "left")
    mask = st.get("elevation_mask_deg")
    for s in st.get("sats", []):
        style = STATE_STYLE.get(s["state"], "")
        el = s.get("elev_deg")
        below = isinstance(mask, (int, float)) and isinstance(el, (int, float)) and el < mask
        sats.add_row(
            s["sv"], Text(_fmt(el), style="dim" if below else ""), _fmt(s.get("azim_deg")),
            str(s["cno_dbhz"]),
            Text(_bar(s["cno_dbhz"], 20, 50), style="cyan"), f"{s['lock_s']:.0f}",
            f"{s['clean_phase_s']:.0f}", str(s["slips"]),
            Text("½", style="bold yellow") if s["half_cycle_unresolved"] else "",
            Text(s["state"] + (", below mask" if below else ""), style=style),
        )
    ppk = Text()
    need, clean_s = ppk_thresholds(st.get("ppk_ready_min"), st.get("ppk_clean_phase_s"))
    ppk.append(f"{ppk_label(clean_s)} ", style="bold")
    ready = st.get("ppk_ready", 0)
    ppk.append(f" {ready} ", style="bold black on green" if ready >= need else "bold white on red")
    ppk.append(f" of {tracked_text(st)}, {need} needed, half-cycle "
               f"{st.get('half_cycle_fraction', 0) * 100:.0f}%")

    ms = st["marks"]
    mark_line = Text()
    mark_line.append("MARKS ", style="bold")
    # the count received here beside the total: at 80 columns the line's tail wraps, not it
    mark_line.append(f"{ms['marks']} ({len(marks)} mark messages here)  last count "
                     f"{_fmt(ms.get('last_count'))}  ")
    lt = ms.get("last_falling_t_gps_ns")
    if lt:
        mark_line.append(f"at {gpstime.gps_to_datetime(lt):%H:%M:%S.%f} UTC  ")
    mark_line.append(f"missed {ms['missed']}", style="bold red" if ms["missed"] else "")
    if ms["missed"]:  # why: the radio (fix the link) or the receiver (the trigger rate)
        mark_line.append(f" ({ms.get('lost_on_link', 0)} radio, "
                         f"{ms.get('not_reported', 0)} receiver)", style="red")
    mark_line.append("  ")
    mark_line.append(f"in dropout {ms['in_dropout']}  ",
                     style="bold yellow" if ms["in_dropout"] else "")
    mark_line.append(f"pulse {_fmt(ms.get('last_pulse_width_ms'), '.1f')} ms  "
                     f"{ms.get('rate_per_min', 0):.1f}/min")

    alerts = st.get("alerts") or []
    alert_text = Text()
    if alerts:
        for a in alerts:  # a finished session's alerts are those standing at its end
            alert_text.append(f" ⚠ {a}\n",
                              style="bold white on grey35" if finished else "bold white on red")
    else:
        alert_text.append(" no alerts", style="green")
    ev_text = Text()
    for e in events[-6:]:
        ev_text.append_text(event_line(e))
    if any("mark" in a for a in alerts) and not finished:
        alert_text.append(" press a to acknowledge the missed marks\n", style="dim")
    # ALERTS right under the head: a short terminal (80x24) cuts the bottom, never the alerts.
    return Group(
        head, Text("ALERTS at the end of the session" if finished else "ALERTS", style="bold"),
        alert_text, link_line,
        Text("last 5 min ") + timeline(link), ppk, mark_line, sats,
        *([Text(unknown, style="dim")] if (unknown := unidentified_text(
            st.get("unidentified"))) else []),
        Text("EVENTS", style="bold"), ev_text,
    )


def connect(
    station: str, settings: ZenohSettings, state: WatchState
) -> Bus:
    """Open the bus, subscribe to the station, and catch up from its queryables."""
    from groundstation.bus import open_bus

    bus = open_bus(settings)
    bus.subscribe(key(station, "**"), state.on_payload)
    bus.subscribe_liveliness(key(station, "alive/**"), state.on_alive)
    for k, payload in bus.get(key(station, "q/timemarks"), timeout_s=2.0):
        state.on_payload(k, payload)
    for k, payload in bus.get(key(station, "q/status"), timeout_s=2.0):
        state.on_payload(k, payload)
    return bus


def station_label(station: str) -> str:
    """The title's station: ``station NAME``; the default name (``station``) said as such,
    not "station station" (``--station`` names another)."""
    if station == DEFAULT_STATION:
        return f"default station {station!r}"
    return f"station {station}"


def acknowledge(bus: Bus, station: str, alert: str = "marks_missed") -> None:
    """Put an acknowledgement on ``groundstation/<station>/ack``: the daemon clears the alert
    for every view and records who acknowledged it (docs/zenoh.md)."""
    import socket

    from groundstation import jsonio

    by = f"watch {os.environ.get('USER', '')}@{socket.gethostname()}".replace(" @", " ")
    bus.put(key(station, "ack"), jsonio.dumps({"alert": alert, "by": by}))


def in_foreground(fd: int) -> bool:
    """Whether this process's group owns the terminal on ``fd`` (``watch &`` does not)."""
    try:
        return os.tcgetpgrp(fd) == os.getpgrp()
    except OSError:
        return False


BACKGROUND_NOTE = "groundstation watch: running in the background: keys work after fg"
"""Said once when the watch starts in the background or is sent there (``watch &``, Ctrl-Z
then ``bg``); shorter than 80 columns, so that the live display's stderr redirection does not
wrap it."""


def _keys(on_key: Callable[[str], None], stop: threading.Event, told: bool = False) -> None:
    """Single key presses from a terminal (no Enter needed), until ``stop``.

    The terminal's modes are changed (cbreak) and read only while this process is in the
    foreground: from the background, setting the modes stops the process by SIGTTOU and
    reading by SIGTTIN (``groundstation watch &`` would stop silently); there the view goes on
    without keys and says so once (``told``: already said at the start).
    """
    import select
    import termios
    import tty

    fd = sys.stdin.fileno()
    try:
        saved = termios.tcgetattr(fd)
    except termios.error:
        return  # not a terminal: no keys
    cbreak = False
    try:
        while not stop.is_set():
            if not in_foreground(fd):
                if not told:
                    sys.stderr.write(BACKGROUND_NOTE + "\n")
                    sys.stderr.flush()
                    told = True
                cbreak = False  # the shell owns the modes now; set them again on fg
                stop.wait(0.2)
                continue
            told = False
            if not cbreak:
                tty.setcbreak(fd)
                cbreak = True
            ready, _, _ = select.select([fd], [], [], 0.2)
            if ready and in_foreground(fd):
                on_key(os.read(fd, 1).decode(errors="replace"))
    finally:
        if cbreak and in_foreground(fd):
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def run_watch(
    station: str,
    settings: ZenohSettings,
    *,
    console: Console | None = None,
    duration_s: float = 0.0,
    refresh_hz: float = 4.0,
    stop: Callable[[], bool] = lambda: False,
) -> WatchState:
    """Show the station until Ctrl-C, ``duration_s`` elapsed or ``stop()`` is true."""
    console = console or Console()
    state = WatchState(station)
    bus = connect(station, settings, state)
    t_end = time.monotonic() + duration_s if duration_s > 0 else None
    keys_done = threading.Event()

    def on_key(ch: str) -> None:
        if ch.lower() == "a":
            acknowledge(bus, station)

    # Started in the background (watch &): said before the live display takes the terminal.
    background = sys.stdin.isatty() and not in_foreground(sys.stdin.fileno())
    if background:
        sys.stderr.write(BACKGROUND_NOTE + "\n")
        sys.stderr.flush()
    threading.Thread(target=_keys, args=(on_key, keys_done, background), daemon=True).start()
    try:
        with Live(render(state), console=console, refresh_per_second=refresh_hz,
                  screen=False, transient=False) as live:
            while not stop() and (t_end is None or time.monotonic() < t_end):
                time.sleep(1 / refresh_hz)
                live.update(render(state))
    finally:
        keys_done.set()
        bus.close()
    return state
