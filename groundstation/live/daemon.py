"""The live pipeline and daemon: source -> framer -> decoder -> fanout -> sinks, in one TaskGroup.

:class:`Pipeline` wires the stages; :func:`run_daemon` is the entry point for ``groundstation
run``, the demo and replay. Shutdown (stop event, SIGINT/SIGTERM, ``duration_s`` or the end of
a file source) drains in order: the source stops first, the framer's waiting bytes are flushed
through the decoder, the other sinks finish, and the recorder finishes last (MCAP summary
written).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from groundstation import events as kinds
from groundstation.config import Settings
from groundstation.errors import GroundstationError
from groundstation.gpstime import format_gps
from groundstation.live.data_time import UNTIMED, DataClock, Timed, restamped
from groundstation.live.fanout import Fanout, InboxStats, Overflow, Publish, Sink, SinkSpec
from groundstation.live.monitor import Monitor
from groundstation.live.monitor_sink import MonitorSink
from groundstation.live.publisher import ZenohPublisherSink
from groundstation.live.recorder_sink import RecorderSink
from groundstation.live.sources import FileSource, Source, make_source
from groundstation.records import (
    DamagedData,
    Event,
    Frame,
    Item,
    PipelineStatus,
    RawChunk,
    UndecodedFrame,
)
from groundstation.rules.plausible import Jump, span_text
from groundstation.storage.mcapio import ExactFile
from groundstation.storage.session import FileOpener, SessionRecorder
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import BetweenFrames, UbxFramer

log = logging.getLogger("groundstation.daemon")


@dataclass(frozen=True, slots=True)
class RunSummary:
    """What a pipeline run did, for the command line and for tests."""

    session_id: str
    files: tuple[Path, ...]
    sidecars: tuple[Path, ...]
    stopped_by: str
    duration_s: float
    bytes_in: int
    chunks: int
    frames: int
    garbage_bytes: int
    records: int
    events: int
    outages: int
    queues: tuple[InboxStats, ...]
    frames_by_type: dict[str, int] = field(default_factory=dict)
    write_failures: int = 0
    dropped_raw_bytes: int = 0
    dropped_records: int = 0
    lost_held_bytes: int = 0
    lost_files: tuple[Path, ...] = ()
    """Files of the session deleted while it was recorded (not in ``files``/``sidecars``)."""
    implausible_by_type: dict[str, int] = field(default_factory=dict)
    """Frames whose time cannot belong to the session (rules/plausible), by message type:
    recorded, not decoded."""
    time_jumps: int = 0
    """Jumps of the receiver's time that a second epoch confirmed (``decoder.time_jump``)."""


def make_monitor(settings: Settings) -> Monitor:
    """A monitor with the configured thresholds."""
    return Monitor(settings.station, settings.monitor,
                   status_interval_s=settings.status_interval_s)


class Pipeline:
    """One live pipeline: a source, the framer and decoder, a fanout and its sinks.

    Args:
        settings: resolved settings.
        source: overrides the configured source (the simulator, an MCAP replay ...).
        sinks: extra sinks (monitor, Zenoh publisher) with their queue policies.
        record: add the recorder sink (MCAP + sidecar) as configured.
        clock: UNIX ns clock.
        on_file: called with each recording file as it is created.
        monitor_data_clock: the monitor's time is the items' host times (always so for a
            :class:`~groundstation.live.sources.FileSource`).
        open_file: how the recorder creates its files (a test's fault hook; default
            :class:`~groundstation.storage.mcapio.ExactFile`).
        on_first_chunk: called with the time of the first chunk, before it is published.
    """

    def __init__(
        self,
        settings: Settings,
        *,
        source: Source | None = None,
        sinks: Sequence[SinkSpec] = (),
        record: bool = True,
        clock: Callable[[], int] = time.time_ns,
        on_file: Callable[[Path], None] | None = None,
        monitor_data_clock: bool = False,
        open_file: FileOpener | None = None,
        on_first_chunk: Callable[[int], None] | None = None,
    ) -> None:
        self.settings = settings
        self._clock = clock
        self.fanout = Fanout(clock=clock)
        self.framer = UbxFramer(settings.framer.max_payload_bytes)
        self.between = BetweenFrames()  # damaged data between frames, for the monitor
        self.decoder = Decoder()
        self.source: Source = source or make_source(settings.source, self.publish, clock=clock)
        self.specs: list[SinkSpec] = []
        self.recorder: RecorderSink | None = None
        if record:
            rec = settings.recorder
            session = SessionRecorder(
                rec.out_dir, settings.station, receiver=settings.receiver,
                configuration=settings.to_jsonable(), chunk_size_bytes=rec.chunk_size_bytes,
                compression=rec.compression, flush_interval_ns=int(rec.flush_interval_s * 1e9),
                rotate_size_bytes=int(rec.rotate_size_mb * 1e6),
                rotate_duration_ns=int(rec.rotate_duration_s * 1e9), sidecar=rec.sidecar,
                clock=clock, backlog_bytes_max=int(rec.backlog_mb * 1e6),
                retry_interval_ns=int(rec.retry_s * 1e9),
                open_file=open_file or ExactFile,
            )
            user_on_file = on_file

            def announce(path: Path) -> None:
                self.publish(Event(
                    kinds.RECORDER_FILE_OPENED, self._clock(), f"recording to {path}", "info",
                    {"path": str(path), "session_id": session.session_id},
                ))
                if user_on_file is not None:
                    user_on_file(path)

            self.recorder = RecorderSink(session, rec.flush_interval_s, announce, clock=clock)
            self.specs.append(
                SinkSpec(self.recorder, settings.queues.recorder, Overflow.NEVER_DROP)
            )
        self.monitor: MonitorSink | None = None
        self.publisher: ZenohPublisherSink | None = None
        if settings.monitor.enabled:
            self.monitor = MonitorSink(
                make_monitor(settings),
                disk_path=settings.recorder.out_dir if record else None,
                clock=clock, data_clock=monitor_data_clock or isinstance(self.source, FileSource),
            )
            self.specs.append(SinkSpec(self.monitor, settings.queues.monitor,
                                       Overflow.DROP_OLDEST))
        if settings.zenoh.enabled:
            self.publisher = ZenohPublisherSink(settings.station, settings.zenoh, clock=clock)
            self.specs.append(SinkSpec(self.publisher, settings.queues.publisher,
                                       Overflow.DROP_OLDEST))
        for spec in sinks:
            self.add_sink(spec.sink, spec.maxsize, spec.overflow)
        self._on_first_chunk = on_first_chunk
        self._data_clock: DataClock | None = None
        self.chunks = 0
        self.records = 0
        self.events = 0
        self._stopping = False
        self.stopped_by = ""

    def add_sink(self, sink: Sink, maxsize: int, overflow: Overflow) -> None:
        """Register a sink before :meth:`run` (the recorder, if any, always finishes last)."""
        if any(s.sink.name == sink.name for s in self.specs):
            raise ValueError(f"a sink named {sink.name!r} is already registered")
        self.specs.append(SinkSpec(sink, maxsize, overflow))

    # -- the synchronous core ---------------------------------------------------------------

    def publish(self, item: Item, origin: str | None = None) -> None:
        """Hand an item (record, event, status) to every sink that accepts it, except the sink
        named ``origin`` (the one that produced it)."""
        if type(item) is Event:
            self.events += 1
        self.fanout.publish(item, origin)

    def _publisher(self, origin: str) -> Publish:
        def publish(item: Item) -> None:
            self.publish(item, origin)

        return publish

    def ingest(self, chunk: bytes, t_host_ns: int) -> None:
        """One chunk from the source: raw bytes first, then what they decode to (an
        :data:`~groundstation.live.data_time.UNTIMED` chunk once timed, without pacing)."""
        for data, items, t in self._timed(chunk, t_host_ns):
            self._emit(data, items, t)

    def _timed(self, chunk: bytes, t_host_ns: int) -> list[Timed]:
        """The chunk framed, decoded and timed: a timed chunk as is; an untimed one by the
        source's data clock from the epochs its frames decoded to (possibly held, or several
        released). The decoder judges every time (rules/plausible) before the data clock sees
        it, so the clock follows only plausible epochs."""
        self.between.feed(chunk)
        if t_host_ns != UNTIMED or self._data_clock is None:
            return [(chunk, self._decode(self.framer.feed(chunk, t_host_ns)), t_host_ns)]
        return self._data_clock.stamp(chunk, self._decode(self.framer.feed(chunk, UNTIMED)))

    def _emit(self, chunk: bytes, items: list[Item], t_host_ns: int) -> None:
        if self.chunks == 0 and self._on_first_chunk is not None:
            self._on_first_chunk(t_host_ns)
        self.chunks += 1
        self.fanout.publish(RawChunk(chunk, t_host_ns))
        for item in items:
            self.publish(item)

    def _decode(self, frames: list[Frame]) -> list[Item]:
        """What the frames decode to, in order (frames left undecoded are in /ubx/raw): records,
        and a ``decoder.time_jump`` event before the epoch that confirmed a jump (the monitor
        starts again from it)."""
        jumps = self.decoder.clock.jumps
        out: list[Item] = []
        for frame in frames:
            if self.between.damaged_before(frame):
                out.append(DamagedData(frame.t_host_ns))
            seen = len(jumps)
            record = self.decoder.decode(frame)
            if len(jumps) != seen:
                out.append(self._time_jump(jumps[-1], frame.t_host_ns))
            if isinstance(record, (Frame, UndecodedFrame)):
                continue  # its bytes are already in /ubx/raw
            self.records += 1
            out.append(record)
        return out

    def _time_jump(self, jump: Jump, t_host_ns: int) -> Event:
        before = ("the host's clock" if jump.from_t_gps_ns is None
                  else f"{span_text(jump.to_t_gps_ns - jump.from_t_gps_ns)} from the session's "
                  "clock")
        return Event(
            kinds.DECODER_TIME_JUMP, t_host_ns or self._clock(),
            f"the receiver's time jumped ({before}) to {format_gps(jump.to_t_gps_ns)}, "
            "confirmed by a second epoch: the session's clock follows it", "warning",
            {"from_t_gps_ns": jump.from_t_gps_ns, "to_t_gps_ns": jump.to_t_gps_ns,
             "skipped_t_gps_ns": jump.skipped_t_gps_ns},
        )

    def status(self) -> PipelineStatus:
        fs = self.framer.stats
        ds = self.decoder.stats
        state = getattr(self.source, "state", None)
        connected = getattr(state, "connected", None)
        return PipelineStatus(
            t_host_ns=self._clock(),
            source=self.source.name,
            source_connected=connected if isinstance(connected, bool) else None,
            bytes_in=fs.bytes_in,
            chunks=self.chunks,
            frames=fs.frames,
            garbage_bytes=fs.garbage_bytes,
            bad_checksum=fs.bad_checksum,
            records=self.records,
            undecodable=ds.undecodable,
            queued={s.name: s.queued for s in self.fanout.stats},
            dropped={s.name: s.dropped for s in self.fanout.stats},
            nmea_sentences=fs.nmea_sentences,
            implausible=ds.implausible,
        )

    # -- tasks ------------------------------------------------------------------------------

    async def _wait_for_sinks(self) -> None:
        """A source that can wait (a file) pauses while any inbox is more than half full."""
        while any(len(i) > i.maxsize // 2 for i in self.fanout.inboxes):
            await asyncio.sleep(0.002)

    async def _ingest_loop(self) -> None:
        chunks = self.source.chunks()
        pace = getattr(self.source, "untimed_delay_s", None)
        try:
            async for chunk, t_host_ns in chunks:
                if t_host_ns == UNTIMED and self._data_clock is None:  # a .ubx file, once
                    self._data_clock = getattr(self.source, "data_clock", None)
                for data, items, t in self._timed(chunk, t_host_ns):
                    if t_host_ns == UNTIMED and callable(pace):
                        delay = pace(t)
                        if delay > 0:
                            await asyncio.sleep(delay)
                    self._emit(data, items, t)
                if self.source.can_wait:
                    await self._wait_for_sinks()
            self.stopped_by = self.stopped_by or "end of source"
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if not self._stopping or task is None:
                raise
            task.uncancel()  # our own orderly stop, not a cancellation of the daemon
        finally:
            with contextlib.suppress(Exception):
                await chunks.aclose()  # type: ignore[attr-defined]
            drain = getattr(self.source, "drain", None)  # reads a source held at the stop
            if callable(drain):
                for chunk, t_host_ns in drain():
                    self.ingest(chunk, t_host_ns)
            # Chunks held for their time and bytes still waiting in the framer: recover what
            # frames they hold.
            clock = self._data_clock
            if clock is None:
                last = self._decode(self.framer.flush(self._clock()))
            else:
                for data, items, t in clock.flush():
                    self._emit(data, items, t)
                last = restamped(self._decode(self.framer.flush(UNTIMED)), clock.now_ns())
            for item in last:
                self.publish(item)
            log.info("source %s stopped (%s)", self.source.name, self.stopped_by)

    async def _status_loop(self) -> None:
        interval = self.settings.status_interval_s
        while True:
            await asyncio.sleep(interval)
            self.publish(self.status())

    async def run(
        self, stop_event: asyncio.Event | None = None, *, handle_signals: bool = False
    ) -> RunSummary:
        """Run until stopped: ``stop_event`` set, a signal (if handled), ``duration_s`` elapsed
        or the source ended. Returns a summary once the recorder has finished.

        Raises:
            GroundstationError: when the source cannot be used at all (e.g. a missing file).
        """
        stop = stop_event if stop_event is not None else asyncio.Event()
        loop = asyncio.get_running_loop()
        handled: list[signal.Signals] = []
        serving = [False]
        serve_stop = asyncio.Event()  # a signal while the finished files are served
        if handle_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                def on_signal(sig: signal.Signals = sig) -> None:
                    log.info("%s: stopping", sig.name)
                    self.stopped_by = self.stopped_by or sig.name
                    if serving[0]:
                        serve_stop.set()
                    stop.set()
                loop.add_signal_handler(sig, on_signal)
                handled.append(sig)
        t0 = time.monotonic()
        try:
            await self._run(stop)
            if self.publisher is not None:  # the recorder has closed every file by now
                serving[0] = True
                rec = self.recorder.recorder.stats.files if self.recorder is not None else ()
                await self.publisher.finish(rec, serve_stop)
        except BaseExceptionGroup as group:
            ours = group.subgroup(lambda e: isinstance(e, GroundstationError))
            if ours is not None:
                raise ours.exceptions[0] from group
            raise
        finally:
            if self.publisher is not None:
                self.publisher.close()
            for sig in handled:
                loop.remove_signal_handler(sig)
        return self.summary(time.monotonic() - t0)

    async def _run(self, stop: asyncio.Event) -> None:
        inboxes = [
            (spec, self.fanout.add_inbox(spec.sink.name, spec.maxsize, spec.overflow,
                                         spec.sink.accepts))
            for spec in self.specs
        ]
        claim = getattr(self.source, "claim", None)
        if callable(claim):
            claim()  # e.g. the serial port, exclusively: refused before any file exists
        if self.recorder is not None:
            try:
                self.recorder.open()  # the file exists (and is announced) before data flows
            except OSError as err:  # at start-up a full or read-only disk is refused at once
                raise GroundstationError(
                    f"cannot create the recording in {self.settings.recorder.out_dir}: {err}"
                ) from err
        duration = self.settings.duration_s
        async with asyncio.TaskGroup() as tg:
            sink_tasks = {
                spec.sink.name: tg.create_task(
                    spec.sink.consume(inbox, self._publisher(spec.sink.name)),
                    name=f"sink:{spec.sink.name}"
                )
                for spec, inbox in inboxes
            }
            status_task = tg.create_task(self._status_loop(), name="status")
            ingest_task = tg.create_task(self._ingest_loop(), name="ingest")
            stop_task = tg.create_task(stop.wait(), name="stop")
            waits: set[asyncio.Task[Any]] = {ingest_task, stop_task}
            timeout = duration if duration > 0 else None
            done, _ = await asyncio.wait(waits, timeout=timeout,
                                         return_when=asyncio.FIRST_COMPLETED)
            if not done:
                self.stopped_by = self.stopped_by or f"duration {duration:g} s"
            elif stop_task in done:
                self.stopped_by = self.stopped_by or "stop requested"
            # 1. the source first (its finally flushes the framer through the decoder)
            self._stopping = True
            if not ingest_task.done():
                ingest_task.cancel()
            await asyncio.wait({ingest_task})
            stop_task.cancel()
            status_task.cancel()
            self.publish(self.status())
            # 2. the monitor drains first, while every sink still takes what it publishes last
            #    (closing it together with the others lost the events of the final burst),
            # 3. the other sinks drain and finish, 4. the recorder last
            if self.monitor is not None and self.monitor.name in sink_tasks:
                self.fanout.close([self.monitor.name])
                await asyncio.wait({sink_tasks[self.monitor.name]})
            others = [n for n in sink_tasks if self.recorder is None or n != self.recorder.name]
            self.fanout.close(others)
            if others:
                await asyncio.wait({sink_tasks[n] for n in others})
            self.fanout.close()

    def summary(self, duration_s: float) -> RunSummary:
        from groundstation.ubx.decode import message_name

        fs = self.framer.stats
        rec = self.recorder.recorder.stats if self.recorder is not None else None
        state = getattr(self.source, "state", None)
        return RunSummary(
            session_id=rec.session_id if rec else "",
            files=rec.files if rec else (),
            sidecars=rec.sidecars if rec else (),
            stopped_by=self.stopped_by or "stopped",
            duration_s=duration_s,
            bytes_in=fs.bytes_in,
            chunks=self.chunks,
            frames=fs.frames,
            garbage_bytes=fs.garbage_bytes,
            records=self.records,
            events=self.events,
            outages=int(getattr(state, "outages", 0)),
            queues=self.fanout.stats,
            frames_by_type={message_name(*k): n for k, n in sorted(fs.frames_by_type.items())},
            write_failures=rec.write_failures if rec else 0,
            dropped_raw_bytes=rec.dropped_raw_bytes if rec else 0,
            dropped_records=rec.dropped_records if rec else 0,
            lost_held_bytes=rec.held_bytes if rec else 0,
            lost_files=rec.lost_files if rec else (),
            implausible_by_type=self.decoder.stats.implausible_by_type,
            time_jumps=self.decoder.stats.time_jumps,
        )


async def run_daemon(
    settings: Settings,
    *,
    stop_event: asyncio.Event | None = None,
    source: Source | None = None,
    sinks: Sequence[SinkSpec] = (),
    record: bool = True,
    handle_signals: bool = False,
    on_file: Callable[[Path], None] | None = None,
) -> RunSummary:
    """Build a :class:`Pipeline` and run it (see :meth:`Pipeline.run`).

    Args:
        settings: resolved settings (``load_settings``).
        stop_event: set it to stop in order.
        source: overrides ``settings.source`` (simulator, replay).
        sinks: extra sinks, e.g. ``SinkSpec(publisher, 2000, Overflow.DROP_OLDEST)``.
        record: write the MCAP and sidecar.
        handle_signals: SIGINT/SIGTERM stop the daemon in order (the command line sets this).
        on_file: called with each recording file as it is created.
    """
    pipeline = Pipeline(settings, source=source, sinks=sinks, record=record, on_file=on_file)
    return await pipeline.run(stop_event, handle_signals=handle_signals)
