"""``groundstation watch``: a live terminal view of a station, from Zenoh only."""

from __future__ import annotations

import argparse
import contextlib

from groundstation.commands.options import add_config, add_zenoh_client, layer
from groundstation.config import WATCH, ZenohSettings, resolve, zenoh_settings

NAME = "watch"
HELP = "live terminal view of a station over Zenoh"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config(parser, WATCH, "[zenoh] and station = ...")
    parser.add_argument("--station", help="station name (default: station)")
    add_zenoh_client(parser)
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default: Ctrl-C)")


def settings_from_args(args: argparse.Namespace) -> tuple[str, ZenohSettings, float]:
    """Station, Zenoh settings and duration: defaults < file < environment < options."""
    values = resolve(WATCH, args.config, overrides=layer(
        args, {"station": "station", "duration": "duration_s"})).values
    from groundstation.view.watch import DEFAULT_STATION

    return (values[""].get("station", DEFAULT_STATION), zenoh_settings(values["zenoh"]),
            values[""].get("duration_s", 0.0))


def run(args: argparse.Namespace) -> int:
    from groundstation.view.watch import run_watch

    station, zenoh, duration_s = settings_from_args(args)
    with contextlib.suppress(KeyboardInterrupt):
        run_watch(station, zenoh, duration_s=duration_s)
    return 0
