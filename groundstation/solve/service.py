"""The solver service: solves a station's session when the daemon reports it finished.

It subscribes to ``groundstation/<station>/session`` (``*`` for every station), and for each
recording of a ``finished`` session either queues a solve (when a base is configured for that
station) or says why it will not. One worker thread runs the solves one after the other, so the
Zenoh callbacks only parse, decide and enqueue; every outcome is published on
``groundstation/<station>/solution`` (``docs/zenoh.md``). Nothing a session brings (a missing
file, a failing engine) stops the service. Several services (workers) share the sessions: each
job is claimed by one of them first (:mod:`groundstation.solve.claims`); a base given as
``station:<name>`` is that station's recording of the same time
(:mod:`groundstation.solve.pairing`).

Nothing a session message says is trusted: it is parsed and range-checked
(:mod:`groundstation.messages`), its station name checked, and at most
``max_sessions_per_min`` are handled (bursts of :data:`SESSION_BURST`; the rest are dropped
unanswered). A recording is solved only if it lies inside ``recording_roots`` (:func:`confine`:
``..`` refused, symbolic links resolved; the refusal never says whether the file exists), its
outputs only under ``out_root/<station>/``, and only once by content (:func:`content_hash`).

Configuration (``config/solver.toml``): top-level keys are the defaults for every station,
``[stations.<name>]`` overrides them per station and ``[zenoh]`` says how to join the bus. Paths
may use ``{dir}`` (the recording's directory), ``{stem}`` (its name without suffix) and
``{station}``. The keys, their types and ranges, the ``GROUNDSTATION_SOLVER_*`` variables and
the precedence are :data:`groundstation.config.SOLVER`'s; this module only turns the resolved
values into :class:`ServiceSettings`.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from groundstation import messages
from groundstation.config import (
    CLIENT_ZENOH,
    SOLVER,
    SOLVER_STATION_KEYS,
    Layer,
    Resolved,
    ZenohSettings,
    check_environment,
    check_station,
    env_layer,
    merge_layers,
    resolve,
    zenoh_settings,
)
from groundstation.errors import ConfigError, GroundstationError
from groundstation.solve import interpolate as mi
from groundstation.solve.base import BASE_KEYS, base_position
from groundstation.solve.fetch import Remote, remote_for
from groundstation.solve.pairing import BASE_WAIT_S, Pairing, base_station, span_of
from groundstation.solve.pipeline import SolveResult, solve
from groundstation.solve.report_data import go_no_go
from groundstation.solve.settings import SolveSettings
from groundstation.solve.trajectory import Q_FIX

if TYPE_CHECKING:
    from groundstation.solve.claims import Claims

log = logging.getLogger("groundstation.solver")

QUEUE_SIZE = 16
"""Sessions waiting for the worker; beyond this a session is refused with a failed solution."""

STATUS_SOLVING, STATUS_OK, STATUS_FAILED, STATUS_SKIPPED = "solving", "ok", "failed", "skipped"
STATUS_REFUSED = "refused"
MAX_SESSIONS_PER_MIN = 60.0
SESSION_BURST = 20
RECORDING_SUFFIXES = (".mcap", ".ubx", ".ubx.gz", ".gz", ".log")

SOLVER_ZENOH = replace(CLIENT_ZENOH, mode="client")
"""The solver's default: a client of the daemon (or router). Not a peer: a peer that listens
nowhere reaches only the process it connects to, and a meeting point routes for its clients,
not between peers, so several peer workers would never hear each other's claims."""

Publish = Callable[[str, dict[str, Any]], None]
"""``publish(station, body)``: send one ``solution`` message for a station."""
Solver = Callable[[SolveSettings], SolveResult]


@dataclass(frozen=True, slots=True)
class StationSolve:
    """How to solve one station's sessions (``base`` and ``photos`` are path templates)."""

    base: str | None = None
    base_ecef_m: tuple[float, float, float] | None = None
    base_llh: tuple[float, float, float] | None = None
    base_en: tuple[float, float, float] | None = None
    base_crs: int | str | None = None
    base_antenna_height_m: float | None = None
    base_antenna: str | None = None
    antex: Path | None = None
    base_given: str = "given with base_xyz"
    photos: str | None = None
    out_root: Path = Path("solutions")
    lever_arm_m: tuple[float, float, float] | None = None
    interp: str = mi.DEFAULT_METHOD
    edge: str = "falling"
    epsg: int | str | None = None
    geoid: Path | None = None
    shutter_delay_ms: float = 0.0
    max_gap_s: float = mi.DEFAULT_MAX_GAP_S
    report_pdf: bool = True
    fetch: str = "auto"


@dataclass(frozen=True, slots=True)
class ServiceSettings:
    """The resolved service configuration.

    Attributes:
        bus: how to join Zenoh (by default a client of the local daemon).
        station: whose sessions to solve, ``*`` for all.
        default: settings for stations without a ``[stations.<name>]`` table.
        stations: per-station settings (defaults already merged in).
        queue_size: sessions that may wait for the worker.
        recording_roots: the only directories whose recordings are solved (resolved; a
            session naming a file elsewhere is refused).
        max_sessions_per_min: session messages handled per minute (burst
            :data:`SESSION_BURST`); more are dropped and counted.
        base_wait_s: how long a rover session paired with a base station waits for a base
            recording that covers its last epoch (:mod:`groundstation.solve.pairing`).
    """

    bus: ZenohSettings = SOLVER_ZENOH
    station: str = "*"
    default: StationSolve = field(default_factory=StationSolve)
    stations: Mapping[str, StationSolve] = field(default_factory=dict)
    queue_size: int = QUEUE_SIZE
    recording_roots: tuple[Path, ...] = (Path("flights"),)
    max_sessions_per_min: float = MAX_SESSIONS_PER_MIN
    base_wait_s: float = BASE_WAIT_S

    def for_station(self, station: str) -> StationSolve:
        """The settings that apply to ``station``."""
        return self.stations.get(station, self.default)

    def base_stations(self) -> set[str]:
        """The stations some configuration names as its base (``base = "station:<name>"``)."""
        confs = [self.default, *self.stations.values()]
        return {b for b in (base_station(c.base) for c in confs) if b is not None}


# -- configuration --------------------------------------------------------------------------

_FIELDS = {"base_xyz": "base_ecef_m", "lever_arm": "lever_arm_m"}
"""Configuration key -> :class:`StationSolve` field, where the names differ."""


def _station_solve(base: StationSolve, values: Mapping[str, Any], prefix: str,
                   station: str | None = None) -> StationSolve:
    """``base`` with converted values (:data:`~groundstation.config.SOLVER_STATION_KEYS`)
    applied; ``base`` and ``base_xyz`` must come together; ``base = "station:<name>"`` names
    a valid station other than ``station`` itself."""
    out = replace(base, **{_FIELDS.get(k, k): v for k, v in values.items()})
    if out.base is not None and not out.base:
        raise ConfigError(f"{prefix}base", "expected a non-empty path")
    base_station(out.base, f"{prefix}base", station)
    xyz, how = base_position(out.base_ecef_m, out.base_llh, out.base_antenna_height_m,
                             {k: f"{prefix}{v}" for k, v in BASE_KEYS.items()},
                             en=out.base_en, crs=out.base_crs, antenna=out.base_antenna,
                             antex_file=out.antex)
    if (out.base is None) != (xyz is None):
        missing = "base_xyz" if xyz is None else "base"
        raise ConfigError(f"{prefix}{missing}", "base and base_xyz (or base_llh) go together")
    # the antenna reference point from now on
    return replace(out, base_ecef_m=xyz, base_llh=None, base_en=None, base_crs=None,
                   base_antenna_height_m=None, base_antenna=None, antex=None,
                   base_given=how)


def _service_settings(resolved: Resolved) -> ServiceSettings:
    top = resolved.values[""]
    station = top.get("station", "*")  # checked by the resolver (config.STATION_OR_ALL)
    keys = {k: v for k, v in top.items() if k in SOLVER_STATION_KEYS}
    from_file = {k: v for k, v in keys.items() if resolved.origin.get(("", k)) == "file"}
    later = {k: v for k, v in keys.items() if k not in from_file}
    default = _station_solve(StationSolve(), keys, "")
    stations: dict[str, StationSolve] = {}
    for name, table in resolved.tables.get("stations", {}).items():
        # file defaults < the station's table < environment and command line
        merged = replace(StationSolve(), **{_FIELDS.get(k, k): v for k, v in
                                            {**from_file, **table}.items()})
        stations[name] = _station_solve(merged, later, f"stations.{name}.", name)
    if "mode" in resolved.values["zenoh"] and resolved.values["zenoh"]["mode"] == "router":
        raise ConfigError("zenoh.mode", "the solver joins as peer or client")
    roots = tuple(Path(r).expanduser() for r in top.get("recording_roots", ("flights",)))
    if not roots:
        raise ConfigError("recording_roots", "at least one directory")
    return ServiceSettings(zenoh_settings(resolved.values["zenoh"], SOLVER_ZENOH), station,
                           default, stations, top.get("queue_size", QUEUE_SIZE), roots,
                           top.get("max_sessions_per_min", MAX_SESSIONS_PER_MIN),
                           top.get("base_wait_s", BASE_WAIT_S))


def build_service_settings(
    file_layer: Mapping[str, Any] | None = None, overrides: Mapping[str, Any] | None = None,
    *, environ: Mapping[str, str] | None = None,
) -> ServiceSettings:
    """Resolve an already-read file layer < environment < command line (the configuration's
    one resolver, :func:`groundstation.config.merge_layers`, with the solver's scope).

    Args:
        file_layer: the parsed TOML file (top-level station defaults, ``[zenoh]``,
            ``[stations.<name>]``).
        overrides: command-line values with the file's key names (``base``, ``base_xyz``,
            ``station``, ``zenoh`` ...); they apply to every station.
        environ: ``GROUNDSTATION_SOLVER_*`` variables (none when ``None``).

    Raises:
        ConfigError: naming the offending key.
    """
    env = environ or {}
    check_environment(env)
    layers: list[Layer] = [(file_layer or {}, "file", False),
                           (env_layer(SOLVER, env), "environment", True)]
    if overrides:
        layers.append((overrides, "command line", False))
    return _service_settings(merge_layers(SOLVER, layers))


def load_service_settings(
    config_file: Path | None, overrides: Mapping[str, Any] | None = None,
    *, environ: Mapping[str, str] | None = None,
) -> ServiceSettings:
    """The solver's settings: defaults < TOML file (``--config`` or
    ``$GROUNDSTATION_SOLVER_CONFIG``) < ``GROUNDSTATION_SOLVER_*`` < command line.

    Raises:
        ConfigError: unreadable or invalid file, or a bad value (naming the key).
    """
    return _service_settings(resolve(SOLVER, config_file, environ=environ, overrides=overrides))


# -- deciding what to do with a session -----------------------------------------------------


@dataclass(frozen=True, slots=True)
class Job:
    """One recording to solve."""

    station: str
    session_id: str
    flight: Path
    settings: SolveSettings
    notes: tuple[str, ...] = ()
    remote: Remote | None = None
    """Fetched over the bus into ``flight`` before solving (``solve/fetch.py``)."""
    base_station: str | None = None
    """The base is this station's recording of the same time (picked when solving)."""
    span_ns: tuple[int, int] | None = None
    """First and last epoch of the recording (GPS ns), as the session message says."""


@dataclass(frozen=True, slots=True)
class Skip:
    """A recording that will not be solved, and why."""

    station: str
    session_id: str
    flight: Path
    reason: str


def _expand(template: str, flight: Path, station: str) -> Path:
    try:
        return Path(template.format(dir=flight.parent, stem=flight.stem, station=station))
    except (KeyError, IndexError, ValueError) as err:
        raise ConfigError("base/photos", f"bad path template {template!r}: {err}") from err


def _free_dir(root: Path) -> Path:
    """``root``, or ``root-2``, ``root-3`` ... whichever does not exist (never overwrite)."""
    if not root.exists():
        return root
    n = 2
    while root.with_name(f"{root.name}-{n}").exists():
        n += 1
    return root.with_name(f"{root.name}-{n}")


@dataclass(frozen=True, slots=True)
class Refusal:
    """A recording the session names that the service will not touch (outside the roots)."""

    station: str
    session_id: str
    flight: Path
    reason: str


def confine(flight: Path, roots: tuple[Path, ...]) -> tuple[Path | None, str]:
    """The recording's resolved path if it lies inside one of ``roots``, else why not.

    The check never says whether the file exists (a refusal must not probe the disk for the
    sender): ``..`` anywhere is refused as written; otherwise the path is resolved (symbolic
    links followed, relative to the working directory) and must be inside a resolved root.
    """
    if ".." in flight.parts:
        return None, "'..' in the recording path"
    if not flight.name.endswith(RECORDING_SUFFIXES):
        return None, "not a recording name (.mcap, .ubx, .ubx.gz, .log)"
    real = flight.resolve()
    for root in roots:
        r = root.resolve()
        if real != r and r in real.parents:
            return real, ""
    return None, "outside the configured recording_roots"


def plan(station: str, session: Mapping[str, Any], conf: StationSolve,
         roots: tuple[Path, ...] | None = None) -> list[Job | Skip | Refusal]:
    """What to do with one ``session`` message: nothing unless it is ``finished``; then a job
    per recording when a base is configured and the recording lies inside ``roots``
    (:func:`confine`; ``None``: not checked), else a :class:`Skip` or :class:`Refusal` that
    says why."""
    if session.get("state") != "finished":
        return []
    sid = str(session.get("session_id") or "")
    files = [Path(str(f)) for f in session.get("files") or [] if f]
    out: list[Job | Skip | Refusal] = []
    for given in files:
        if conf.base is None or conf.base_ecef_m is None:
            out.append(Skip(station, sid, given,
                            f"no base configured for station {station!r} (--base FILE "
                            f"--base-xyz X,Y,Z, or base and base_xyz in [stations.{station}])"))
            continue
        real, why = confine(given, roots) if roots is not None else (given, "")
        remote = remote_for(station, session, given, conf.out_root, real, conf.fetch)
        if remote is not None:  # the daemon serves it: fetched into out_root, then solved
            flight = remote.dest
        elif real is None:
            out.append(Refusal(station, sid, given, f"refused: {why}"))
            continue
        else:
            flight = real
        paired = base_station(conf.base)
        if paired == station:  # a top-level base = "station:x" does not apply to x itself
            out.append(Skip(station, sid, given, f"station {station!r} is its own base "
                                                 f"(base = \"station:{paired}\")"))
            continue
        out_dir = conf.out_root / station / flight.stem
        root = conf.out_root.resolve()
        if root not in out_dir.resolve().parents:  # a symbolic link under out_root leading out
            out.append(Refusal(station, sid, given, "refused: the output directory would lie "
                                                    "outside out_root"))
            continue
        notes: list[str] = []
        photos: Path | None = None
        if conf.photos is not None:
            photos = _expand(conf.photos, flight, station)
            if not photos.is_dir():
                notes.append(f"photos directory {photos} not found: solved without photos")
                photos = None
        settings = SolveSettings(
            flight=flight,
            out_dir=out_dir,
            base=None if paired else _expand(conf.base, flight, station),
            base_ecef_m=conf.base_ecef_m,
            base_given=conf.base_given,
            photos=photos,
            lever_arm_m=conf.lever_arm_m,
            epsg=conf.epsg,
            geoid=conf.geoid,
            interp=conf.interp,
            edge=conf.edge,  # type: ignore[arg-type]  # checked against mi.EDGES on load
            shutter_delay_ms=conf.shutter_delay_ms,
            max_gap_s=conf.max_gap_s,
            report_pdf=conf.report_pdf,
        )
        out.append(Job(station, sid, flight, settings, tuple(notes), remote=remote,
                       base_station=paired, span_ns=span_of(session)))
    if not files:
        out.append(Skip(station, sid, Path(), "the finished session lists no recording file"))
    return out


def quality_summary(result: SolveResult) -> dict[str, Any]:
    """Counts and accuracy figures of a solve, as plain JSON values."""
    mp = result.mark_positions
    ok = np.isfinite(mp.ecef_m[:, 0])
    sd_h = np.hypot(mp.sd_enu_m[ok, 0], mp.sd_enu_m[ok, 1])
    sd_u = mp.sd_enu_m[ok, 2]

    def med(v: np.ndarray[Any, Any]) -> float | None:
        v = v[np.isfinite(v)]
        return round(float(np.median(v)), 4) if v.size else None

    def worst(v: np.ndarray[Any, Any]) -> float | None:
        v = v[np.isfinite(v)]
        return round(float(np.max(v)), 4) if v.size else None

    fixed = int(np.sum(mp.quality == Q_FIX))
    return {
        "fixed_fraction": round(float(result.trajectory.fixed_fraction), 4),
        "marks_fixed_fraction": round(fixed / len(mp), 4) if len(mp) else None,
        "sd_horizontal_median_m": med(sd_h),
        "sd_vertical_median_m": med(sd_u),
        "sd_horizontal_max_m": worst(sd_h),
        "sd_vertical_max_m": worst(sd_u),
        "interp": mp.method,
        "source": result.trajectory.source,
    }


# -- the worker ------------------------------------------------------------------------------


def content_hash(path: Path) -> str:
    """SHA-256 of a file (a recording is solved once whatever its name)."""
    from groundstation.storage.transfer import sha256_file

    return sha256_file(path)


class SolverService:
    """Turns session messages into solves and solution messages (no Zenoh in here).

    :meth:`on_session` is meant for a Zenoh callback: it parses, decides and enqueues without
    blocking. :meth:`run` is the worker loop; it solves one job at a time until ``stop``.
    """

    def __init__(
        self,
        settings: ServiceSettings,
        publish: Publish,
        *,
        solver: Solver = solve,
        clock_ns: Callable[[], int] = time.time_ns,
        fetcher: Callable[[Remote], Path] | None = None,
    ) -> None:
        self.settings = settings
        self._fetch = fetcher
        self._publish = publish
        self._solver = solver
        self._clock_ns = clock_ns
        self._queue: queue.Queue[Job | None] = queue.Queue(maxsize=settings.queue_size)
        self._taken_up: collections.deque[Job] = collections.deque()
        """Jobs whose claimant vanished: solved before the queue (a replacement is prompt)."""
        self._seen: set[tuple[str, str, str]] = set()
        self._hashes: dict[str, Path] = {}
        """Content hash of every recording solved (or being solved) -> its path."""
        self._lock = threading.Lock()
        self._tokens = float(SESSION_BURST)
        self._tokens_at = time.monotonic()
        self.solved = 0
        self.failed = 0
        self.skipped = 0
        self.refused = 0
        self.rejected = 0
        """Session messages dropped: malformed, a bad station name, or over the rate limit."""
        self.pairing = Pairing(lambda p: confine(p, settings.recording_roots),
                               settings.base_wait_s)
        self._bases = settings.base_stations()
        self.claims: Claims | None = None
        """Shares the jobs with other workers (:mod:`~groundstation.solve.claims`), if set."""
        self._stop = threading.Event()

    def _admit(self) -> bool:
        """Token bucket: ``max_sessions_per_min``, bursts of :data:`SESSION_BURST`."""
        now = time.monotonic()
        with self._lock:
            rate = self.settings.max_sessions_per_min / 60.0
            self._tokens = min(SESSION_BURST, self._tokens + (now - self._tokens_at) * rate)
            self._tokens_at = now
            if self._tokens < 1.0:
                return False
            self._tokens -= 1.0
            return True

    def _send(self, station: str, status: str, flight: Path | None, session_id: str,
              **body: Any) -> None:
        msg = {"status": status, "station": station, "session_id": session_id,
               "flight": str(flight) if flight is not None else None,
               "t_host_ns": self._clock_ns(), **body}
        try:
            self._publish(station, msg)
        except Exception:  # a broken bus must not stop the worker
            log.exception("could not publish the %s solution of %s", status, station)

    def drop(self, station: str, why: str) -> None:
        """Count and log (sparingly) a session message that is not handled."""
        with self._lock:
            self.rejected += 1
            n = self.rejected
        if n <= 10 or n % 100 == 0:  # a flood must not flood the log too
            log.warning("session message for %r dropped (%d so far): %s", station[:80], n, why)

    def on_session(self, station: str, session: Mapping[str, Any]) -> None:
        """Handle one ``session`` message of ``station``: checked (station name, message
        fields, rate), then planned; nothing outside the recording roots is read."""
        try:
            check_station(station)
            messages.check({"type": "session", **session}, "session")
        except (ConfigError, messages.BadMessage) as err:
            self.drop(station, str(err))
            return
        if station in self._bases:  # only bases: a flood of station names keeps nothing
            self.pairing.note(station, session)
            if self.settings.for_station(station).base is None:  # a base, not to be solved
                return
        if self.settings.station not in ("*", station):  # heard only as someone's base
            return
        if not self._admit():
            self.drop(station, "over the rate limit "
                                f"({self.settings.max_sessions_per_min:g} per minute)")
            return
        try:
            actions = plan(station, session, self.settings.for_station(station),
                           self.settings.recording_roots)
        except GroundstationError as err:
            self.failed += 1
            self._send(station, STATUS_FAILED, None, str(session.get("session_id") or ""),
                       reason=str(err))
            return
        for act in actions:
            ident = (act.station, act.session_id, str(act.flight))
            with self._lock:
                if ident in self._seen:  # the daemon may repeat a finished session
                    log.debug("already handled %s", ident)
                    continue
                self._seen.add(ident)
            if isinstance(act, Skip):
                self.skipped += 1
                log.info("%s %s: not solved: %s", act.station, act.flight, act.reason)
                self._send(act.station, STATUS_SKIPPED, act.flight, act.session_id,
                           reason=act.reason)
                continue
            if isinstance(act, Refusal):
                self.refused += 1
                log.warning("%s %s: %s", act.station, act.flight, act.reason)
                self._send(act.station, STATUS_REFUSED, act.flight, act.session_id,
                           reason=act.reason)
                continue
            try:
                self._queue.put_nowait(act)
            except queue.Full:
                self.failed += 1
                self._send(act.station, STATUS_FAILED, act.flight, act.session_id,
                           reason=f"solver busy: {self._queue.qsize()} sessions already queued")
                with self._lock:
                    self._seen.discard(ident)
                continue
            log.info("%s %s: queued (%d waiting)", act.station, act.flight, self._queue.qsize())

    def run(self, stop: threading.Event) -> None:
        """Solve queued jobs one by one until ``stop`` is set (or :meth:`close` is called);
        with :attr:`claims`, only the jobs this worker claims."""
        self._stop = stop
        while not stop.is_set():
            try:
                job = self._taken_up.popleft() if self._taken_up else self._queue.get(
                    timeout=0.2)
            except queue.Empty:
                continue
            if job is None:
                return
            claims = self.claims
            if claims is None:
                self.solve_job(job)
                continue
            from groundstation.solve.claims import job_key

            ident = job_key(job.station, job.session_id, job.flight)
            if claims.acquire(ident, job, job.settings.out_dir):
                try:
                    self.solve_job(job)
                finally:
                    claims.release(ident)

    def requeue(self, job: Job) -> None:
        """Hand a job back to the worker (a claim on it vanished): it comes next."""
        self._taken_up.append(job)

    def close(self) -> None:
        """Wake the worker so that it returns."""
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait(None)

    def solve_job(self, job: Job) -> None:
        """Solve one recording and publish the outcome (ok or failed); never raises."""
        # Shared by workers: one directory per recording, overwritten by a replacement worker.
        out_dir = job.settings.out_dir if self.claims else _free_dir(job.settings.out_dir)
        s = replace(job.settings, out_dir=out_dir)
        notes = list(job.notes)
        self._send(job.station, STATUS_SOLVING, job.flight, job.session_id,
                   out_dir=str(s.out_dir))
        t0 = time.monotonic()
        digest = ""
        try:
            if job.remote is not None:
                if self._fetch is None:
                    raise GroundstationError(f"{job.remote.name}: not readable here and no bus "
                                             "to fetch it over")
                self._fetch(job.remote)
            if not job.flight.is_file():
                raise GroundstationError(f"{job.flight}: recording not found")
            digest = content_hash(job.flight)
            with self._lock:
                first = self._hashes.get(digest)
                if first is None:
                    self._hashes[digest] = job.flight
            if first is not None:  # the same bytes, whatever the name or session
                digest = ""  # not ours to forget
                self.skipped += 1
                self._send(job.station, STATUS_SKIPPED, job.flight, job.session_id,
                           reason=f"already solved: same content as {first}")
                return
            if job.base_station is not None:
                s = replace(s, base=self.pairing.base_for(job.base_station, job.span_ns,
                                                          self._stop, notes))
            if s.base is not None and not s.base.is_file():
                raise GroundstationError(f"{s.base}: base recording not found")
            result = self._solver(s)
        except Exception as err:  # any failure is reported; the service goes on
            self.failed += 1
            with self._lock:  # a failed recording may be solved again (a base added ...)
                if digest and self._hashes.get(digest) == job.flight:
                    del self._hashes[digest]
            if not isinstance(err, GroundstationError):
                log.exception("%s %s: solve crashed", job.station, job.flight)
            else:
                log.warning("%s %s: solve failed: %s", job.station, job.flight, err)
            self._send(job.station, STATUS_FAILED, job.flight, job.session_id,
                       reason=f"{type(err).__name__}: {err}", out_dir=str(s.out_dir),
                       elapsed_s=round(time.monotonic() - t0, 3), notes=notes)
            return
        self.solved += 1
        summary = result.summary()
        files = summary.pop("files")
        notes = [*notes, *summary.pop("notes")]  # type: ignore[misc]
        elapsed = time.monotonic() - t0
        log.info("%s %s: solved in %.1f s: %s marks, %s positioned, %.0f%% epochs fixed",
                 job.station, job.flight, elapsed, summary["marks"], summary["marks_positioned"],
                 100 * float(summary["fixed_fraction"]))  # type: ignore[arg-type]
        reports = {p.name: str(p) for p in result.files}
        self._send(job.station, STATUS_OK, job.flight, job.session_id, out_dir=str(s.out_dir),
                   files=files, counts=summary, quality=quality_summary(result), notes=notes,
                   go_no_go=go_no_go(result.rows),
                   report=reports.get("report.html"), report_pdf=reports.get("report.pdf"),
                   elapsed_s=round(elapsed, 3))


# -- running it on the bus ------------------------------------------------------------------


OPEN_RETRY_S = 2.0
"""A client solver started before its daemon or router tries again this often."""


def _open_bus_when_reachable(bus_settings: ZenohSettings, stop: threading.Event) -> Any:
    """The open bus; a client whose endpoints nobody listens on yet waits for one (a solver
    service may start before the daemons), ``None`` if stopped meanwhile.

    Raises:
        GroundstationError: any other failure (a peer's listener, TLS files ...).
    """
    from groundstation.bus import open_bus

    said = False
    while True:
        try:
            return open_bus(bus_settings)
        except GroundstationError as err:
            if bus_settings.mode != "client" or "Unable to connect" not in str(err):
                raise
            if not said:
                said = True
                log.info("waiting for a daemon or router on %s (retrying every %g s)",
                         ", ".join(bus_settings.connect), OPEN_RETRY_S)
        if stop.wait(OPEN_RETRY_S):
            return None


def run_service(
    settings: ServiceSettings,
    stop: threading.Event,
    *,
    solver: Solver = solve,
    ready: Callable[[str], None] | None = None,
) -> SolverService:
    """Join Zenoh, subscribe to sessions, solve until ``stop`` is set; returns the service.

    Several such workers share the sessions (:mod:`groundstation.solve.claims`): each job is
    claimed by one of them; base stations' sessions are followed for pairing.

    Raises:
        GroundstationError: the Zenoh session cannot be opened.
    """
    from groundstation.bus import encode, key
    from groundstation.solve.claims import Claims
    from groundstation.solve.fetch import Fetcher
    from groundstation.solve.solutions import LatestSolutions

    bus = _open_bus_when_reachable(settings.bus, stop)
    if bus is None:  # stopped before the daemon or router was there
        return SolverService(settings, lambda *_: None, solver=solver)
    claims: Claims | None = None
    try:
        latest = LatestSolutions()  # answered on q/solution for late joiners

        def publish(station: str, body: dict[str, Any]) -> None:
            if claims is not None:
                body = {**body, "worker": claims.worker}  # who solved it, among the workers
            payload = encode("solution", body)
            latest.keep(station, body, payload)
            bus.put(key(station, "solution"), payload)
            if claims is not None:
                claims.record(station, body)

        bus.answer(key(settings.station, "q/solution"), latest.answer)
        service = SolverService(settings, publish, solver=solver,
                                fetcher=Fetcher(bus).fetch)
        claims = service.claims = Claims(bus, service.requeue)
        claims.start()

        def ask_session(station: str) -> dict[str, Any] | None:
            for _, payload in bus.get(key(station, "q/session"), timeout_s=1.0):
                with contextlib.suppress(messages.BadMessage):
                    return messages.parse(payload, "session")
            return None

        service.pairing.ask = ask_session

        def on_sample(key_expr: str, payload: bytes) -> None:
            parts = key_expr.split("/")
            if len(parts) != 3:
                return
            try:
                msg = messages.parse(payload, "session")
            except messages.BadMessage as err:
                service.drop(parts[1], f"{key_expr}: {err}")
                return
            service.on_session(parts[1], msg)

        selector = key(settings.station, "session")
        bus.subscribe(selector, on_sample)
        if settings.station != "*":  # the paired base stations' sessions, for pairing only
            for base in sorted(settings.base_stations() - {settings.station}):
                bus.subscribe(key(base, "session"), on_sample)
        worker = threading.Thread(target=service.run, args=(stop,), name="solver-worker",
                                  daemon=True)
        worker.start()
        log.info("listening on %s (connect %s, listen %s); worker %s", selector,
                 list(settings.bus.connect), list(settings.bus.listen), claims.worker)
        if ready is not None:
            ready(selector)
        while not stop.wait(0.5):  # a timed wait, so signals are handled promptly
            continue
        service.close()
        claims.close()
        worker.join(timeout=5.0)
        if worker.is_alive():
            log.warning("a solve is still running; leaving it to the process exit")
        return service
    finally:
        bus.close()
