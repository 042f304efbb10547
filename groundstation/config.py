"""Every command's settings and the one resolver: defaults < TOML file < environment < command line.

A command's configuration is a :class:`Scope`: a schema of sections and keys (each a :class:`Key`
with its type and range), the prefix of its environment variables and the variable naming its
file. :func:`resolve` merges the layers of one scope into plain values, checking every key
against the schema (an unknown key is an error, never ignored), converting and range-checking
each value (numbers must be finite), and raising :class:`~groundstation.errors.ConfigError`
naming the dotted key (and the variable, for the environment); the command line turns that into
exit status 2. The scopes:

- :data:`DAEMON` (``run``, ``demo`` and ``replay``, each with its own defaults):
  ``GROUNDSTATION_<KEY>``, ``GROUNDSTATION_<SECTION>_<KEY>`` (``GROUNDSTATION_SOURCE_BAUD``),
  file ``--config`` or ``GROUNDSTATION_CONFIG``; :func:`load_settings` gives :class:`Settings`.
- :data:`SOLVER` (``solver``): ``GROUNDSTATION_SOLVER_<KEY>``,
  ``GROUNDSTATION_SOLVER_ZENOH_<KEY>``, file ``GROUNDSTATION_SOLVER_CONFIG``; per-station
  ``[stations.<name>]`` tables come from the file only (``solve/service.py`` builds them).
- :data:`WATCH` and :data:`DASHBOARD`: ``GROUNDSTATION_WATCH_*``, ``GROUNDSTATION_DASHBOARD_*``.
- :data:`ROUTER` (``router``): ``GROUNDSTATION_ROUTER_<KEY>``, ``GROUNDSTATION_ROUTER_TLS_<KEY>``,
  ``GROUNDSTATION_ROUTER_ACCESS_<KEY>``, file ``GROUNDSTATION_ROUTER_CONFIG``; per-station
  ``[stations.<name>]`` tables from the file only; :func:`load_router_settings` gives
  :class:`RouterSettings`.

Every ``GROUNDSTATION_*`` variable must name a setting of some scope: a misspelt variable is an
error, whichever command reads the environment. The Zenoh endpoint default,
:data:`DEFAULT_ENDPOINT`, is written here and nowhere else.
"""

from __future__ import annotations

import importlib
import math
import os
import re
import stat
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from groundstation import jsonio
from groundstation.errors import ConfigError

ENV_PREFIX = "GROUNDSTATION_"
ENV_CONFIG_FILE = "GROUNDSTATION_CONFIG"

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where the daemon listens and the views and the solver connect by default: loopback only."""

VALID_BAUDS: tuple[int, ...] = (
    1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600
)
"""Rates the u-blox UART and the Wi232 radios can be set to."""

SourceKind = Literal["serial", "tcp", "file"]


@dataclass(frozen=True, slots=True)
class SerialSourceSettings:
    """A serial device (USB radio modem), 8N1."""

    port: str
    baud: int = 115200
    read_size_bytes: int = 4096
    reconnect_min_s: float = 0.05
    reconnect_max_s: float = 1.0
    stall_check_s: float = 0.5
    kind: Literal["serial"] = "serial"


@dataclass(frozen=True, slots=True)
class TcpSourceSettings:
    """A TCP server streaming UBX (RTKLIB ``str2str``, u-center's server)."""

    host: str
    port: int
    read_size_bytes: int = 4096
    reconnect_min_s: float = 0.05
    reconnect_max_s: float = 2.0
    connect_timeout_s: float = 5.0
    kind: Literal["tcp"] = "tcp"


@dataclass(frozen=True, slots=True)
class FileSourceSettings:
    """A ``.ubx``, ``.ubx.gz`` or ``.mcap`` recording, paced at ``rate_bytes_per_s`` (0 = as fast
    as possible)."""

    path: Path
    rate_bytes_per_s: float = 0.0
    read_size_bytes: int = 4096
    kind: Literal["file"] = "file"


SourceSettings = SerialSourceSettings | TcpSourceSettings | FileSourceSettings


@dataclass(frozen=True, slots=True)
class RecorderSettings:
    """Where and how the session is recorded.

    Attributes:
        out_dir: directory for the MCAP files and their ``.ubx`` sidecars.
        rotate_size_mb: start a new file when the MCAP exceeds this size (0 = never).
        rotate_duration_s: start a new file after this long (0 = never). A file is also
            rotated after 43 200 MCAP chunks (6 hours at a 0.5 s flush interval), because
            the MCAP writer holds an index entry per chunk in memory until the file is finished.
        flush_interval_s: close the chunk and flush MCAP and sidecar at least this often.
        chunk_size_bytes: MCAP chunk size target (small, so a crash loses little).
        compression: MCAP chunk compression: ``zstd``, ``lz4`` or ``none``.
        sidecar: also write the raw bytes to a ``.ubx`` file.
        backlog_mb: while writing fails (disk full), hold up to this much in memory; beyond
            it decoded records, then new raw bytes, are dropped and counted.
        retry_s: how often writing is tried again after a failure.
    """

    out_dir: Path = Path("flights")
    rotate_size_mb: float = 0.0
    rotate_duration_s: float = 0.0
    flush_interval_s: float = 0.5
    chunk_size_bytes: int = 64 * 1024
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    sidecar: bool = True
    backlog_mb: float = 64.0
    retry_s: float = 2.0


@dataclass(frozen=True, slots=True)
class QueueSettings:
    """Per-sink queue bounds. Recorder: never drops (beyond the bound it alerts);
    monitor and publisher: drop the oldest item and count."""

    recorder: int = 10_000
    monitor: int = 2_000
    publisher: int = 2_000


@dataclass(frozen=True, slots=True)
class FramerSettings:
    max_payload_bytes: int = 8192


@dataclass(frozen=True, slots=True)
class ZenohSettings:
    """How a command joins Zenoh: the one settings type for the daemon, the views and the solver.

    The defaults are the daemon's: a peer listening on loopback only, no multicast scouting.
    Clients (``watch``, ``dashboard``, ``solver``) start from :data:`CLIENT_ZENOH`: they listen
    nowhere and connect to the daemon. An empty ``listen`` means no listener at all (the bus
    never lets Zenoh fall back to its own default of every interface).

    Attributes:
        enabled: publish at all (the daemon's ``--no-zenoh``).
        mode: ``peer``, ``client`` or ``router``.
        listen: endpoints to listen on.
        connect: endpoints to connect to (a router, the daemon).
        scouting: multicast scouting.
        publish_epochs: the daemon also puts every raw epoch on ``.../epoch``.
        publish_obs: the daemon puts every epoch's measurements and every navigation subframe
            on ``.../obs``, compactly (:mod:`groundstation.live.obswire`), for a live engine.
        publish_raw: the daemon also puts every raw chunk on ``.../ubx``.
        tls_ca: the CA certificate (PEM) that ``tls/`` endpoints are checked against.
        tls_certificate: this process's certificate (PEM, X.509 v3) for mutual TLS: presented
            to a router that asks for one (``docs/security.md``); its common name is who the
            router's access control sees.
        tls_private_key: the certificate's private key (PEM).
        serve_recordings: the daemon answers chunk queries for its finished recording files
            (``q/recording/<session_id>``, ``docs/zenoh.md``).
        serve_after_s: after its session ends, the daemon keeps serving the session's files
            this long at most (0: it exits at once), ending earlier once every file was sent in
            full, or at a second Ctrl-C / SIGTERM.
    """

    enabled: bool = True
    mode: Literal["peer", "client", "router"] = "peer"
    listen: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    connect: tuple[str, ...] = ()
    scouting: bool = False
    publish_epochs: bool = False
    publish_obs: bool = True
    publish_raw: bool = False
    tls_ca: Path | None = None
    tls_certificate: Path | None = None
    tls_private_key: Path | None = None
    serve_recordings: bool = True
    serve_after_s: float = 0.0


CLIENT_ZENOH = ZenohSettings(listen=(), connect=(DEFAULT_ENDPOINT,))
"""A view's or the solver's default: no listener, connect to the local daemon."""


@dataclass(frozen=True, slots=True)
class MonitorSettings:
    """The real-time monitor: whether it runs, and its alert thresholds (the monitor takes
    this record as its thresholds)."""

    enabled: bool = True
    dropout_alert_s: float = 2.0
    ppk_ready_min: int = 5
    clean_phase_s: float = 30.0
    half_cycle_fraction_max: float = 0.3
    no_data_s: float = 3.0
    disk_free_min_mb: float = 500.0
    elevation_mask_deg: float = 15.0
    marks_missed_hold_s: float = 0.0
    no_frames_s: float = 5.0


@dataclass(frozen=True, slots=True)
class Settings:
    """Everything the daemon needs, resolved and validated."""

    source: SourceSettings
    station: str = "station"
    receiver: str = "u-blox LEA-6T"
    duration_s: float = 0.0
    status_interval_s: float = 1.0
    recorder: RecorderSettings = RecorderSettings()
    queues: QueueSettings = QueueSettings()
    framer: FramerSettings = FramerSettings()
    zenoh: ZenohSettings = ZenohSettings()
    monitor: MonitorSettings = MonitorSettings()

    def to_jsonable(self) -> dict[str, Any]:
        """Plain JSON values (paths as strings), for the MCAP metadata record."""
        out: dict[str, Any] = jsonio.plain(self)
        return out




# -- the schema ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Key:
    """One setting's type and range.

    Attributes:
        kind: ``str``, ``int``, ``float``, ``bool``, ``path``, ``strlist``, ``endpoints``
            (Zenoh endpoints), ``station`` / ``stations`` / ``station_or_all`` (station names,
            :data:`STATION_NAME`), ``triple`` (three numbers ``X,Y,Z``) or ``epsg`` (a code).
        lo: smallest value (numbers; for ``int``/``float`` only).
        hi: largest value.
        lo_open: ``lo`` itself is not allowed (``> lo`` rather than ``>= lo``).
        choices: the allowed values (strings and integers).
        choices_from: ``module:NAME`` of the collection that owns the allowed values, read
            when a value is checked (the solver's interpolators and edges live with the solver,
            whose imports the daemon should not pay for).
    """

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[Any, ...] = ()
    choices_from: str = ""

    def allowed(self) -> tuple[Any, ...]:
        """The allowed values (empty: any)."""
        if not self.choices_from:
            return self.choices
        module, _, name = self.choices_from.partition(":")
        return tuple(getattr(importlib.import_module(module), name))


def _num(kind: str, lo: float | None = None, hi: float | None = None, *,
         above: float | None = None) -> Key:
    """A number ``lo <= v <= hi`` (or ``above < v <= hi``)."""
    if above is not None:
        return Key(kind, above, hi, lo_open=True)
    return Key(kind, lo, hi)


STR, BOOL, PATH, STRLIST = Key("str"), Key("bool"), Key("path"), Key("strlist")
STATION, STATIONS, STATION_OR_ALL = Key("station"), Key("stations"), Key("station_or_all")
"""A station name (:func:`check_station`), a list of them, or one name or ``*`` (the solver)."""
ENDPOINTS, TRIPLE, EPSG = Key("endpoints"), Key("triple"), Key("epsg")
ECEF = Key("ecef")
"""A point near the Earth's surface in ECEF metres (catches lat,lon,h given instead)."""
ECEF_NORM_M = (6_300_000.0, 6_400_000.0)
"""|X,Y,Z| of a ground point: between the polar radius less 56 km and the equator plus 22 km."""
DURATION = _num("float", 0.0, 10 * 365 * 86_400.0)
"""How long to run: 0 = until stopped."""
SECONDS = _num("float", above=0, hi=86_400.0)
"""A timer: positive and at most a day (a zero or tiny timer would spin the event loop)."""


def _choice(*values: Any) -> Key:
    return Key("int" if all(isinstance(v, int) for v in values) else "str", choices=values)


ZENOH_KEYS: dict[str, Key] = {
    "mode": _choice("peer", "client", "router"),
    "listen": ENDPOINTS,
    "connect": ENDPOINTS,
    "scouting": BOOL,
    "tls_ca": PATH,
    "tls_certificate": PATH,
    "tls_private_key": PATH,
}
"""The ``[zenoh]`` table every scope shares (the daemon adds its publishing switches)."""

Schema = Mapping[str, Mapping[str, Key]]

DAEMON_SCHEMA: Schema = {
    "": {
        "station": STATION,
        "receiver": STR,
        "duration_s": DURATION,
        # at least 20 Hz: a smaller interval livelocks the daemon (issue 17)
        "status_interval_s": _num("float", 0.05, 3600.0),
    },
    "source": {
        "type": _choice("serial", "tcp", "file"),
        "port": STR,
        "baud": _choice(*VALID_BAUDS),
        "address": STR,
        "path": PATH,
        "rate_bytes_per_s": _num("float", 0.0, 1e10),
        # one read's buffer: a huge one is allocated and fails on every read (issue 17)
        "read_size_bytes": _num("int", 1, 1 << 20),
        "reconnect_min_s": _num("float", 0.001, 3600.0),
        "reconnect_max_s": _num("float", 0.001, 3600.0),
        "stall_check_s": _num("float", 0.01, 3600.0),
        "connect_timeout_s": _num("float", 0.01, 600.0),
    },
    "recorder": {
        "out_dir": PATH,
        "rotate_size_mb": _num("float", 0.0, 1e7),
        "rotate_duration_s": _num("float", 0.0, 1e8),
        # at most 1 s: a crash must lose little (DESIGN.md)
        "flush_interval_s": _num("float", 0.01, 1.0),
        "chunk_size_bytes": _num("int", 256, 1 << 28),
        "compression": _choice("zstd", "lz4", "none"),
        "sidecar": BOOL,
        "backlog_mb": _num("float", above=0.0, hi=1e6),
        "retry_s": _num("float", 0.01, 3600.0),
    },
    "queues": {name: _num("int", 1, 10_000_000) for name in ("recorder", "monitor", "publisher")},
    "framer": {"max_payload_bytes": _num("int", 1, 65535)},
    "zenoh": {
        "enabled": BOOL,
        **ZENOH_KEYS,
        "publish_epochs": BOOL,
        "publish_obs": BOOL,
        "publish_raw": BOOL,
        "serve_recordings": BOOL,
        "serve_after_s": _num("float", 0.0, 86_400.0),
    },
    "monitor": {
        "enabled": BOOL,
        "dropout_alert_s": SECONDS,
        "ppk_ready_min": _num("int", 0, 1000),
        "clean_phase_s": SECONDS,
        "half_cycle_fraction_max": _num("float", above=0.0, hi=1.0),
        "no_data_s": SECONDS,
        "disk_free_min_mb": _num("float", 0.0, 1e9),
        "elevation_mask_deg": _num("float", 0.0, 90.0),
        "marks_missed_hold_s": _num("float", 0.0, 86_400.0),
        "no_frames_s": SECONDS,
    },
}
"""Every key the daemon's configuration accepts, by section ("" = top level)."""

SOLVER_STATION_KEYS: dict[str, Key] = {
    "base": STR,
    "base_xyz": ECEF,
    "base_llh": TRIPLE,
    "base_en": TRIPLE,
    "base_crs": EPSG,
    "base_antenna_height_m": _num("float", 0.0, 100.0),
    "base_antenna": STR,
    "antex": PATH,
    "photos": STR,
    "out_root": PATH,
    "lever_arm": TRIPLE,
    "interp": Key("str", choices_from="groundstation.solve.interpolate:INTERPOLATORS"),
    "edge": Key("str", choices_from="groundstation.solve.interpolate:EDGES"),
    "epsg": EPSG,
    "geoid": PATH,
    "shutter_delay_ms": _num("float", -10_000.0, 10_000.0),
    "max_gap_s": _num("float", above=0.0, hi=3600.0),
    "report_pdf": BOOL,  # print report.pdf with Chromium (false: report.html only)
    # fetch the recording over the bus: when not readable here (auto), always, never
    "fetch": _choice("auto", "always", "never"),
}
"""What may differ per station in the solver (top-level defaults, ``[stations.<name>]``)."""

SOLVER_SCHEMA: Schema = {
    "": {"station": STATION_OR_ALL, "queue_size": _num("int", 1, 10_000),
         "recording_roots": STRLIST, "max_sessions_per_min": _num("float", above=0.0, hi=1e4),
         "base_wait_s": _num("float", 0.0, 86_400.0),
         **SOLVER_STATION_KEYS},
    "zenoh": ZENOH_KEYS,
}

WATCH_SCHEMA: Schema = {
    "": {"station": STATION, "duration_s": _num("float", 0.0, 10 * 365 * 86_400.0)},
    "zenoh": ZENOH_KEYS,
}

RTK_SCHEMA: Schema = {
    "": {"rover": STATION, "base": STATION,
         **{k: SOLVER_STATION_KEYS[k] for k in (
             "base_xyz", "base_llh", "base_en", "base_crs", "base_antenna_height_m",
             "base_antenna", "antex")},
         "duration_s": _num("float", 0.0, 10 * 365 * 86_400.0)},
    "zenoh": ZENOH_KEYS,
}

DASHBOARD_SCHEMA: Schema = {
    "": {
        "stations": STATIONS,
        "bind": STR,
        "port": _num("int", 0, 65535),
        "ppk_min": _num("int", 0, 1000),
        "duration_s": DURATION,
    },
    "zenoh": ZENOH_KEYS,
}


@dataclass(frozen=True, slots=True)
class Scope:
    """One command's configuration: its keys, its environment prefix, its free-form tables.

    Attributes:
        name: the command (for messages).
        schema: sections and keys.
        env_prefix: ``GROUNDSTATION_`` plus the command's own part, if any.
        tables: file-only tables of named tables (the solver's ``stations``), each checked
            against these keys of the top-level section.
    """

    name: str
    schema: Schema
    env_prefix: str = ENV_PREFIX
    tables: Mapping[str, Mapping[str, Key]] = field(default_factory=dict)

    @property
    def config_variable(self) -> str:
        """The variable that names the configuration file."""
        return self.env_prefix + "CONFIG"

    def variables(self) -> dict[str, tuple[str, str]]:
        """Environment variable -> (section, key)."""
        out: dict[str, tuple[str, str]] = {}
        for section, keys in self.schema.items():
            for k in keys:
                out[self.env_prefix + (f"{section}_{k}" if section else k).upper()] = (section, k)
        return out


DAEMON = Scope("run", DAEMON_SCHEMA)
SOLVER = Scope("solver", SOLVER_SCHEMA, ENV_PREFIX + "SOLVER_",
               tables={"stations": SOLVER_STATION_KEYS})
WATCH = Scope("watch", WATCH_SCHEMA, ENV_PREFIX + "WATCH_")
DASHBOARD = Scope("dashboard", DASHBOARD_SCHEMA, ENV_PREFIX + "DASHBOARD_")
RTK = Scope("rtk", RTK_SCHEMA, ENV_PREFIX + "RTK_")

ROUTER_STATION_KEYS: dict[str, Key] = {"cert_common_names": STRLIST}
"""A ``[stations.<name>]`` table of the router: the certificate common names that speak for
the station (default: the station's name)."""

ROUTER_SCHEMA: Schema = {
    "": {"listen": ENDPOINTS, "connect": ENDPOINTS, "scouting": BOOL, "duration_s": DURATION},
    "tls": {"ca": PATH, "certificate": PATH, "private_key": PATH, "mtls": BOOL},
    "access": {"enabled": BOOL, "local": BOOL, "solvers": STRLIST, "viewers": STRLIST},
}
ROUTER = Scope("router", ROUTER_SCHEMA, ENV_PREFIX + "ROUTER_",
               tables={"stations": ROUTER_STATION_KEYS})
SCOPES: tuple[Scope, ...] = (DAEMON, SOLVER, WATCH, DASHBOARD, ROUTER, RTK)


def known_variables() -> frozenset[str]:
    """Every ``GROUNDSTATION_*`` variable some command reads."""
    names: set[str] = set()
    for scope in SCOPES:
        names.update(scope.variables())
        names.add(scope.config_variable)
    return frozenset(names)


# -- converting and checking one value -----------------------------------------------------

_ENDPOINT = re.compile(
    r"^(?:(?:tcp|udp|tls|quic|ws)/(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+):[0-9]{1,5}"
    r"|unixsock-stream/[^?#\s]+|unixpipe/[^?#\s]+)(?:\?[^#\s]*)?(?:#\S*)?$"
)


def _endpoint(value: str) -> str:
    if not _ENDPOINT.match(value):
        raise ValueError(f"{value!r} is not a Zenoh endpoint (e.g. {DEFAULT_ENDPOINT})")
    port = value.split("?")[0].split("#")[0].rpartition(":")[2]
    if value.startswith(("tcp/", "udp/", "tls/", "quic/", "ws/")) and not 0 <= int(port) < 65536:
        raise ValueError(f"{value!r}: port must be 0..65535")
    return value


STATION_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
"""The one station alphabet: a letter or digit, then letters, digits, ``_ . -``; at most 64.

A station names files (``<station>_<time>.mcap``, ``<out_root>/<station>/``) and Zenoh keys
(``groundstation/<station>/...``), so nothing that is a path separator, ``..``, a Zenoh wildcard
or special character (``* ** $ # ?``), a space or a control character may appear in it."""


def check_station(name: object, key: str = "station") -> str:
    """``name`` if it is a valid station name.

    Raises:
        ConfigError: naming ``key``, with the rule.
    """
    try:
        return _station_text(name)
    except ValueError as err:
        raise ConfigError(key, str(err)) from err


def _station_text(value: Any) -> str:
    if not isinstance(value, str) or not STATION_NAME.fullmatch(value):
        raise ValueError(f"{value!r} is not a station name (1-64 characters: letters, digits, "
                         "'_', '.', '-'; starting with a letter or digit)")
    return value


def _number_text(value: Any, *, from_text: bool) -> Any:
    if isinstance(value, bool) or (isinstance(value, str) and not from_text):
        raise ValueError(f"expected a number, got {value!r}")
    return value


def _parse(spec: Key, value: Any, *, from_text: bool) -> Any:
    """``value`` converted to ``spec.kind`` (``from_text`` for environment strings)."""
    kind = spec.kind
    if kind == "bool":
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower() if from_text else None
        if text in {"1", "true", "yes", "on"}:
            return True
        if text in {"0", "false", "no", "off"}:
            return False
        raise ValueError(f"expected true or false, got {value!r}")
    if kind == "int":
        _number_text(value, from_text=from_text)
        if isinstance(value, float) and not from_text:
            raise ValueError(f"expected an integer, got {value!r}")
        return int(str(value).strip()) if isinstance(value, str) else int(value)
    if kind == "float":
        v = float(_number_text(value, from_text=from_text))
        if not math.isfinite(v):
            raise ValueError(f"expected a finite number, got {value!r}")
        return v
    if kind == "str":
        if not isinstance(value, str):
            raise ValueError(f"expected a string, got {value!r}")
        return value
    if kind == "station":
        return _station_text(value)
    if kind == "station_or_all":
        return value if value == "*" else _station_text(value)
    if kind == "path":
        if not isinstance(value, (str, Path)) or not str(value):
            raise ValueError(f"expected a path, got {value!r}")
        return Path(value).expanduser()
    if kind in ("strlist", "endpoints", "stations"):
        if isinstance(value, str):  # environment: comma-separated; a file may give one string
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ValueError(f"expected a list of strings, got {value!r}")
        if kind == "stations":
            return tuple(_station_text(v) for v in value)
        return tuple(_endpoint(v) for v in value) if kind == "endpoints" else tuple(value)
    if kind == "ecef":
        xyz = _parse(TRIPLE, value, from_text=from_text)
        norm = math.sqrt(sum(v * v for v in xyz))
        if not ECEF_NORM_M[0] <= norm <= ECEF_NORM_M[1]:
            hint = (" (this looks like latitude,longitude,height: give those with --base-llh,"
                    " or base_llh in the configuration)"
                    if abs(xyz[0]) <= 90 and abs(xyz[1]) <= 360 else "")
            raise ValueError(f"{value!r} is {norm / 1000:,.1f} km from the Earth's centre, not "
                             f"on its surface: expected ECEF metres X,Y,Z{hint}")
        return xyz
    if kind == "triple":
        if isinstance(value, str):
            value = [v for v in value.replace(" ", "").split(",") if v]
        if (not isinstance(value, (list, tuple)) or len(value) != 3
                or any(isinstance(v, bool) for v in value)):
            raise ValueError(f"expected three numbers separated by commas, got {value!r}")
        out = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in out):
            raise ValueError(f"expected finite numbers, got {value!r}")
        return out
    if kind == "epsg":
        text = str(value).strip().upper().removeprefix("EPSG:")
        parts = text.split("+")
        if isinstance(value, bool) or len(parts) > 2 or not all(p.isdigit() for p in parts):
            raise ValueError(f"expected an EPSG code number (or horizontal+vertical, as "
                             f"32629+5773), got {value!r}")
        return int(text) if len(parts) == 1 else f"{int(parts[0])}+{int(parts[1])}"
    raise ValueError(f"no converter for {kind!r}")  # pragma: no cover


def convert(spec: Key, name: str, value: Any, *, from_text: bool = False, origin: str = "") -> Any:
    """One value converted and range-checked.

    Args:
        spec: the key's type and range.
        name: the dotted key, for the message.
        value: the value as the layer holds it.
        from_text: the value is text to parse (an environment variable).
        origin: where it came from, added to the message (``environment GROUNDSTATION_X``).

    Raises:
        ConfigError: naming ``name`` (and ``origin``).
    """
    where = f" ({origin})" if origin else ""
    try:
        out = _parse(spec, value, from_text=from_text)
    except (TypeError, ValueError, OverflowError) as err:
        raise ConfigError(name, f"{err}{where}") from err
    allowed = spec.allowed()
    if allowed and out not in allowed:
        raise ConfigError(name, f"{out!r} is not one of {', '.join(map(str, allowed))}{where}")
    if spec.kind in ("int", "float"):
        low_bad = spec.lo is not None and (out <= spec.lo if spec.lo_open else out < spec.lo)
        if low_bad or (spec.hi is not None and out > spec.hi):
            unit = name.endswith("_bytes")
            low = ("" if spec.lo is None
                   else f"{'>' if spec.lo_open else '>='} {bound_text(spec.lo, bytes_=unit)}")
            high = "" if spec.hi is None else f"<= {bound_text(spec.hi, bytes_=unit)}"
            rule = " and ".join(r for r in (low, high) if r)
            raise ConfigError(name, f"must be {rule}, got {out!r}{where}")
    return out


def bound_text(value: float, *, bytes_: bool = False) -> str:
    """A bound as a person writes it: ``1048576``, ``3600``, ``0.05``, never ``1.04858e+06``
    (``:g`` keeps 6 digits); a byte count of whole KiB, MiB or GiB also in those units
    (``268435456 (256 MiB)``)."""
    if isinstance(value, int) or (math.isfinite(value) and value.is_integer()
                                  and abs(value) < 1e18):
        n = int(value)
        text = str(n)
        if bytes_ and n >= 1024:
            for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
                if n % size == 0:
                    return f"{text} ({n // size} {unit})"
        return text
    return repr(float(value))  # the shortest text that reads back as the same float


def _dotted(section: str, key: str) -> str:
    return f"{section}.{key}" if section else key


# -- reading the layers --------------------------------------------------------------------


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML configuration file (no validation of its keys yet).

    Raises:
        ConfigError: key ``config``, one line: missing, not a regular file (a directory or a
            FIFO, which would block), unreadable, not UTF-8 or not TOML.
    """
    try:
        info = path.stat()
    except FileNotFoundError as err:
        raise ConfigError("config", f"file not found: {path}") from err
    except OSError as err:
        raise ConfigError("config", f"{path}: {err.strerror or err}") from err
    if not stat.S_ISREG(info.st_mode):
        what = "a directory" if stat.S_ISDIR(info.st_mode) else "not a regular file"
        raise ConfigError("config", f"{path} is {what}")
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except OSError as err:
        raise ConfigError("config", f"{path}: {err.strerror or err}") from err
    except UnicodeDecodeError as err:
        raise ConfigError("config", f"{path}: not UTF-8 text (byte {err.start})") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError("config", f"{path}: invalid TOML: {err}") from err


def check_environment(environ: Mapping[str, str]) -> None:
    """Refuse a ``GROUNDSTATION_*`` variable that names no setting of any command.

    Raises:
        ConfigError: naming the variable.
    """
    known = known_variables()
    for var in sorted(environ):
        if var.startswith(ENV_PREFIX) and var not in known:
            raise ConfigError(var, "unknown environment variable: it names no setting "
                                   "(see config/groundstation.toml and config/solver.toml)")


def env_layer(scope: Scope, environ: Mapping[str, str]) -> dict[str, Any]:
    """The scope's settings named by its variables, as a nested layer of strings."""
    layer: dict[str, Any] = {}
    for var, (section, k) in scope.variables().items():
        if var in environ:
            (layer.setdefault(section, {}) if section else layer)[k] = environ[var]
    return layer


@dataclass(slots=True)
class Resolved:
    """A scope's merged, converted values (only what some layer set; defaults are the typed
    settings' own). ``values[section][key]``; ``tables[table][name][key]``."""

    values: dict[str, dict[str, Any]]
    tables: dict[str, dict[str, dict[str, Any]]]
    origin: dict[tuple[str, str], str] = field(default_factory=dict)
    """Which layer set each value: ``file``, ``environment`` or ``command line``."""


Hook = Callable[[dict[str, dict[str, Any]], Mapping[str, Any]], None]


def _merge(scope: Scope, out: Resolved, layer: Mapping[str, Any], *, origin: str,
           env: bool) -> None:
    names = {sk: v for v, sk in scope.variables().items()} if env else {}

    def put(section: str, k: str, value: Any) -> None:
        spec = scope.schema[section][k]
        where = f"environment {names[(section, k)]}" if env else origin
        out.values[section][k] = convert(spec, _dotted(section, k), value, from_text=env,
                                         origin=where)
        out.origin[(section, k)] = origin.split(" ")[0]

    for k, value in layer.items():
        if k in scope.tables:
            if env or not isinstance(value, Mapping):
                raise ConfigError(k, f"must be a table of [{k}.<name>] tables ({origin})")
            allowed = scope.tables[k]
            for name, table in value.items():
                check_station(name, f"{k}.{name}")
                if not isinstance(table, Mapping):
                    raise ConfigError(f"{k}.{name}", f"must be a table ({origin})")
                got = out.tables.setdefault(k, {}).setdefault(str(name), {})
                for sub, sub_value in table.items():
                    dotted = f"{k}.{name}.{sub}"
                    if sub not in allowed:
                        raise ConfigError(dotted, f"unknown key ({origin})")
                    got[sub] = convert(allowed[sub], dotted, sub_value, origin=origin)
        elif k in scope.schema and k != "":
            if not isinstance(value, Mapping):
                raise ConfigError(k, f"must be a table ({origin})")
            for sub, sub_value in value.items():
                if sub not in scope.schema[k]:
                    raise ConfigError(_dotted(k, sub), f"unknown key ({origin})")
                put(k, sub, sub_value)
        elif k in scope.schema.get("", {}):
            put("", k, value)
        else:
            raise ConfigError(k, f"unknown key ({origin})")


Layer = tuple[Mapping[str, Any], str, bool]
"""A layer: its values, where it comes from (``file X``, ``environment``, ``command line``)
and whether its values are text to parse (the environment)."""


def resolve(
    scope: Scope,
    config_file: Path | None = None,
    *,
    environ: Mapping[str, str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    before_layer: Hook | None = None,
    defaults: Mapping[str, Any] | None = None,
) -> Resolved:
    """Merge defaults < TOML file < environment < ``overrides`` (the command line) for a scope.

    Args:
        scope: the command's configuration.
        config_file: TOML file; ``None`` uses the scope's variable (``GROUNDSTATION_CONFIG``
            for the daemon) if set, else no file.
        environ: the environment (``os.environ`` when ``None``).
        overrides: command-line values as a nested layer (``{"zenoh": {"connect": [...]}}``).
        before_layer: called with the merged values and each layer before it is merged (the
            daemon lets a layer that names a device choose the source kind).
        defaults: the command's own defaults where they differ from the scope's (``demo``
            and ``replay`` name their station), as the lowest layer: a file, the
            environment and the command line all override them.

    Raises:
        ConfigError: naming the offending key, or the unknown variable.
    """
    env = os.environ if environ is None else environ
    check_environment(env)
    if config_file is None and env.get(scope.config_variable):
        config_file = Path(env[scope.config_variable])
    layers: list[Layer] = []
    if defaults:
        layers.append((defaults, "defaults of the command", False))
    if config_file is not None:
        layers.append((read_toml(config_file), f"file {config_file}", False))
    layers.append((env_layer(scope, env), "environment", True))
    if overrides:
        layers.append((overrides, "command line", False))
    return merge_layers(scope, layers, before_layer=before_layer)


def merge_layers(scope: Scope, layers: list[Layer], *, before_layer: Hook | None = None
                 ) -> Resolved:
    """Merge already-read layers, lowest first (:func:`resolve` reads them)."""
    out = Resolved({section: {} for section in scope.schema}, {})
    out.values.setdefault("", {})
    for layer, origin, is_env in layers:
        if before_layer is not None:
            before_layer(out.values, layer)
        _merge(scope, out, layer, origin=origin, env=is_env)
    return out


# -- the daemon's settings -----------------------------------------------------------------

_SOURCE_KEYS: dict[str, frozenset[str]] = {
    "serial": frozenset(
        {"port", "baud", "read_size_bytes", "reconnect_min_s", "reconnect_max_s", "stall_check_s"}
    ),
    "tcp": frozenset(
        {"address", "read_size_bytes", "reconnect_min_s", "reconnect_max_s", "connect_timeout_s"}
    ),
    "file": frozenset({"path", "rate_bytes_per_s", "read_size_bytes"}),
}
_SOURCE_LOCATOR = {"serial": "port", "tcp": "address", "file": "path"}


def _parse_address(address: str) -> tuple[str, int]:
    host, sep, port_text = address.rpartition(":")
    if not sep or not host:
        raise ConfigError("source.address", f"expected HOST:PORT, got {address!r}")
    try:
        port = int(port_text)
    except ValueError as err:
        raise ConfigError("source.address", f"port must be a number, got {port_text!r}") from err
    if not 0 < port < 65536:
        raise ConfigError("source.address", f"port must be 1..65535, got {port}")
    return host.strip("[]"), port


def _build_source(src: dict[str, Any]) -> SourceSettings:
    kind = src.get("type")
    if kind is None:
        present = [k for k, loc in _SOURCE_LOCATOR.items() if loc in src]
        if len(present) != 1:
            raise ConfigError(
                "source",
                "no source configured: give --port, --tcp or --file, or a [source] table "
                "with type = serial|tcp|file" if not present else
                f"ambiguous source ({', '.join(present)}): set source.type",
            )
        kind = present[0]
    locator = _SOURCE_LOCATOR[kind]
    if locator not in src:
        raise ConfigError(f"source.{locator}", f"required for a {kind} source")
    opts = {k: v for k, v in src.items() if k in _SOURCE_KEYS[kind] and k != locator}
    if kind == "serial":
        if not src["port"]:
            raise ConfigError("source.port", "empty device name")
        return SerialSourceSettings(port=src["port"], **opts)
    if kind == "tcp":
        host, port = _parse_address(src["address"])
        return TcpSourceSettings(host=host, port=port, **opts)
    return FileSourceSettings(path=src["path"], **opts)


def build_settings(merged: dict[str, dict[str, Any]]) -> Settings:
    """Build :class:`Settings` from the daemon's merged, converted values (checks that span
    several keys: the source, the station name)."""
    top = merged[""]
    source = _build_source(merged["source"])
    return Settings(
        source=source,
        recorder=RecorderSettings(**merged["recorder"]),
        queues=QueueSettings(**merged["queues"]),
        framer=FramerSettings(**merged["framer"]),
        zenoh=_checked_zenoh(ZenohSettings(**merged["zenoh"])),
        monitor=MonitorSettings(**merged["monitor"]),
        **top,
    )


def _source_kind_from_layer(merged: dict[str, dict[str, Any]], layer: Mapping[str, Any]) -> None:
    """A later layer naming a device (port, address or path) chooses the source kind too."""
    src = layer.get("source")
    if isinstance(src, Mapping) and "type" not in src:
        kinds = [k for k, loc in _SOURCE_LOCATOR.items() if loc in src]
        if len(kinds) == 1:
            merged["source"]["type"] = kinds[0]


def load_settings(
    config_file: Path | None = None,
    *,
    environ: Mapping[str, str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    defaults: Mapping[str, Any] | None = None,
) -> Settings:
    """Resolve the daemon's settings: defaults < TOML file < environment < ``overrides`` (CLI).

    ``run``, ``demo`` and ``replay`` all resolve their settings here.

    Args:
        config_file: TOML file; ``None`` uses ``$GROUNDSTATION_CONFIG`` if set, else no file.
        environ: the environment (``os.environ`` when ``None``).
        overrides: command-line values as a nested layer (``{"source": {"port": ...}}``);
            a ``source`` table here that carries a locator (port, address or path) replaces
            the source type chosen by earlier layers.
        defaults: the command's own defaults, below the file (:func:`resolve`).

    Raises:
        ConfigError: naming the offending key.
    """
    resolved = resolve(DAEMON, config_file, environ=environ, overrides=overrides,
                       before_layer=_source_kind_from_layer, defaults=defaults)
    return build_settings(resolved.values)


def _checked_zenoh(settings: ZenohSettings) -> ZenohSettings:
    """Checks that span several ``[zenoh]`` keys (a certificate needs its key)."""
    if (settings.tls_certificate is None) != (settings.tls_private_key is None):
        missing = "tls_private_key" if settings.tls_private_key is None else "tls_certificate"
        raise ConfigError(f"zenoh.{missing}", "tls_certificate and tls_private_key go together")
    for name in ("tls_ca", "tls_certificate", "tls_private_key"):
        _readable_file(f"zenoh.{name}", getattr(settings, name))
    return settings


def _readable_file(name: str, path: Path | None) -> None:
    """A certificate or key must be a readable file (Zenoh's own message would be a Rust
    error at connection time)."""
    if path is not None and not (path.is_file() and os.access(path, os.R_OK)):
        raise ConfigError(name, f"not a readable file: {path}")


def zenoh_settings(values: Mapping[str, Any], base: ZenohSettings = CLIENT_ZENOH) -> ZenohSettings:
    """A resolved ``[zenoh]`` section over ``base`` (a client's defaults unless given)."""
    return _checked_zenoh(replace(base, **values))


# -- the router's settings -----------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RouterTls:
    """The router's TLS side: its certificate for ``tls/`` listeners, the CA it trusts.

    Attributes:
        ca: the CA certificate (PEM) clients' certificates must chain to (mutual TLS).
        certificate: the router's certificate (PEM, X.509 v3, its name in subjectAltName).
        private_key: its private key (PEM).
        mtls: ask every ``tls/`` client for a certificate from ``ca`` (refuse those without).
    """

    ca: Path | None = None
    certificate: Path | None = None
    private_key: Path | None = None
    mtls: bool = True


@dataclass(frozen=True, slots=True)
class RouterAccess:
    """Access control by certificate common name (``docs/security.md``).

    Attributes:
        enabled: deny everything not allowed below (off: Zenoh allows everything).
        local: plain TCP over loopback (the daemons and views on this machine) may do
            anything under ``groundstation/**``.
        solvers: common names that read every station and write only ``.../solution``.
        viewers: common names that only read (a remote dashboard).
        stations: station name -> the common names that write ``groundstation/<name>/**``.
    """

    enabled: bool = False
    local: bool = True
    solvers: tuple[str, ...] = ()
    viewers: tuple[str, ...] = ()
    stations: Mapping[str, tuple[str, ...]] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class RouterSettings:
    """``groundstation router``: a Zenoh router in this process.

    Attributes:
        listen: endpoints to listen on; the default is the daemons' meeting point, so that
            daemons started after the router join it.
        connect: other routers to connect to.
        scouting: multicast scouting.
        duration_s: stop after this long (0: until stopped).
        tls: certificates for ``tls/`` endpoints.
        access: access control.
    """

    listen: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    connect: tuple[str, ...] = ()
    scouting: bool = False
    duration_s: float = 0.0
    tls: RouterTls = RouterTls()
    access: RouterAccess = RouterAccess()


def build_router_settings(resolved: Resolved) -> RouterSettings:
    """:class:`RouterSettings` from the router scope's resolved values (checks across keys)."""
    top, tls_values, access_values = (resolved.values[""], resolved.values["tls"],
                                      resolved.values["access"])
    tls = RouterTls(**tls_values)
    if (tls.certificate is None) != (tls.private_key is None):
        missing = "private_key" if tls.private_key is None else "certificate"
        raise ConfigError(f"tls.{missing}", "tls.certificate and tls.private_key go together")
    listen = top.get("listen", (DEFAULT_ENDPOINT,))
    if any(e.startswith(("tls/", "quic/")) for e in listen) and tls.certificate is None:
        raise ConfigError("tls.certificate", "required by the tls/ listen endpoints")
    if tls.mtls and tls.certificate is not None and tls.ca is None:
        raise ConfigError("tls.ca", "mutual TLS (tls.mtls) needs the CA clients chain to")
    for name in ("ca", "certificate", "private_key"):
        _readable_file(f"tls.{name}", getattr(tls, name))
    stations: dict[str, tuple[str, ...]] = {}
    for name, table in resolved.tables.get("stations", {}).items():
        if not name or any(c in name for c in "/\\ \t*$#?"):
            raise ConfigError(f"stations.{name}", "a station name: no slashes, spaces or "
                                                  "wildcards")
        stations[name] = tuple(table.get("cert_common_names", (name,)))
    access = RouterAccess(**access_values, stations=stations)
    if access.enabled and not (access.local or access.solvers or access.viewers or stations):
        raise ConfigError("access.enabled", "nobody is allowed anything: add [stations.<name>] "
                                            "tables, access.solvers or access.local = true")
    return RouterSettings(tls=tls, access=access, **top)


def load_router_settings(
    config_file: Path | None = None,
    *,
    environ: Mapping[str, str] | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> RouterSettings:
    """Resolve the router's settings: defaults < TOML file < environment < ``overrides``.

    Raises:
        ConfigError: naming the offending key.
    """
    return build_router_settings(resolve(ROUTER, config_file, environ=environ,
                                         overrides=overrides))
