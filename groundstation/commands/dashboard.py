"""``groundstation dashboard``: the operator's web page on 127.0.0.1, fed live from Zenoh."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from types import FrameType

from groundstation.bus import BusSettings
from groundstation.errors import ConfigError

NAME = "dashboard"
HELP = "local web dashboard of the stations on Zenoh (sky plot, link, marks, PPK readiness)"

log = logging.getLogger("groundstation.dashboard")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--station", action="append", metavar="NAME",
        help="station to show from the start (repeatable; others are discovered from their "
        "liveliness tokens)",
    )
    parser.add_argument("--port", type=int, default=8080, help="web server port (default 8080; "
                        "0 picks a free one)")
    parser.add_argument("--bind", default="127.0.0.1",
                        help="web server address (default 127.0.0.1: this machine only)")
    parser.add_argument(
        "--connect", action="append", metavar="ENDPOINT",
        help="Zenoh endpoint of the daemon (default tcp/127.0.0.1:7447; repeatable)",
    )
    parser.add_argument("--mode", choices=("peer", "client"), default="peer")
    parser.add_argument("--ppk-min", type=int, default=None, metavar="N",
                        help="satellites with clean phase the PPK gauge asks for (default 5, "
                        "the monitor's ppk_ready_min)")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C or SIGTERM)")


def run(args: argparse.Namespace) -> int:
    from groundstation.view.dashboard import Dashboard, DashboardSettings
    from groundstation.view.dashboard.state import PPK_READY_MIN

    if not 0 <= args.port <= 65535:
        raise ConfigError("port", f"{args.port} is not a TCP port")
    settings = DashboardSettings(
        stations=tuple(args.station or ()),
        bind=args.bind,
        port=args.port,
        bus=BusSettings(mode=args.mode, listen=(),
                        connect=tuple(args.connect or ["tcp/127.0.0.1:7447"])),
        ppk_ready_min=args.ppk_min if args.ppk_min is not None else PPK_READY_MIN,
    )
    try:
        dashboard = Dashboard(settings)
    except OSError as err:
        raise ConfigError("port", f"cannot serve on {args.bind}:{args.port}: {err}") from err
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    with dashboard:
        dashboard.start()
        log.info("dashboard on %s (Zenoh %s)", dashboard.url, ", ".join(settings.bus.connect))
        print(f"dashboard: {dashboard.url}", flush=True)
        stop.wait(args.duration if args.duration > 0 else None)
    return 0
