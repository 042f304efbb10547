"""The demo: the simulator feeds the daemon through a real pty; the daemon records and publishes.

It wires a simulated flight (rover and base), a pseudo-terminal that stands in for the Wi232
radio's USB serial port, the live pipeline reading it with pyserial (recorder, monitor, Zenoh
publisher) and an in-process view sink for the terminal. What it writes goes to one directory:
the MCAP and raw sidecar of the session, the base station's stream and the simulator's truth.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from groundstation import events as kinds
from groundstation.bus import encode
from groundstation.config import (
    DEFAULT_ENDPOINT,
    SerialSourceSettings,
    Settings,
    load_settings,
)
from groundstation.live.daemon import Pipeline, RunSummary
from groundstation.live.fanout import Inbox, InboxClosed, Item, Overflow
from groundstation.live.rtk import EngineUnavailable, LiveRtkSink, measurements
from groundstation.records import Event, LiveSolution, Status, TimeMark
from groundstation.sim.faults import FaultConfig
from groundstation.sim.profiles import sim_config
from groundstation.sim.ptylink import PtyLink
from groundstation.sim.stream import SimResult, simulate

log = logging.getLogger("groundstation.demo")

DRAIN_IDLE_S = 2.0
"""At the end, the daemon reads what is still in the pty; if it reads nothing for this long it
is not reading any more (the bytes it never read are then reported in the summary)."""
BASE_WAITS_FOR_SESSION_S = 10.0
"""How long the base station's daemon waits for the demo's Zenoh session to listen before it
starts all the same (a session that cannot open: the demo records on and says so)."""


SIMULATED_RECEIVER = "simulated u-blox LEA-6T (groundstation.sim)"
DEMO_DEFAULTS: dict[str, Any] = {"station": "demo", "receiver": SIMULATED_RECEIVER}
"""Where ``demo`` differs from the daemon's defaults (below the file and the environment)."""
PTY_BAUD = 115200
"""The pty has no baud rate; the source is told the simulator's link rate."""


def demo_settings(config_file: Path | None = None, *, environ: dict[str, str] | None = None,
                  overrides: dict[str, Any] | None = None) -> Settings:
    """``demo``'s daemon settings through the one resolver: its defaults < file < environment
    < ``overrides`` (its options). The source is the simulator's pty whatever the layers say
    (:func:`run_demo` opens it and puts its path in).

    Raises:
        ConfigError: naming the offending key or variable.
    """
    layer = {**(overrides or {}), "source": {"type": "serial", "port": "(the simulator's pty)",
                                             "baud": PTY_BAUD}}
    return load_settings(config_file, environ=environ, overrides=layer, defaults=DEMO_DEFAULTS)


@dataclass(frozen=True, slots=True)
class DemoOptions:
    """What to simulate and how to run the daemon on it.

    ``settings`` (from :func:`demo_settings`: file, environment, options) is the daemon's
    configuration; without it, ``station``, ``out_dir`` and the Zenoh fields over the demo's
    defaults, without the environment.
    """

    flight_s: float = 300.0
    speed: float | None = 1.0
    seed: int = 1
    faults: str = "default"
    profile: str = "default"
    severity: float = 1.0
    duration_s: float = 0.0
    out_dir: Path = Path("flights")
    station: str = "demo"
    zenoh_listen: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    zenoh: bool = True
    serve_after_s: float = 0.0
    settings: Settings | None = None
    live_rtk: bool = True
    """Solve the rover's epochs live against the simulated base (``--no-base``: not)."""


WEEK_NS = 604_800 * 1_000_000_000


@dataclass(frozen=True, slots=True)
class SentFigures:
    """The simulator's own figures for what it put on the link before the demo stopped.

    Attributes:
        whole_flight: every chunk of the flight was written (the figures are the whole flight's).
        flight_s: seconds of flight data sent (from the flight's start to the last chunk).
        lost_epochs: epochs the injected link faults dropped among those sent.
        exposures: the truth's exposures whose time mark was due on the link before the stop.
    """

    whole_flight: bool
    flight_s: float
    lost_epochs: int
    exposures: tuple[dict[str, Any], ...]


@dataclass(frozen=True, slots=True)
class DemoResult:
    summary: RunSummary
    sim: SimResult
    base_path: Path
    truth_path: Path
    pty_path: str
    last_status: Status | None
    endpoint: str | None
    station: str
    bytes_written: int
    sent_until_gps_ns: int | None = None
    """GPS time of the last chunk written when the run stopped before the flight's end."""
    alerts_cleared: tuple[str, ...] = ()
    """The alerts raised during the run and cleared before its end (their messages)."""
    live: tuple[LiveSolution, ...] = ()
    """The live engine's position at every rover epoch (none without it)."""
    live_missing: str = ""
    """Why the live engine did not run, when it was asked for."""
    base_station: RunSummary | None = None
    """The base station's daemon (``<station>-base``): its recording and counts."""

    def sent(self) -> SentFigures:
        """The simulator's figures up to the stop (the whole flight's when it ran to its end),
        so a cut run is never compared with the whole flight's totals."""
        truth = self.sim.truth
        start = int(truth["start_gps_ns"])
        exposures = truth["exposures"]
        lost_tow = truth["fault_summary"]["epochs_lost_tow_ms"]
        if self.sent_until_gps_ns is None:
            return SentFigures(True, (int(truth["end_gps_ns"]) - start) / 1e9, len(lost_tow),
                               tuple(exposures))
        until = self.sent_until_gps_ns
        week0 = start - start % WEEK_NS

        def lost_t(tow_ms: int) -> int:
            t = week0 + tow_ms * 1_000_000
            return t + WEEK_NS if t < start else t  # the flight crossed a week boundary

        # A mark is output with the first epoch after its rising edge (sim/stream.py) and that
        # epoch's chunk follows the epoch: the mark was sent if its epoch is before the last
        # chunk written.
        interval = round(1e9 / float(truth["rate_hz"]))

        def mark_epoch(e: dict[str, Any]) -> int:
            r = int(e["rising_t_gps_ns"])
            return start + -(-(r - start) // interval) * interval

        return SentFigures(
            False, max(0.0, (until - start) / 1e9),
            sum(1 for tow in lost_tow if lost_t(int(tow)) < until),
            tuple(e for e in exposures if mark_epoch(e) < until))


class ViewSink:
    """Hands status, events and marks to a callback as bus payloads (the terminal view)."""

    name = "view"
    accepts = frozenset((Status, Event, TimeMark, LiveSolution))

    def __init__(self, on_payload: Callable[[str, bytes], None], station: str) -> None:
        self._on_payload = on_payload
        self.station = station
        self.last_status: Status | None = None
        self._marks = 0

    async def consume(self, inbox: Inbox, publish: Callable[[Item], None]) -> None:
        while True:
            try:
                item = await inbox.get()
            except InboxClosed:
                return
            if isinstance(item, Status):
                self.last_status = item
                self._on_payload("status", encode("status", item))
            elif isinstance(item, Event):
                self._on_payload("event", encode("event", item, station=self.station))
            elif isinstance(item, TimeMark):
                self._on_payload("timemark", encode("timemark", item, index=self._marks))
                self._marks += 1
            elif isinstance(item, LiveSolution):
                self._on_payload("rtk", encode("rtk", item.message(), station=self.station))


class AlertLog:
    """The alerts raised during the run, by name, and whether each was cleared since: the
    summary names those cleared before the end beside the ones standing."""

    name = "alert-log"
    accepts = frozenset((Event,))

    def __init__(self) -> None:
        self.raised: dict[str, str] = {}
        """Alert name -> its message when it was (last) raised."""
        self.standing: set[str] = set()

    async def consume(self, inbox: Inbox, publish: Callable[[Item], None]) -> None:
        while True:
            try:
                items = await inbox.get_all()
            except InboxClosed:
                return
            for item in items:
                if not isinstance(item, Event):
                    continue
                name = str(item.data.get("alert", ""))
                if item.kind == kinds.ALERT_RAISED:
                    self.raised[name] = item.message
                    self.standing.add(name)
                elif item.kind == kinds.ALERT_CLEARED:
                    self.standing.discard(name)

    def cleared(self) -> tuple[str, ...]:
        """Messages of the alerts raised and cleared again before the end, in raising order."""
        return tuple(m for n, m in self.raised.items() if n not in self.standing)


def base_station_name(station: str) -> str:
    """The demo's base station: ``<station>-base``, cut to stay a station name (64 at most)."""
    return f"{station[:59]}-base"


def _live_sink(sim: SimResult) -> tuple[LiveRtkSink | None, str]:
    """The live engine on the rover's epochs against the simulated base (its stream decoded
    as the base's daemon would); None and why when pyrtklib5 is missing."""
    try:
        return LiveRtkSink(tuple(sim.truth["base"]["ecef_m"]), measurements(sim.base_bytes)), ""
    except EngineUnavailable as err:
        log.warning("no live positions: %s", err)
        return None, str(err)


def simulate_flight(opts: DemoOptions) -> SimResult:
    """The simulated flight (rover, base, truth) of ``opts``: computed before the daemon starts,
    so that the command can check what it will write (the photos' names) first.

    Raises:
        ConfigError: the faults file.
    """
    faults = FaultConfig.load(opts.faults)
    return simulate(sim_config(opts.profile, duration_s=opts.flight_s, seed=opts.seed,
                               severity=opts.severity, faults=faults))


async def run_demo(
    opts: DemoOptions,
    *,
    sim: SimResult | None = None,
    on_payload: Callable[[str, bytes], None] | None = None,
    on_file: Callable[[Path], None] | None = None,
    ready: Callable[[dict[str, Any]], None] | None = None,
) -> DemoResult:
    """Simulate, feed the pty, run the pipeline until the flight ends, ``duration_s`` passes or
    the process is interrupted; return what happened and where it went. ``sim``: the flight
    :func:`simulate_flight` made of ``opts`` (default: simulated here)."""
    if sim is None:
        sim = simulate_flight(opts)
    settings = opts.settings or demo_settings(environ={}, overrides={
        "station": opts.station, "recorder": {"out_dir": opts.out_dir},
        "zenoh": {"enabled": opts.zenoh, "listen": list(opts.zenoh_listen),
                  "serve_after_s": opts.serve_after_s}})
    station, out_dir, zenoh = settings.station, settings.recorder.out_dir, settings.zenoh
    out_dir.mkdir(parents=True, exist_ok=True)
    feeder = PtyLink()
    source = settings.source
    settings = dataclasses.replace(settings, source=(
        dataclasses.replace(source, port=feeder.path, baud=PTY_BAUD)
        if isinstance(source, SerialSourceSettings)
        else SerialSourceSettings(port=feeder.path, baud=PTY_BAUD)))
    view = ViewSink(on_payload, station) if on_payload is not None else None
    written: list[Path] = []

    def write_companions(stem: str) -> None:
        """The base stream and the truth beside the first recording, before any data flows
        (a solver reacting to the session's end must find them)."""
        if written:
            return
        base_path = out_dir / f"{stem}_base.ubx"
        base_path.write_bytes(sim.base_bytes)
        truth_path = out_dir / f"{stem}.truth.json"
        sim.write_truth(truth_path)
        written.extend((base_path, truth_path))

    def first_file(path: Path) -> None:
        write_companions(path.stem)
        if on_file is not None:
            on_file(path)

    pipeline = Pipeline(settings, on_file=first_file)
    if view is not None:
        pipeline.add_sink(view, 1000, Overflow.DROP_OLDEST)
    alert_log = AlertLog()
    pipeline.add_sink(alert_log, 1000, Overflow.NEVER_DROP)
    live, live_missing = _live_sink(sim) if opts.live_rtk else (None, "")
    if live is not None:
        pipeline.add_sink(live, 1000, Overflow.NEVER_DROP)
    # The base receiver as a station of its own (``<station>-base``): its pty and daemon,
    # recorded beside the rover and published (``groundstation rtk --rover <station> --base
    # <station>-base`` solves from the bus). The demo's own engine takes the same stream
    # decoded in advance: at any speed each base epoch is there before the rover's.
    base_feeder = PtyLink() if opts.live_rtk else None
    base_pipeline = None
    if base_feeder is not None:
        base_pipeline = Pipeline(dataclasses.replace(
            settings, station=base_station_name(station),
            source=SerialSourceSettings(port=base_feeder.path, baud=PTY_BAUD),
            zenoh=dataclasses.replace(zenoh, mode="client", listen=(),
                                      connect=tuple(zenoh.listen))
            if zenoh.enabled else zenoh))
    stop = asyncio.Event()

    async def drained() -> None:
        """Until the feeder has stopped and the daemon has read every byte it wrote into the
        pty (a loaded machine may be seconds behind); a fixed pause lost the tail."""
        while not feeder.done.is_set():  # polled: an executor thread would block the exit
            await asyncio.sleep(0.05)
        loop = asyncio.get_running_loop()
        read, idle_since = -1, loop.time()
        while pipeline.framer.stats.bytes_in < feeder.bytes_written:
            if pipeline.framer.stats.bytes_in != read:
                read, idle_since = pipeline.framer.stats.bytes_in, loop.time()
            elif loop.time() - idle_since > DRAIN_IDLE_S:
                log.warning("the daemon stopped reading the pty with %d bytes unread",
                            feeder.bytes_written - read)
                return
            await asyncio.sleep(0.02)

    async def stop_when_fed() -> None:
        """Stop once the feed has ended (the flight sent, or cut at ``duration_s`` by the
        feeder itself) and the daemon has read what it wrote."""
        await drained()
        pipeline.stopped_by = pipeline.stopped_by or (
            f"duration {opts.duration_s:g} s" if feeder.cut_short and opts.duration_s > 0
            else "end of simulated flight")
        stop.set()

    watcher = asyncio.create_task(stop_when_fed(), name="feed-end")
    if ready is not None:
        ready({"pty": feeder.path, "out_dir": str(out_dir), "station": station,
               "base_station": base_station_name(station) if base_feeder is not None else None,
               "base_pty": base_feeder.path if base_feeder is not None else None,
               "zenoh": list(zenoh.listen) if zenoh.enabled else None,
               "flight_s": opts.flight_s, "speed": opts.speed})
    runner = asyncio.create_task(pipeline.run(stop, handle_signals=True), name="pipeline")
    if base_pipeline is not None and pipeline.publisher is not None:
        # The base's daemon is a client of this session: it starts once the session listens.
        # Started together, its first attempt could find nobody, warn "cannot open Zenoh
        # session" on the README's first command and wait 5 s to try again (1 run in 3).
        for _ in range(int(BASE_WAITS_FOR_SESSION_S / 0.01)):
            if pipeline.publisher.bus is not None or runner.done():
                break
            await asyncio.sleep(0.01)
    base_runner = (asyncio.create_task(base_pipeline.run(stop), name="base-pipeline")
                   if base_pipeline is not None else None)
    # the serial source opens the pty (and flushes its input) before the first byte is written
    for _ in range(200):
        if getattr(getattr(pipeline.source, "state", None), "connected", False):
            break
        await asyncio.sleep(0.01)
    for _ in range(200 if base_pipeline is not None else 0):
        if getattr(getattr(base_pipeline.source, "state", None), "connected", False):  # type: ignore[union-attr]
            break
        await asyncio.sleep(0.01)
    feeder.start_feed(sim.rover_chunks, opts.speed, opts.duration_s)
    if base_feeder is not None:
        base_feeder.start_feed(sim.base_chunks, opts.speed)
    try:
        summary = await runner
        base_summary = await base_runner if base_runner is not None else None
    finally:
        feeder.close()
        if base_feeder is not None:
            base_feeder.close()
        watcher.cancel()
    write_companions(summary.files[0].stem if summary.files else f"{station}_demo")
    base_path, truth_path = written
    return DemoResult(
        summary=summary, sim=sim, base_path=base_path, truth_path=truth_path,
        pty_path=feeder.path, last_status=view.last_status if view else None,
        endpoint=zenoh.listen[0] if zenoh.enabled and zenoh.listen else None,
        station=station,
        bytes_written=feeder.bytes_written,
        alerts_cleared=alert_log.cleared(),
        live=tuple(live.solutions) if live is not None else (), live_missing=live_missing,
        base_station=base_summary,
        sent_until_gps_ns=(None if feeder.chunks_written == len(sim.rover_chunks)
                           else feeder.last_t_ns if feeder.last_t_ns is not None
                           else int(sim.truth["start_gps_ns"])),
    )
