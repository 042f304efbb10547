"""Session recording: file naming, rotation, channel routing, JSON encoding, the .ubx sidecar.

Sans-asyncio: the live recorder sink (``live/recorder.py``) feeds it; tests and tools can drive
it directly. Raw chunks go to ``/ubx/raw`` byte for byte (``log_time`` = host receive time) and to
the sidecar; decoded records go to JSON channels routed by their type (:data:`ROUTES`,
extensible with :func:`register_record_topic`), with ``publish_time`` = GPS time as UNIX ns
(UTC) where the record knows it.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from groundstation import __version__, gpstime
from groundstation.records import (
    Ephemeris,
    Event,
    NavSolution,
    RawEpoch,
    Subframe,
    SvInfo,
    TimeMark,
    to_jsonable,
)
from groundstation.storage.mcapio import (
    RAW_TOPIC,
    ChannelSpec,
    McapFileWriter,
    json_channel,
)
from groundstation.storage.schemas import LOCATION_FIX_SCHEMA, dataclass_schema, union_schema

log = logging.getLogger("groundstation.recorder")

RAW_CHANNEL = ChannelSpec(RAW_TOPIC, "ubx")
LOCATION_CHANNEL = json_channel("/groundstation/location", LOCATION_FIX_SCHEMA)
HALF_WEEK_NS = gpstime.NS_PER_WEEK // 2

ROUTES: dict[type, ChannelSpec] = {
    RawEpoch: json_channel("/gnss/epoch", dataclass_schema(RawEpoch)),
    TimeMark: json_channel("/gnss/timemark", dataclass_schema(TimeMark)),
    Subframe: json_channel("/gnss/ephemeris", union_schema("NavData", (Subframe, Ephemeris))),
    Ephemeris: json_channel("/gnss/ephemeris", union_schema("NavData", (Subframe, Ephemeris))),
    NavSolution: json_channel("/gnss/nav", dataclass_schema(NavSolution)),
    SvInfo: json_channel("/gnss/svinfo", dataclass_schema(SvInfo)),
    Event: json_channel("/groundstation/event", dataclass_schema(Event)),
}
"""Record type -> the JSON channel it is recorded on. Types not listed are not recorded as JSON
(frames and undecodable frames are already in ``/ubx/raw``)."""


def register_record_topic(cls: type, topic: str, schema: dict[str, Any] | None = None) -> None:
    """Record instances of ``cls`` (a dataclass) on ``topic`` (e.g. the monitor's Status on
    ``/groundstation/status``); the schema is derived from the dataclass unless given."""
    ROUTES[cls] = json_channel(topic, schema if schema is not None else dataclass_schema(cls))


def session_file_stem(station: str, start_ns: int) -> str:
    """``<station>_<YYYYmmddTHHMMSSZ>`` for a UTC start time given as UNIX ns."""
    when = dt.datetime.fromtimestamp(start_ns / 1e9, tz=dt.UTC)
    return f"{station}_{when:%Y%m%dT%H%M%SZ}"


def _json_bytes(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, default=str).encode()


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


def plain_json(value: Any) -> Any:
    """:func:`records.to_jsonable`, but NaN/infinity become null and field names are cached per
    class (half of the recorder's time went to generic dataclass introspection)."""
    t = type(value)
    if t is int or t is str or t is bool or value is None:
        return value
    if t is float:
        return value if math.isfinite(value) else None
    if t is tuple or t is list:
        return [plain_json(v) for v in value]
    names = _FIELD_NAMES.get(t)
    if names is None:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            names = _FIELD_NAMES[t] = tuple(f.name for f in dataclasses.fields(value))
        elif isinstance(value, dict):
            return {str(k): plain_json(v) for k, v in value.items()}
        elif isinstance(value, (bytes, bytearray, memoryview)):
            return bytes(value).hex()
        else:
            return to_jsonable(value)
    return {n: plain_json(getattr(value, n)) for n in names}


@dataclass(frozen=True, slots=True)
class RecorderStats:
    """Counters of a recording session."""

    session_id: str
    files: tuple[Path, ...]
    sidecars: tuple[Path, ...]
    raw_chunks: int
    raw_bytes: int
    records: int
    events: int
    flushes: int


class SessionRecorder:
    """Writes one session: MCAP files (rotated) plus a ``.ubx`` sidecar for each.

    Args:
        out_dir: directory for the files (created if missing).
        station: station name; files are ``<station>_<YYYYmmddTHHMMSSZ>.mcap``.
        receiver: receiver description for the metadata record.
        configuration: the resolved settings, recorded as metadata.
        chunk_size_bytes: MCAP chunk size target.
        compression: MCAP chunk compression.
        flush_interval_ns: close the chunk and flush both files at least this often.
        rotate_size_bytes: start a new file beyond this MCAP size (0 = never).
        rotate_duration_ns: start a new file after this long (0 = never).
        sidecar: write the ``.ubx`` sidecar.
        clock: wall clock in UNIX ns (injected for tests).
    """

    def __init__(
        self,
        out_dir: Path,
        station: str,
        *,
        receiver: str = "",
        configuration: dict[str, Any] | None = None,
        chunk_size_bytes: int = 64 * 1024,
        compression: str = "zstd",
        flush_interval_ns: int = 500_000_000,
        rotate_size_bytes: int = 0,
        rotate_duration_ns: int = 0,
        sidecar: bool = True,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.out_dir = out_dir
        self.station = station
        self.receiver = receiver
        self.configuration = configuration or {}
        self.chunk_size_bytes = chunk_size_bytes
        self.compression = compression
        self.flush_interval_ns = flush_interval_ns
        self.rotate_size_bytes = rotate_size_bytes
        self.rotate_duration_ns = rotate_duration_ns
        self.sidecar = sidecar
        self._clock = clock
        self.session_id = ""
        self._mcap: McapFileWriter | None = None
        self._ubx: BinaryIO | None = None
        self._files: list[Path] = []
        self._sidecars: list[Path] = []
        self._file_start_ns = 0
        self._last_flush_ns = 0
        self._week: int | None = None
        self._tow_ns = 0
        self._raw_chunks = 0
        self._raw_bytes = 0
        self._records = 0
        self._events = 0
        self._flushes = 0
        self._closed = False

    # -- lifecycle ------------------------------------------------------------------------------

    def open(self) -> Path:
        """Start the session: create the first file. Returns its path."""
        now = self._clock()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.session_id = session_file_stem(self.station, now)
        return self._open_file(now)

    def _open_file(self, now_ns: int) -> Path:
        stem = session_file_stem(self.station, now_ns)
        for n in range(10_000):
            name = stem if n == 0 else f"{stem}_{n}"
            path = self.out_dir / f"{name}.mcap"
            side = self.out_dir / f"{name}.ubx"
            if side.exists() and self.sidecar:
                continue
            try:
                mcap = McapFileWriter(
                    path, chunk_size_bytes=self.chunk_size_bytes, compression=self.compression,
                    library=f"groundstation {__version__}",
                )
            except FileExistsError:
                continue
            break
        else:  # pragma: no cover - ten thousand files in one second
            raise FileExistsError(f"no free file name for {stem} in {self.out_dir}")
        self._mcap = mcap
        # Unbuffered: every received byte is in the OS's hands at once, so a killed daemon's
        # sidecar holds everything it received (the MCAP loses at most one flush interval).
        self._ubx = side.open("xb", buffering=0) if self.sidecar else None
        self._files.append(path)
        if self.sidecar:
            self._sidecars.append(side)
        self._file_start_ns = now_ns
        self._last_flush_ns = now_ns
        mcap.add_metadata(
            "groundstation",
            {
                "station": self.station,
                "receiver": self.receiver,
                "software_version": __version__,
                "session_id": self.session_id,
                "part": str(len(self._files)),
                "started_utc_ns": str(now_ns),
                "previous_file": self._files[-2].name if len(self._files) > 1 else "",
                "sidecar": side.name if self.sidecar else "",
            },
        )
        mcap.add_metadata("configuration", {"json": json.dumps(self.configuration)})
        mcap.flush()
        log.info("recording to %s", path)
        return path

    def _rotate_due(self, now_ns: int) -> bool:
        mcap = self._mcap
        if mcap is None:
            return False
        if self.rotate_size_bytes and mcap.size_bytes >= self.rotate_size_bytes:
            return True
        return bool(
            self.rotate_duration_ns and now_ns - self._file_start_ns >= self.rotate_duration_ns
        )

    def _close_file(self) -> None:
        if self._mcap is not None:
            self._mcap.finish()
            self._mcap = None
        if self._ubx is not None:
            self._ubx.close()
            self._ubx = None

    def close(self) -> None:
        """Finish the MCAP (summary written) and close the sidecar; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._close_file()
        log.info(
            "session %s finished: %d raw bytes, %d records, %d file(s)",
            self.session_id, self._raw_bytes, self._records, len(self._files),
        )

    # -- writing --------------------------------------------------------------------------------

    def _writer(self) -> McapFileWriter:
        if self._mcap is None:
            raise RuntimeError("recorder is not open")
        return self._mcap

    def write_raw(self, data: bytes, t_host_ns: int) -> None:
        """Record one received chunk byte for byte (MCAP ``/ubx/raw`` and the sidecar)."""
        now = self._clock()
        if self._rotate_due(now):
            self._close_file()
            self._open_file(now)
        self._writer().add(RAW_CHANNEL, data, t_host_ns, t_host_ns)
        if self._ubx is not None:
            self._ubx.write(data)
        self._raw_chunks += 1
        self._raw_bytes += len(data)

    def write_record(self, record: Any, log_time_ns: int) -> bool:
        """Record a decoded record or event on its channel; False if its type is not routed."""
        spec = ROUTES.get(type(record))
        if spec is None:
            return False
        body = {"type": type(record).__name__, **plain_json(record)}
        publish = self._publish_time_ns(record, log_time_ns)
        mcap = self._writer()
        mcap.add(spec, _json_bytes(body), log_time_ns, publish)
        self._records += 1
        if isinstance(record, Event):
            self._events += 1
        if isinstance(record, NavSolution) and record.lat_deg is not None:
            mcap.add(LOCATION_CHANNEL, _json_bytes(self._location_fix(record, publish)),
                     log_time_ns, publish)
        return True

    def _gps_unix_ns(self, tow_ns: int, week: int | None) -> int | None:
        if week is None:
            if self._week is None:
                return None
            week = self._week
            if tow_ns - self._tow_ns > HALF_WEEK_NS:
                week -= 1
            elif self._tow_ns - tow_ns > HALF_WEEK_NS:
                week += 1
        return gpstime.gps_to_unix_ns(week * gpstime.NS_PER_WEEK + tow_ns)

    def _publish_time_ns(self, record: Any, log_time_ns: int) -> int:
        t: int | None = None
        if isinstance(record, RawEpoch):
            self._week, self._tow_ns = record.gps_week, record.tow_ns
            t = gpstime.gps_to_unix_ns(record.t_gps_ns)
        elif isinstance(record, TimeMark):
            edge = record.falling_t_gps_ns if record.new_falling else record.rising_t_gps_ns
            edge = edge if edge is not None else record.falling_t_gps_ns
            t = gpstime.gps_to_unix_ns(edge) if edge is not None else None
        elif isinstance(record, (NavSolution, SvInfo)):
            week = record.gps_week if isinstance(record, NavSolution) else None
            t = self._gps_unix_ns(record.tow_ns, week)
        return t if t is not None and t >= 0 else log_time_ns

    def _location_fix(self, nav: NavSolution, publish_ns: int) -> dict[str, Any]:
        cov = [0.0] * 9
        cov_type = 0
        if nav.h_acc_m is not None and nav.v_acc_m is not None:
            cov[0] = cov[4] = nav.h_acc_m**2
            cov[8] = nav.v_acc_m**2
            cov_type = 1
        elif nav.p_acc_m is not None:
            cov[0] = cov[4] = cov[8] = nav.p_acc_m**2
            cov_type = 1
        return {
            "timestamp": {"sec": publish_ns // 1_000_000_000, "nsec": publish_ns % 1_000_000_000},
            "frame_id": self.station,
            "latitude": nav.lat_deg,
            "longitude": nav.lon_deg,
            "altitude": nav.height_m if nav.height_m is not None else 0.0,
            "position_covariance": cov,
            "position_covariance_type": cov_type,
        }

    # -- flushing -------------------------------------------------------------------------------

    def flush(self) -> None:
        """Close the MCAP chunk in progress and flush MCAP and sidecar to the OS."""
        if self._mcap is not None:
            self._mcap.flush()
        if self._ubx is not None:
            self._ubx.flush()
        self._last_flush_ns = self._clock()
        self._flushes += 1

    def maybe_flush(self) -> bool:
        """Flush if the flush interval has passed; True if it flushed."""
        if self._clock() - self._last_flush_ns >= self.flush_interval_ns:
            self.flush()
            return True
        return False

    @property
    def current_file(self) -> Path | None:
        return self._files[-1] if self._files else None

    @property
    def stats(self) -> RecorderStats:
        return RecorderStats(
            self.session_id, tuple(self._files), tuple(self._sidecars), self._raw_chunks,
            self._raw_bytes, self._records, self._events, self._flushes,
        )
