"""``groundstation watch``: a live terminal view of a station, from Zenoh only."""

from __future__ import annotations

import argparse
import contextlib

from groundstation.commands.options import add_config, add_zenoh_client, layer
from groundstation.config import WATCH, resolve, zenoh_settings

NAME = "watch"
HELP = "live terminal view of a station over Zenoh"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config(parser, WATCH, "[zenoh] and station = ...")
    parser.add_argument("--station", help="station name (default: station)")
    add_zenoh_client(parser)
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default: Ctrl-C)")


def run(args: argparse.Namespace) -> int:
    from groundstation.view.watch import run_watch

    values = resolve(WATCH, args.config, overrides=layer(
        args, {"station": "station", "duration": "duration_s"})).values
    with contextlib.suppress(KeyboardInterrupt):
        run_watch(values[""].get("station", "station"), zenoh_settings(values["zenoh"]),
                  duration_s=values[""].get("duration_s", 0.0))
    return 0
