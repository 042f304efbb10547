"""``groundstation watch``: a live terminal view of a station, from Zenoh only."""

from __future__ import annotations

import argparse
import contextlib

from groundstation.bus import BusSettings

NAME = "watch"
HELP = "live terminal view of a station over Zenoh"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--station", default="station", help="station name (default: station)")
    parser.add_argument(
        "--connect", action="append", metavar="ENDPOINT",
        help="Zenoh endpoint of the daemon (default tcp/127.0.0.1:7447; repeatable)",
    )
    parser.add_argument("--mode", choices=("peer", "client"), default="peer")
    parser.add_argument(
        "--duration", type=float, default=0.0, help="stop after S seconds (default: Ctrl-C)"
    )


def run(args: argparse.Namespace) -> int:
    from groundstation.view.watch import run_watch

    settings = BusSettings(
        mode=args.mode, listen=(), connect=tuple(args.connect or ["tcp/127.0.0.1:7447"]),
    )
    with contextlib.suppress(KeyboardInterrupt):
        run_watch(args.station, settings, duration_s=args.duration)
    return 0
