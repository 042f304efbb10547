"""``groundstation dashboard``: the operator's web page on 127.0.0.1, fed live from Zenoh."""

from __future__ import annotations

import argparse
import errno
import ipaddress
import logging
import signal
import threading
from types import FrameType
from typing import TYPE_CHECKING

from groundstation.commands.options import add_config, add_zenoh_client, layer
from groundstation.config import DASHBOARD, resolve, zenoh_settings
from groundstation.errors import ConfigError, GroundstationError

if TYPE_CHECKING:
    from groundstation.view.dashboard import DashboardSettings

NAME = "dashboard"
HELP = "local web dashboard of the stations on Zenoh (sky plot, link, marks, PPK readiness)"

log = logging.getLogger("groundstation.dashboard")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config(parser, DASHBOARD, "[zenoh], stations, bind, port, ppk_min")
    parser.add_argument(
        "--station", action="append", metavar="NAME",
        help="station to show from the start (repeatable; others are discovered from their "
        "liveliness tokens)",
    )
    parser.add_argument("--port", type=int, help="web server port (default 8080; "
                        "0 picks a free one)")
    parser.add_argument("--bind",
                        help="web server address (default 127.0.0.1: this machine only)")
    add_zenoh_client(parser)
    parser.add_argument("--ppk-min", type=int, default=None, metavar="N",
                        help="satellites with clean phase the PPK gauge asks for (default: "
                        "the daemon's [monitor] ppk_ready_min, which its status carries)")
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C or SIGTERM)")


def is_loopback(bind: str) -> bool:
    """Whether a bind address serves this machine only (``127.0.0.1``, ``::1``, ``localhost``);
    ``0.0.0.0``, ``::`` or a host name may be reached from the network."""
    if bind == "localhost":
        return True
    try:
        return ipaddress.ip_address(bind).is_loopback
    except ValueError:
        return False


def settings_from_args(args: argparse.Namespace) -> tuple[DashboardSettings, float]:
    """The dashboard's settings and duration: defaults < file < environment < options."""
    from groundstation.view.dashboard import DashboardSettings

    top = resolve(DASHBOARD, args.config, overrides=layer(args, {
        "station": "stations", "port": "port", "bind": "bind", "ppk_min": "ppk_min",
        "duration": "duration_s"})).values
    values, duration_s = top[""], top[""].get("duration_s", 0.0)
    defaults = DashboardSettings()
    settings = DashboardSettings(
        stations=tuple(values.get("stations", defaults.stations)),
        bind=values.get("bind", defaults.bind),
        port=values.get("port", defaults.port),
        bus=zenoh_settings(top["zenoh"]),
        ppk_ready_min=values.get("ppk_min", defaults.ppk_ready_min),
    )
    return settings, duration_s


def run(args: argparse.Namespace) -> int:
    from groundstation.view.dashboard import Dashboard

    settings, duration_s = settings_from_args(args)
    try:
        dashboard = Dashboard(settings)
    except OSError as err:
        if err.errno == errno.EADDRINUSE:  # a runtime condition (exit 1), not a bad setting
            raise GroundstationError(
                f"port {settings.port} is in use on {settings.bind} (another dashboard?); "
                "choose another with --port") from err
        where = f"{settings.bind}:{settings.port}"
        raise ConfigError("port", f"cannot serve on {where}: {err}") from err
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    with dashboard:
        dashboard.start()
        log.info("dashboard on %s (Zenoh %s)", dashboard.url, ", ".join(settings.bus.connect))
        if not is_loopback(settings.bind):
            log.warning("the dashboard is reachable from other machines on %s: the page has no "
                        "authentication (anyone on the network can acknowledge alerts); keep "
                        "--bind 127.0.0.1 in the field", settings.bind)
        print(f"dashboard: {dashboard.url}", flush=True)
        stop.wait(duration_s if duration_s > 0 else None)
    return 0
