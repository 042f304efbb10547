"""``groundstation solver``: the service that solves each session when the daemon finishes it."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any

from groundstation.commands.options import add_config, add_zenoh_client, layer
from groundstation.config import DURATION, SOLVER, convert

NAME = "solver"
HELP = "the solver service: listens on Zenoh and solves a session when it finishes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config(parser, SOLVER, "config/solver.toml: defaults, [zenoh], [stations.<name>]")
    parser.add_argument("--station", help="station whose sessions to solve (default: all, '*')")
    parser.add_argument("--base", metavar="FILE",
                        help="base recording (.ubx/.obs) for every station; may use {dir}, "
                             "{stem}, {station} of the session's recording")
    parser.add_argument("--base-xyz", metavar="X,Y,Z", help="known base position, ECEF metres")
    parser.add_argument("--photos", metavar="DIR", help="photo directory (same placeholders)")
    parser.add_argument("--out-dir", "--out-root", dest="out_root", metavar="DIR",
                        help="solutions go to DIR/<station>/<recording> (default: solutions)")
    parser.add_argument("--recording-root", dest="recording_roots", action="append",
                        metavar="DIR", help="only recordings under DIR are solved (repeatable; "
                        "default: recordings, the daemon's default out_dir)")
    parser.add_argument("--lever-arm", metavar="X,Y,Z", help="lever arm, camera frame, metres")
    parser.add_argument("--interp", help="linear, spline or smoother (default smoother)")
    parser.add_argument("--epsg", help="output CRS (default: the WGS84 UTM zone)")
    add_zenoh_client(parser, "client")  # service.SOLVER_ZENOH
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="stop after S seconds (default: until SIGINT/SIGTERM)")


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The command line as a layer with the configuration file's key names."""
    return layer(args, {opt: opt for opt in (
        "station", "base", "base_xyz", "photos", "out_root", "lever_arm", "interp", "epsg",
        "recording_roots")})


def run(args: argparse.Namespace) -> int:
    from groundstation.solve.service import load_service_settings, run_service

    args.duration = convert(DURATION, "duration", args.duration, origin="command line")
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
          f"{service.skipped} not solved, {service.refused} refused, {service.rejected} "
          "messages dropped", flush=True)
    return 0
