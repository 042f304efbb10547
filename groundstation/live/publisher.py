"""The Zenoh publisher sink: status, time marks, events and session news for the solver and views.

Each time mark is put on the bus the moment the sink receives it; the queryables answer with all
marks of the session and the latest status, so a subscriber that joins late catches up. A Zenoh
failure never stops recording: the sink keeps draining its inbox, counts what it could not
publish and retries the session every few seconds. A peer or router that goes away and comes
back is rejoined by the Zenoh session itself (it keeps retrying its ``connect`` endpoints, in
peer and client mode): puts meanwhile reach nobody and fail nothing, and the marks they carried
are still answered by ``q/timemarks`` (``tests/integration/test_zenoh_faults.py``). When
``connect`` endpoints are configured, the sink checks every second that some peer or router is
connected; none for ``LINK_GRACE_S`` raises ``zenoh.disconnected`` (the monitor's
``zenoh_disconnected`` alert), and the first connection after that ``zenoh.connected``.

One station, one daemon: each daemon's liveliness token is ``groundstation/<station>/alive/<id>``
(a random id per process) and it watches ``groundstation/<station>/alive/**``. Another token
there means a second daemon claims the station: both raise the ``station.conflict`` event and
carry a ``station_conflict: ...`` alert in every status while it lasts (``station.conflict_ended``
after). Neither stops recording: a peer on the bus must not be able to silence a station by
claiming its name; the operator sees the alert in every view and renames one of them.

Recordings over Zenoh (``serve_recordings``): each MCAP file of the session, once closed, is
handed to :class:`~groundstation.live.serve.RecordingServer` (hashed off the event loop) and
listed in the ``session`` message's ``recordings[]``. The ``finished`` session message then
waits for the recorder: the daemon calls :meth:`ZenohPublisherSink.finish` once the last file
is closed (so a solver never reads a file being finished), which may keep serving for
``serve_after_s``.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import secrets
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from groundstation import events as kinds
from groundstation.bus import Bus, decode, encode, key, open_bus
from groundstation.config import ZenohSettings
from groundstation.errors import GroundstationError
from groundstation.live import obswire
from groundstation.live.fanout import Inbox, InboxClosed, Item, RawChunk
from groundstation.live.serve import RecordingServer
from groundstation.records import Event, LiveSolution, RawEpoch, Status, Subframe, TimeMark

log = logging.getLogger("groundstation.publisher")

RETRY_S = 5.0
FLUSH_BEFORE_CLOSE_S = 0.3
LINK_CHECK_S = 1.0
LINK_GRACE_S = 2.0  # connecting takes a moment; a peer restarting in under this goes unsaid
ACK_BURST = 5
ACK_PER_S = 1.0
"""Acknowledgements taken: a burst of 5, then one a second. Each one is an ``operator.ack``
event in the recording and on the bus; a peer putting 50 000 a second must not add megabytes
to the recording or flood the event loop. What goes beyond is counted and said."""


class RateLimit:
    """A token bucket: at most ``burst`` at once and ``per_s`` a second on average
    (thread-safe: Zenoh threads ask). ``dropped`` counts the refusals."""

    def __init__(self, per_s: float, burst: int,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.per_s = per_s
        self.burst = burst
        self._clock = clock
        self._tokens = float(burst)
        self._at = clock()
        self._lock = threading.Lock()
        self.dropped = 0

    def allow(self) -> bool:
        """Take one token if there is one; count a refusal otherwise."""
        with self._lock:
            now = self._clock()
            # elapsed time only forward (a monotonic clock; a step back adds nothing)
            self._tokens = min(float(self.burst),
                               self._tokens + max(0.0, now - self._at) * self.per_s)
            self._at = now
            if self._tokens >= 1.0:
                self._tokens -= 1.0
                return True
            self.dropped += 1
            return False


class ZenohPublisherSink:
    """Publishes a station's pipeline items on Zenoh.

    Args:
        station: the station name (key ``groundstation/<station>/...``).
        settings: how to join the bus, and whether to also put every RawEpoch on
            ``.../epoch`` (``publish_epochs``) and every raw chunk on ``.../ubx``
            (``publish_raw``, remote recording).
        clock: UNIX ns clock.
    """

    name = "publisher"

    def __init__(
        self,
        station: str,
        settings: ZenohSettings,
        *,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.station = station
        self.settings = settings
        self.publish_epochs = settings.publish_epochs
        self.publish_obs = settings.publish_obs
        self.publish_raw = settings.publish_raw
        self._clock = clock
        self.bus: Bus | None = None
        self._last_try = 0.0
        self.marks: list[bytes] = []
        self.latest_status: bytes | None = None
        self.session: dict[str, Any] = {"state": "started", "files": []}
        self.published = 0
        self.failed = 0
        self._unavailable_reported = False
        self._next_link_check = 0.0
        self._links_zero_since: float | None = None
        self.disconnected = False
        self.instance = secrets.token_hex(6)
        """This daemon's id in its liveliness token (``alive/<instance>``)."""
        self._others: set[str] = set()
        self._others_lock = threading.Lock()
        self.conflict: tuple[str, ...] = ()
        """The other daemons' ids claiming this station, as last reported."""
        self.server = RecordingServer(station) if settings.serve_recordings else None
        self.acks = RateLimit(ACK_PER_S, ACK_BURST)
        """Acknowledgements taken from the bus (:data:`ACK_BURST`, :data:`ACK_PER_S`)."""
        self._acks_dropped_said = 0
        self._hashing: set[asyncio.Task[None]] = set()

    def _on_token(self, key_expr: str, alive: bool) -> None:
        """A liveliness token under this station's ``alive`` (on a Zenoh thread)."""
        rest = key_expr.split("/alive", 1)[-1].lstrip("/")
        if rest == self.instance:
            return
        with self._others_lock:
            if alive:
                self._others.add(rest or "(unnamed)")
            else:
                self._others.discard(rest or "(unnamed)")

    def _check_conflict(self, publish: Callable[[Item], None]) -> None:
        with self._others_lock:
            others = tuple(sorted(self._others))
        if others == self.conflict:
            return
        was, self.conflict = self.conflict, others
        st = self.station
        if others:
            msg = (f"another daemon publishes as station {st!r} ({len(others)} other): "
                   "every view mixes the two; rename one (station = ...)")
            log.error("%s", msg)
            publish(Event(kinds.STATION_CONFLICT, self._clock(), msg, "error",
                          {"others": list(others), "instance": self.instance}))
        elif was:
            publish(Event(kinds.STATION_CONFLICT_ENDED, self._clock(),
                          f"no other daemon publishes as station {st!r} any more", "info",
                          {"instance": self.instance}))

    @property
    def accepts(self) -> frozenset[type]:
        """Marks, status and events; epochs and raw chunks when configured."""
        extra = ((RawEpoch,) if self.publish_epochs or self.publish_obs else ()) + (
            (Subframe,) if self.publish_obs else ()) + ((RawChunk,) if self.publish_raw else ())
        return frozenset((TimeMark, Status, Event, LiveSolution, *extra))

    # -- the bus, opened lazily and re-opened after failures ---------------------------------

    async def _connect(self, publish: Callable[[Item], None]) -> None:
        now = time.monotonic()
        if self.bus is not None or (self._last_try and now - self._last_try < RETRY_S):
            return
        self._last_try = now
        loop = asyncio.get_running_loop()
        try:  # opening may take a moment: keep the event loop (and the recorder) going
            bus = await loop.run_in_executor(None, open_bus, self.settings)
        except GroundstationError as err:
            if not self._unavailable_reported:
                self._unavailable_reported = True
                log.warning("%s; recording goes on, retrying every %g s", err, RETRY_S)
                publish(Event(kinds.ZENOH_UNAVAILABLE, self._clock(), str(err), "warning",
                              {"retry_s": RETRY_S}))
            return
        self.bus = bus
        st = self.station
        bus.queryable(key(st, "q/timemarks"), lambda: list(self.marks))
        bus.queryable(
            key(st, "q/status"), lambda: [self.latest_status] if self.latest_status else []
        )
        # the session so far (files, span) for a solver pairing a rover with this base
        bus.queryable(key(st, "q/session"), lambda: [
            encode("session", dict(self.session), station=st)] if self.session["files"] else [])
        bus.liveliness_token(key(st, f"alive/{self.instance}"))
        bus.subscribe_liveliness(key(st, "alive/**"), self._on_token)

        def on_ack(_key: str, payload: bytes) -> None:  # a Zenoh thread: hand over to the loop
            if not self.acks.allow():  # before anything else: a flood costs a counter each
                dropped = self.acks.dropped
                if dropped == 1 or dropped % 10_000 == 0:
                    log.warning("acknowledgements beyond %d at once or %g a second: %d dropped "
                                "so far", ACK_BURST, ACK_PER_S, dropped)
                return
            loop.call_soon_threadsafe(self._on_ack, payload, publish)

        bus.subscribe(key(st, "ack"), on_ack)
        if self.server is not None:
            self.server.bind(bus)
        if self._unavailable_reported:
            self._unavailable_reported = False
            publish(Event(kinds.ZENOH_AVAILABLE, self._clock(), "Zenoh session open again", "info"))
        self._put_session()
        log.info("publishing on Zenoh as %s (%s, listen %s, connect %s)", key(st, "**"),
                 self.settings.mode, list(self.settings.listen), list(self.settings.connect))

    def _on_ack(self, payload: bytes, publish: Callable[[Item], None]) -> None:
        """An operator's acknowledgement from a view (``groundstation/<station>/ack``, JSON
        ``{"alert": ..., "by": ...}``): into the pipeline as ``operator.ack``, where the
        monitor clears the alert for every view and the recorder keeps it."""
        try:
            msg = decode(payload)
        except ValueError as err:
            log.warning("ignoring a malformed acknowledgement: %s", err)
            return
        alert, by = str(msg.get("alert", ""))[:64], str(msg.get("by", ""))[:64]
        dropped = self.acks.dropped - self._acks_dropped_said
        self._acks_dropped_said += dropped
        log.info("operator acknowledged %s (%s)%s", alert or "all alerts", by or "unnamed view",
                 f"; {dropped} acknowledgements dropped before it (rate limit)" if dropped
                 else "")
        data: dict[str, Any] = {"alert": alert, "by": by}
        if dropped:
            data["dropped_before"] = dropped
        ev = Event(kinds.OPERATOR_ACK, self._clock(),
                   f"{alert or 'alerts'} acknowledged by {by or 'an operator'}", "info", data)
        publish(ev)  # to the monitor and the recorder; the fanout never hands it back to us
        self._put("event", encode("event", ev, station=self.station))

    def _check_links(self, publish: Callable[[Item], None]) -> None:
        """Say when nobody we are meant to connect to is connected, and when one is again."""
        now = time.monotonic()
        if self.bus is None or not self.settings.connect or now < self._next_link_check:
            return
        self._next_link_check = now + LINK_CHECK_S
        try:
            linked = self.bus.connections() > 0
        except Exception as err:  # a session in trouble: _put notices and reopens it
            log.debug("Zenoh session info failed: %s", err)
            return
        endpoints = ", ".join(self.settings.connect)
        if linked:
            self._links_zero_since = None
            if self.disconnected:
                self.disconnected = False
                log.info("Zenoh connected again (%s)", endpoints)
                publish(Event(kinds.ZENOH_CONNECTED, self._clock(),
                              f"Zenoh connected again ({endpoints})", "info",
                              {"connect": list(self.settings.connect)}))
            return
        if self._links_zero_since is None:
            self._links_zero_since = now
        elif not self.disconnected and now - self._links_zero_since >= LINK_GRACE_S:
            self.disconnected = True
            log.warning("Zenoh: no peer or router connected (%s)", endpoints)
            publish(Event(
                kinds.ZENOH_DISCONNECTED, self._clock(),
                f"Zenoh: no peer or router connected ({endpoints}): status, marks and events "
                "reach nobody; recording goes on and Zenoh keeps trying", "warning",
                {"connect": list(self.settings.connect)},
            ))

    def _put(self, leaf: str, payload: bytes) -> None:
        if self.bus is None:
            self.failed += 1
            return
        try:
            self.bus.put(key(self.station, leaf), payload)
            self.published += 1
        except Exception as err:  # the session broke: drop it and retry later
            self.failed += 1
            log.warning("Zenoh put on %s failed: %s", leaf, err)
            self._drop_bus()

    def _put_session(self) -> None:
        if self.server is not None:
            self.session["recordings"] = self.server.entries()
        self._put("session", encode("session", self.session, station=self.station))

    def _serve(self, paths: Sequence[Path]) -> None:
        """Serve closed files: hashed in a thread, then the session message says so."""
        server = self.server
        if server is None:
            return
        session_id = str(self.session.get("session_id") or "")

        async def hash_and_announce() -> None:
            loop = asyncio.get_running_loop()
            for path in paths:
                await loop.run_in_executor(None, server.add, path, session_id)
            self._put_session()

        try:
            task = asyncio.get_running_loop().create_task(hash_and_announce())
        except RuntimeError:  # no event loop (a synchronous caller): hash here
            for path in paths:
                server.add(path, session_id)
            self._put_session()
            return
        self._hashing.add(task)
        task.add_done_callback(self._hashing.discard)

    async def finish(self, files: Sequence[Path], stop: asyncio.Event | None = None) -> None:
        """The session has ended and the recorder has closed ``files``: serve them, put the
        ``finished`` session message, keep serving up to ``serve_after_s`` (until every file
        was sent in full, or ``stop`` is set), then leave the bus."""
        try:
            if self.server is None:
                return
            if self._hashing:
                await asyncio.wait(set(self._hashing))
            if self.bus is not None:
                loop = asyncio.get_running_loop()
                sid = str(self.session.get("session_id") or "")
                for path in files:
                    await loop.run_in_executor(None, self.server.add, path, sid)
            self.session["state"] = "finished"
            self.session["marks"] = len(self.marks)
            self._put_session()
            linger = self.settings.serve_after_s
            if self.bus is not None and linger > 0 and self.server.entries():
                log.info("serving %d recording file(s) for up to %g s (Ctrl-C to stop now)",
                         len(self.server.entries()), linger)
                deadline = time.monotonic() + linger
                while time.monotonic() < deadline and not (stop and stop.is_set()):
                    if self.server.sent_in_full():
                        log.info("every recording file was sent in full: done serving")
                        break
                    await asyncio.sleep(0.2)
            await self._let_puts_leave()
        finally:
            self._drop_bus()

    async def _let_puts_leave(self) -> None:
        """Before leaving the bus: give the last puts time to leave the host, when anyone is
        connected to receive them (with nobody connected there is nothing in flight, and the
        0.3 s was a fixed cost of every file replayed or ingested alone)."""
        if self.bus is not None and self.bus.connections() > 0:
            await asyncio.sleep(FLUSH_BEFORE_CLOSE_S)

    def close(self) -> None:
        """Leave the bus (when :meth:`finish` was not reached)."""
        self._drop_bus()

    def _drop_bus(self) -> None:
        bus, self.bus = self.bus, None
        if bus is not None:
            bus.close()

    # -- the sink -------------------------------------------------------------------------

    def handle(self, item: Item) -> None:
        """Publish one item (synchronous; also used by replay)."""
        st = self.station
        if isinstance(item, TimeMark):
            payload = encode("timemark", item, station=st, index=len(self.marks))
            self.marks.append(payload)
            self._put("timemark", payload)
        elif isinstance(item, Status):
            if self.conflict:
                alert = (f"station_conflict: {len(self.conflict)} other daemon(s) publish as "
                         f"station {st!r}")
                item = dataclasses.replace(item, alerts=(*item.alerts, alert))
            self.latest_status = encode("status", item)
            self._put("status", self.latest_status)
            # the span of epochs recorded so far, for a solver pairing rover and base
            for k in ("first_epoch_t_gps_ns", "last_epoch_t_gps_ns"):
                if getattr(item.link, k) is not None:
                    self.session[k] = getattr(item.link, k)
        elif isinstance(item, Event):
            self._put("event", encode("event", item, station=st))
            if item.kind == kinds.RECORDER_FILE_OPENED:
                path = item.data.get("path")
                # Absolute: the solver and the views run in other directories.
                path = str(Path(path).absolute()) if path else path
                if path and path not in self.session["files"]:
                    closed = [Path(p) for p in self.session["files"]]  # all but the new one
                    self.session["files"].append(path)
                    self.session["session_id"] = item.data.get("session_id", "")
                    self._put_session()
                    if closed:
                        self._serve(closed)
            elif item.kind == kinds.RECORDER_VANISHED:  # the solver must not look for them
                gone = {str(Path(str(p)).absolute()) for p in item.data.get("lost") or ()}
                self.session["files"] = [f for f in self.session["files"] if f not in gone]
        elif isinstance(item, RawEpoch):
            if self.publish_obs:
                self._put("obs", obswire.encode_epoch(item))
            if self.publish_epochs:
                self._put("epoch", encode("epoch", item, station=st))
        elif isinstance(item, LiveSolution):
            self._put("rtk", encode("rtk", item.message(), station=st))
        elif isinstance(item, Subframe) and self.publish_obs:
            self._put("obs", obswire.encode_subframe(item))
        elif isinstance(item, RawChunk) and self.publish_raw:
            self._put("ubx", item.data)

    async def consume(self, inbox: Inbox, publish: Callable[[Item], None]) -> None:
        await self._connect(publish)
        try:
            while True:
                try:
                    item = await inbox.get(timeout_s=1.0)
                except InboxClosed:
                    break
                if self.bus is None:
                    await self._connect(publish)
                if item is not None:
                    self.handle(item)
                self._check_links(publish)
                self._check_conflict(publish)
        finally:
            if self.server is None:
                self.session["state"] = "finished"
                self.session["marks"] = len(self.marks)
                self._put_session()
                await self._let_puts_leave()
                self._drop_bus()
            # else: the daemon calls finish() once the recorder has closed the last file
