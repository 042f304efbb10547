"""``groundstation router``: a Zenoh router (TLS, mutual TLS, access control) from TOML."""

from __future__ import annotations

import argparse
import signal
import threading
from typing import Any

from groundstation.commands.options import add_config
from groundstation.config import DEFAULT_ENDPOINT, DURATION, ROUTER, convert

NAME = "router"
HELP = "a Zenoh router: listen endpoints, TLS, mutual TLS, access control per station"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config(parser, ROUTER, "config/router.toml: listen, [tls], [access], [stations.<name>]")
    parser.add_argument("--listen", action="append", metavar="ENDPOINT",
                        help=f"endpoint to listen on (default {DEFAULT_ENDPOINT}; repeatable)")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="another router to connect to (repeatable)")
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default: until SIGINT/SIGTERM)")


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The command line as a layer with the configuration file's key names."""
    out: dict[str, Any] = {}
    for k in ("listen", "connect"):
        if getattr(args, k, None):
            out[k] = list(getattr(args, k))
    if args.duration is not None:
        out["duration_s"] = convert(DURATION, "duration", args.duration, origin="command line")
    return out


def run(args: argparse.Namespace) -> int:
    from groundstation.config import load_router_settings
    from groundstation.router import run_router

    settings = load_router_settings(args.config, overrides=overrides_from_args(args))
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if settings.duration_s > 0:
        timer = threading.Timer(settings.duration_s, stop.set)
        timer.daemon = True
        timer.start()
    run_router(settings, stop)
    return 0
