"""``groundstation replay``: a recording through the live pipeline, to Zenoh, at xN or max."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from groundstation.commands.options import add_config, add_zenoh_daemon, layer
from groundstation.commands.simulate import parse_speed
from groundstation.config import DAEMON
from groundstation.view.summary import status_lines

NAME = "replay"
HELP = "MCAP/.ubx through the live pipeline (to Zenoh), at xN or max speed"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", type=Path, help=".mcap, .ubx or .ubx.gz recording")
    parser.add_argument("--speed", default="max", help="1 (as recorded), N or max (default)")
    add_config(parser, DAEMON, "config/groundstation.toml")
    parser.add_argument("--station", help="station name on Zenoh (default replay)")
    add_zenoh_daemon(parser)


def run(args: argparse.Namespace) -> int:
    from groundstation.errors import InputError
    from groundstation.live.replay import replay_settings, run_replay
    from groundstation.offline.inspect import require_ubx_frames

    settings = replay_settings(args.input, args.config,
                               overrides=layer(args, {"station": "station"}))
    if not args.input.exists():
        raise InputError(f"{args.input}: no such file")
    require_ubx_frames(args.input)
    speed = parse_speed(args.speed, live=False)
    summary, pipeline = asyncio.run(run_replay(args.input, speed=speed, settings=settings))
    st = pipeline.monitor.last_status if pipeline.monitor is not None else None
    print(f"replayed {args.input}: {summary.bytes_in:,} bytes, {summary.frames:,} frames, "
          f"{summary.records:,} records, {summary.events} events ({summary.stopped_by})")
    if st is not None:
        at = ("at the end of the recording" if summary.stopped_by == "end of source"
              else "where the replay stopped")
        for line in status_lines(st, at=at):
            print(line)
    from groundstation.cli import EXIT_INTERRUPTED, INTERRUPTS

    return EXIT_INTERRUPTED if summary.stopped_by in INTERRUPTS else 0
