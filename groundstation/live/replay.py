"""Replay: a recording through the live pipeline (framer, decoder, monitor, Zenoh), unrecorded.

The recording is read by the same :class:`~groundstation.live.sources.FileSource` as ``run
--file``: an MCAP re-emits its ``/ubx/raw`` chunks with their original host times and the
monitor runs on those times, so it reaches the status and events the live daemon recorded for
the same bytes; a ``.ubx``/``.ubx.gz`` file has no reception times, so its chunks are timed as a
115200-baud link would have delivered them. ``speed`` paces those times.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from groundstation.config import FileSourceSettings, load_settings
from groundstation.live.daemon import Pipeline, RunSummary
from groundstation.live.fanout import SinkSpec
from groundstation.live.sources import FileSource

READ_SIZE_BYTES = 1024
"""Chunk size of a file without recorded chunks: about what a serial read returns at 115200
baud, so the monitor sees the bytes arrive as it would live."""


async def run_replay(
    path: Path,
    *,
    speed: float | None = None,
    station: str = "replay",
    zenoh: dict[str, Any] | None = None,
    sinks: tuple[SinkSpec, ...] = (),
) -> tuple[RunSummary, Pipeline]:
    """Replay ``path`` (and its session's later parts) through a pipeline that does not record,
    at ``speed`` times the recorded pace (``None``: as fast as possible); return its summary."""
    overrides: dict[str, Any] = {
        "station": station,
        "source": {"path": path},
        "zenoh": zenoh if zenoh is not None else {"enabled": False},
    }
    settings = load_settings(None, environ={}, overrides=overrides)
    source = FileSource(FileSourceSettings(path, read_size_bytes=READ_SIZE_BYTES), speed=speed)
    pipeline = Pipeline(settings, source=source, sinks=sinks, record=False)
    summary = await pipeline.run(handle_signals=True)
    return summary, pipeline
