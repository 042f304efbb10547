"""``groundstation solver``: the service that solves each session when the daemon finishes it."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path
from typing import Any

NAME = "solver"
HELP = "the solver service: listens on Zenoh and solves a session when it finishes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, metavar="FILE",
                        help="solver TOML (defaults, [zenoh], [stations.<name>]); see "
                             "config/solver.toml")
    parser.add_argument("--station", help="station whose sessions to solve (default: all, '*')")
    parser.add_argument("--base", metavar="FILE",
                        help="base recording (.ubx/.obs) for every station; may use {dir}, "
                             "{stem}, {station} of the session's recording")
    parser.add_argument("--base-xyz", metavar="X,Y,Z", help="known base position, ECEF metres")
    parser.add_argument("--photos", metavar="DIR", help="photo directory (same placeholders)")
    parser.add_argument("--out-root", metavar="DIR",
                        help="solutions go to DIR/<station>/<recording> (default: solutions)")
    parser.add_argument("--lever-arm", metavar="X,Y,Z", help="lever arm, camera frame, metres")
    parser.add_argument("--interp", help="linear, spline or smoother (default smoother)")
    parser.add_argument("--epsg", help="output CRS (default: the WGS84 UTM zone)")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="Zenoh endpoint of the daemon (default tcp/127.0.0.1:7447)")
    parser.add_argument("--listen", action="append", metavar="ENDPOINT",
                        help="Zenoh endpoint to listen on (default: none)")
    parser.add_argument("--mode", choices=("peer", "client"), help="Zenoh mode (default peer)")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="stop after S seconds (default: until SIGINT/SIGTERM)")


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The command line as a layer with the configuration file's key names."""
    out: dict[str, Any] = {}
    for opt, k in (("station", "station"), ("base", "base"), ("base_xyz", "base_xyz"),
                   ("photos", "photos"), ("out_root", "out_root"), ("lever_arm", "lever_arm"),
                   ("interp", "interp"), ("epsg", "epsg")):
        v = getattr(args, opt)
        if v is not None:
            out[k] = v
    zen: dict[str, Any] = {}
    if args.connect:
        zen["connect"] = list(args.connect)
    if args.listen:
        zen["listen"] = list(args.listen)
    if args.mode:
        zen["mode"] = args.mode
    if zen:
        out["zenoh"] = zen
    return out


def run(args: argparse.Namespace) -> int:
    from groundstation.errors import ConfigError
    from groundstation.solve.service import load_service_settings, run_service

    if args.duration < 0:
        raise ConfigError("duration", "must be >= 0")
    settings = load_service_settings(args.config, overrides_from_args(args))
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration > 0:
        timer = threading.Timer(args.duration, stop.set)
        timer.daemon = True
        timer.start()
    configured = sorted(settings.stations)
    base = "a base for every station" if settings.default.base else (
        f"a base for {', '.join(configured)}" if configured else "no base (nothing will be solved)")
    print(f"solver: {base}; solutions under {settings.default.out_root}/<station>/",
          file=sys.stderr, flush=True)
    service = run_service(settings, stop)
    print(f"solver: stopped: {service.solved} solved, {service.failed} failed, "
          f"{service.skipped} not solved", flush=True)
    return 0
