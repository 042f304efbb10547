"""Replay: a recording through the live pipeline (framer, decoder, monitor, Zenoh), unrecorded.

The recording is read by the same :class:`~groundstation.live.sources.FileSource` as ``run
--file``: an MCAP re-emits its ``/ubx/raw`` chunks with their original host times and the
monitor runs on those times, so it reaches the status and events the live daemon recorded for
the same bytes; a ``.ubx``/``.ubx.gz`` file has no reception times, so its chunks take the
data's own time (the UTC of its latest measurement epoch, :mod:`groundstation.live.data_time`).
``speed`` paces those times (1: as recorded).

Each replay is a session of its own for the views: its id (:func:`replay_session_id`) is new
on every run (so a view drops the previous run's marks even when the same recording is replayed
again) and ends with the UTC time of the first replayed chunk, so that a session's duration
read from its id runs on the same data time as its statuses.
"""

from __future__ import annotations

import secrets
import time
from pathlib import Path
from typing import Any

from groundstation.config import FileSourceSettings, Settings, load_settings
from groundstation.live.daemon import Pipeline, RunSummary
from groundstation.live.fanout import SinkSpec
from groundstation.live.sources import FileSource
from groundstation.storage.naming import session_file_stem

READ_SIZE_BYTES = 1024
"""Chunk size of a file without recorded chunks: about what a serial read returns at 115200
baud, so the monitor sees the bytes arrive as it would live."""


REPLAY_DEFAULTS: dict[str, Any] = {"station": "replay"}
"""Where ``replay`` differs from the daemon's defaults (below the file and the environment)."""


def replay_settings(path: Path, config_file: Path | None = None, *,
                    environ: dict[str, str] | None = None,
                    overrides: dict[str, Any] | None = None) -> Settings:
    """``replay``'s settings, through the one resolver: its defaults < file < environment
    < ``overrides`` (its options); the source is ``path`` whatever the layers say.

    Raises:
        ConfigError: naming the offending key or variable.
    """
    layer = {**(overrides or {}), "source": {"path": path}}
    return load_settings(config_file, environ=environ, overrides=layer,
                         defaults=REPLAY_DEFAULTS)


def replay_session_id(station: str, wall_start_ns: int, data_start_ns: int) -> str:
    """``<station>_replay-<wall UTC>-<random>_<data UTC>``: unique per run (two runs may start
    within a second), ending with the data start (which the views read as the session's
    start, ``YYYYmmddTHHMMSSZ``)."""
    wall = session_file_stem("replay", wall_start_ns).removeprefix("replay_")
    return session_file_stem(f"{station}_replay-{wall}-{secrets.token_hex(3)}", data_start_ns)


async def run_replay(
    path: Path,
    *,
    speed: float | None = None,
    station: str = "replay",
    zenoh: dict[str, Any] | None = None,
    sinks: tuple[SinkSpec, ...] = (),
    settings: Settings | None = None,
) -> tuple[RunSummary, Pipeline]:
    """Replay ``path`` (and its session's later parts) through a pipeline that does not record,
    at ``speed`` times the recorded pace (``None``: as fast as possible); return its summary.

    Args:
        settings: the resolved settings (``groundstation replay`` resolves them with the
            file, the environment and its options: :func:`replay_settings`); when ``None``,
            ``station`` and ``zenoh`` over the defaults, without the environment.
    """
    if settings is None:
        settings = load_settings(None, environ={}, overrides={
            "station": station, "source": {"path": path},
            "zenoh": zenoh if zenoh is not None else {"enabled": False}})
    station = settings.station
    source = FileSource(FileSourceSettings(path, read_size_bytes=READ_SIZE_BYTES), speed=speed)
    wall_start_ns = time.time_ns()

    def start_session(data_start_ns: int) -> None:
        # before the first chunk reaches the monitor: every status names this session
        if pipeline.monitor is not None:
            pipeline.monitor.monitor.session_id = replay_session_id(
                station, wall_start_ns, data_start_ns)

    pipeline = Pipeline(settings, source=source, sinks=sinks, record=False,
                        monitor_data_clock=True, on_first_chunk=start_session)
    summary = await pipeline.run(handle_signals=True)
    return summary, pipeline
