"""Typed daemon settings and the one place they are resolved: defaults < TOML < environment < CLI.

The configuration is a small nested table (see ``config/groundstation.toml``). Every layer is
merged into the same plain dictionary, checked against :data:`SCHEMA` (an unknown key is an
error, never ignored), converted to the section's type and then turned into frozen dataclasses.
Any problem raises :class:`~groundstation.errors.ConfigError` naming the dotted key, which the
command line turns into exit status 2.

Environment variables are ``GROUNDSTATION_<KEY>`` for top-level keys and
``GROUNDSTATION_<SECTION>_<KEY>`` for the others (``GROUNDSTATION_SOURCE_BAUD=57600``,
``GROUNDSTATION_RECORDER_OUT_DIR=/data``). Variables that name no setting are ignored, because
other tools share the prefix (``GROUNDSTATION_CONFIG`` names the file itself).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

from groundstation.errors import ConfigError

ENV_PREFIX = "GROUNDSTATION_"
ENV_CONFIG_FILE = "GROUNDSTATION_CONFIG"

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

    out_dir: Path = Path("recordings")
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
    """The Zenoh publisher: loopback only and no multicast scouting unless configured."""

    enabled: bool = True
    mode: Literal["peer", "client", "router"] = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    scouting: bool = False
    publish_epochs: bool = False
    publish_raw: bool = False


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
    marks_missed_hold_s: float = 30.0
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
        out: dict[str, Any] = _jsonable(asdict(self))
        return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


# Types a key may take: str, int, float, bool, "path", "strlist".
_T = str | type
SCHEMA: dict[str, dict[str, _T]] = {
    "": {
        "station": str,
        "receiver": str,
        "duration_s": float,
        "status_interval_s": float,
    },
    "source": {
        "type": str,
        "port": str,
        "baud": int,
        "address": str,
        "path": "path",
        "rate_bytes_per_s": float,
        "read_size_bytes": int,
        "reconnect_min_s": float,
        "reconnect_max_s": float,
        "stall_check_s": float,
        "connect_timeout_s": float,
    },
    "recorder": {
        "out_dir": "path",
        "rotate_size_mb": float,
        "rotate_duration_s": float,
        "flush_interval_s": float,
        "chunk_size_bytes": int,
        "compression": str,
        "sidecar": bool,
        "backlog_mb": float,
        "retry_s": float,
    },
    "queues": {"recorder": int, "monitor": int, "publisher": int},
    "framer": {"max_payload_bytes": int},
    "zenoh": {
        "enabled": bool,
        "mode": str,
        "listen": "strlist",
        "connect": "strlist",
        "scouting": bool,
        "publish_epochs": bool,
        "publish_raw": bool,
    },
    "monitor": {
        "enabled": bool,
        "dropout_alert_s": float,
        "ppk_ready_min": int,
        "clean_phase_s": float,
        "half_cycle_fraction_max": float,
        "no_data_s": float,
        "disk_free_min_mb": float,
        "elevation_mask_deg": float,
        "marks_missed_hold_s": float,
        "no_frames_s": float,
    },
}
"""Every key the configuration accepts, by section ("" = top level)."""

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


def _dotted(section: str, key: str) -> str:
    return f"{section}.{key}" if section else key


def _convert(section: str, key: str, value: Any, *, from_text: bool) -> Any:
    """Convert one value to the schema type; ``from_text`` for environment strings."""
    kind = SCHEMA[section][key]
    name = _dotted(section, key)
    try:
        if kind is bool:
            if isinstance(value, bool):
                return value
            if from_text and str(value).strip().lower() in {"1", "true", "yes", "on"}:
                return True
            if from_text and str(value).strip().lower() in {"0", "false", "no", "off"}:
                return False
            raise ValueError(f"expected true or false, got {value!r}")
        if kind is int:
            if isinstance(value, bool) or (isinstance(value, float) and not from_text):
                raise ValueError(f"expected an integer, got {value!r}")
            if isinstance(value, str) and not from_text:
                raise ValueError(f"expected an integer, got the string {value!r}")
            return int(value)
        if kind is float:
            if isinstance(value, bool) or (isinstance(value, str) and not from_text):
                raise ValueError(f"expected a number, got {value!r}")
            return float(value)
        if kind is str:
            if not isinstance(value, str):
                raise ValueError(f"expected a string, got {value!r}")
            return value
        if kind == "path":
            if not isinstance(value, (str, Path)):
                raise ValueError(f"expected a path, got {value!r}")
            return Path(value).expanduser()
        if kind == "strlist":
            if from_text and isinstance(value, str):
                return tuple(v.strip() for v in value.split(",") if v.strip())
            if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"expected a list of strings, got {value!r}")
            return tuple(value)
    except (TypeError, ValueError) as err:
        raise ConfigError(name, str(err)) from err
    raise ConfigError(name, f"no converter for {kind!r}")  # pragma: no cover


def _merge_layer(
    merged: dict[str, dict[str, Any]], layer: Mapping[str, Any], *, origin: str, from_text: bool
) -> None:
    """Merge one nested layer into ``merged``, rejecting unknown keys."""
    for key, value in layer.items():
        if key in SCHEMA and key != "":
            if not isinstance(value, Mapping):
                raise ConfigError(key, f"must be a table ({origin})")
            for sub, sub_value in value.items():
                if sub not in SCHEMA[key]:
                    raise ConfigError(_dotted(key, sub), f"unknown key ({origin})")
                merged[key][sub] = _convert(key, sub, sub_value, from_text=from_text)
        elif key in SCHEMA[""]:
            merged[""][key] = _convert("", key, value, from_text=from_text)
        else:
            raise ConfigError(key, f"unknown key ({origin})")


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML configuration file (no validation yet)."""
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError as err:
        raise ConfigError("config", f"file not found: {path}") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError("config", f"{path}: invalid TOML: {err}") from err


def env_layer(environ: Mapping[str, str]) -> dict[str, Any]:
    """The settings named by ``GROUNDSTATION_*`` variables, as a nested layer of strings."""
    layer: dict[str, Any] = {}
    for section, keys in SCHEMA.items():
        for key in keys:
            var = ENV_PREFIX + (f"{section}_{key}" if section else key).upper()
            if var in environ:
                if section:
                    layer.setdefault(section, {})[key] = environ[var]
                else:
                    layer[key] = environ[var]
    return layer


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


def _positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    if value < 0 or (value == 0 and not allow_zero):
        raise ConfigError(name, f"must be {'>= 0' if allow_zero else '> 0'}, got {value}")


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
    if kind not in _SOURCE_KEYS:
        raise ConfigError("source.type", f"must be serial, tcp or file, got {kind!r}")
    locator = _SOURCE_LOCATOR[kind]
    if locator not in src:
        raise ConfigError(f"source.{locator}", f"required for a {kind} source")
    opts = {k: v for k, v in src.items() if k in _SOURCE_KEYS[kind] and k != locator}
    for key in ("read_size_bytes", "reconnect_min_s", "reconnect_max_s", "stall_check_s",
                "connect_timeout_s"):
        if key in opts:
            _positive(f"source.{key}", opts[key])
    if kind == "serial":
        baud = opts.get("baud", 115200)
        if baud not in VALID_BAUDS:
            raise ConfigError(
                "source.baud", f"{baud} is not a valid rate ({', '.join(map(str, VALID_BAUDS))})"
            )
        if not src["port"]:
            raise ConfigError("source.port", "empty device name")
        return SerialSourceSettings(port=src["port"], **opts)
    if kind == "tcp":
        host, port = _parse_address(src["address"])
        return TcpSourceSettings(host=host, port=port, **opts)
    if "rate_bytes_per_s" in opts:
        _positive("source.rate_bytes_per_s", opts["rate_bytes_per_s"], allow_zero=True)
    return FileSourceSettings(path=src["path"], **opts)


def build_settings(merged: dict[str, dict[str, Any]]) -> Settings:
    """Validate a fully merged configuration and build :class:`Settings`."""
    top = merged[""]
    source = _build_source(merged["source"])
    rec = dict(merged["recorder"])
    if "compression" in rec and rec["compression"] not in ("zstd", "lz4", "none"):
        raise ConfigError(
            "recorder.compression", f"must be zstd, lz4 or none: {rec['compression']!r}"
        )
    for key in ("rotate_size_mb", "rotate_duration_s"):
        if key in rec:
            _positive(f"recorder.{key}", rec[key], allow_zero=True)
    for key in ("flush_interval_s", "chunk_size_bytes", "backlog_mb", "retry_s"):
        if key in rec:
            _positive(f"recorder.{key}", rec[key])
    if rec.get("flush_interval_s", 0.5) > 1.0:
        raise ConfigError("recorder.flush_interval_s", "must be at most 1 s (crash safety)")
    for key, value in merged["queues"].items():
        _positive(f"queues.{key}", value)
    if "max_payload_bytes" in merged["framer"]:
        mp = merged["framer"]["max_payload_bytes"]
        if not 0 < mp <= 65535:
            raise ConfigError("framer.max_payload_bytes", f"must be 1..65535, got {mp}")
    zen = merged["zenoh"]
    if "mode" in zen and zen["mode"] not in ("peer", "client", "router"):
        raise ConfigError("zenoh.mode", f"must be peer, client or router, got {zen['mode']!r}")
    for key, value in merged["monitor"].items():
        if key != "enabled":
            _positive(f"monitor.{key}", value, allow_zero=key in ("ppk_ready_min",
                                                                 "disk_free_min_mb",
                                                                 "elevation_mask_deg"))
    if "station" in top and not str(top["station"]).strip():
        raise ConfigError("station", "must not be empty")
    if "station" in top and any(c in top["station"] for c in "/\\ \t"):
        raise ConfigError("station", f"no slashes or spaces (it names files): {top['station']!r}")
    for key in ("duration_s",):
        if key in top:
            _positive(key, top[key], allow_zero=True)
    if "status_interval_s" in top:
        _positive("status_interval_s", top["status_interval_s"])
    return Settings(
        source=source,
        recorder=RecorderSettings(**rec),
        queues=QueueSettings(**merged["queues"]),
        framer=FramerSettings(**merged["framer"]),
        zenoh=ZenohSettings(**zen),
        monitor=MonitorSettings(**merged["monitor"]),
        **top,
    )


def load_settings(
    config_file: Path | None = None,
    *,
    environ: Mapping[str, str] | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> Settings:
    """Resolve the settings: defaults < TOML file < environment < ``overrides`` (the CLI).

    Args:
        config_file: TOML file; ``None`` uses ``$GROUNDSTATION_CONFIG`` if set, else no file.
        environ: the environment (``os.environ`` when ``None``).
        overrides: command-line values as a nested layer (``{"source": {"port": ...}}``);
            a ``source`` table here that carries a locator (port, address or path) replaces
            the source type chosen by earlier layers.

    Raises:
        ConfigError: naming the offending key.
    """
    env = os.environ if environ is None else environ
    merged: dict[str, dict[str, Any]] = {section: {} for section in SCHEMA}
    if config_file is None and env.get(ENV_CONFIG_FILE):
        config_file = Path(env[ENV_CONFIG_FILE])
    if config_file is not None:
        _merge_layer(merged, read_toml(config_file), origin=str(config_file), from_text=False)
    layers: list[tuple[Mapping[str, Any], str, bool]] = [(env_layer(env), "environment", True)]
    if overrides:
        layers.append((overrides, "command line", False))
    for layer, origin, from_text in layers:
        src = layer.get("source")
        if isinstance(src, Mapping) and any(loc in src for loc in _SOURCE_LOCATOR.values()):
            # A later layer naming a device chooses the source kind too.
            kinds = [k for k, loc in _SOURCE_LOCATOR.items() if loc in src]
            if "type" not in src and len(kinds) == 1:
                merged["source"]["type"] = kinds[0]
        _merge_layer(merged, layer, origin=origin, from_text=from_text)
    return build_settings(merged)
