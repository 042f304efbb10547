"""Replay: a recording's raw chunks through the live pipeline (framer, decoder, monitor, Zenoh).

An MCAP re-emits its ``/ubx/raw`` chunks with their original host times, and the monitor runs on
those times, so it reaches the status and events the live daemon recorded for the same bytes.
A ``.ubx``/``.ubx.gz`` file has no reception times: its chunks are timed as a 115200-baud link
would have delivered them.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from groundstation.config import load_settings
from groundstation.live.daemon import Pipeline, RunSummary
from groundstation.live.fanout import SinkSpec
from groundstation.offline.readers import detect_format, iter_chunks

LINK_BYTES_PER_S = 11_520  # 115200 baud, 8N1


class ReplaySource:
    """Chunks of a recording, at ``speed`` times their original pace (``None``: at once)."""

    can_wait = True

    def __init__(self, path: Path, speed: float | None) -> None:
        self.path = path
        self.speed = speed
        self.name = f"replay:{path}"
        self.format = detect_format(path)
        self.chunks_out = 0

    async def chunks(self) -> AsyncIterator[tuple[bytes, int]]:
        t_first: int | None = None
        wall0 = time.monotonic()
        synthetic = time.time_ns()
        sent = 0
        for data, t_host in iter_chunks(self.path, chunk_bytes=1024):
            if t_host <= 0:  # a plain .ubx: time it like the radio link would
                t_host = synthetic + sent * 1_000_000_000 // LINK_BYTES_PER_S
            sent += len(data)
            if t_first is None:
                t_first = t_host
            if self.speed is not None:
                due = wall0 + (t_host - t_first) / 1e9 / self.speed
                delay = due - time.monotonic()
                if delay > 0:
                    await asyncio.sleep(delay)
            else:
                await asyncio.sleep(0)
            self.chunks_out += 1
            yield data, t_host


async def run_replay(
    path: Path,
    *,
    speed: float | None = None,
    station: str = "replay",
    zenoh: dict[str, Any] | None = None,
    sinks: tuple[SinkSpec, ...] = (),
) -> tuple[RunSummary, Pipeline]:
    """Replay ``path`` through a pipeline that does not record; return its summary."""
    overrides: dict[str, Any] = {
        "station": station,
        "source": {"path": path},
        "zenoh": zenoh if zenoh is not None else {"enabled": False},
    }
    settings = load_settings(None, environ={}, overrides=overrides)
    source = ReplaySource(path, speed)
    pipeline = Pipeline(settings, source=source, sinks=sinks, record=False,
                        monitor_data_clock=True)
    summary = await pipeline.run(handle_signals=True)
    return summary, pipeline
