"""``groundstation replay``: a recording through the live pipeline, to Zenoh, at xN or max."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path
from typing import Any

from groundstation.commands.options import add_zenoh_daemon, zenoh_layer
from groundstation.commands.simulate import parse_speed
from groundstation.view.summary import status_lines

NAME = "replay"
HELP = "MCAP/.ubx through the live pipeline (to Zenoh), at xN or max speed"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", type=Path, help=".mcap, .ubx or .ubx.gz recording")
    parser.add_argument("--speed", default="max", help="1 (as recorded), N or max (default)")
    parser.add_argument("--station", default="replay", help="station name on Zenoh")
    add_zenoh_daemon(parser)


def run(args: argparse.Namespace) -> int:
    from groundstation.config import check_station
    from groundstation.errors import InputError
    from groundstation.live.replay import run_replay
    from groundstation.offline.inspect import require_ubx_frames

    check_station(args.station, "--station")
    if not args.input.exists():
        raise InputError(f"{args.input}: no such file")
    require_ubx_frames(args.input)
    zenoh: dict[str, Any] = {"enabled": not args.no_zenoh, **zenoh_layer(args)}
    speed = parse_speed(args.speed, live=False)
    summary, pipeline = asyncio.run(
        run_replay(args.input, speed=speed, station=args.station, zenoh=zenoh)
    )
    st = pipeline.monitor.last_status if pipeline.monitor is not None else None
    print(f"replayed {args.input}: {summary.bytes_in:,} bytes, {summary.frames:,} frames, "
          f"{summary.records:,} records, {summary.events} events ({summary.stopped_by})")
    if st is not None:
        for line in status_lines(st):
            print(line)
    return 0
