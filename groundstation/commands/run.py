"""``groundstation run``: the live daemon (config file, environment and command-line overrides)."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

from groundstation.commands.options import add_config, add_zenoh_daemon, zenoh_layer
from groundstation.config import DAEMON, Key, convert, load_settings
from groundstation.live.daemon import RunSummary, run_daemon

NAME = "run"
HELP = "the live daemon: receive, decode and record a station's stream"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config(parser, DAEMON, "config/groundstation.toml")
    src = parser.add_mutually_exclusive_group()
    src.add_argument("--port", metavar="DEV", help="serial device (e.g. /dev/ttyUSB0)")
    src.add_argument("--tcp", metavar="HOST:PORT", help="TCP server streaming UBX")
    src.add_argument("--file", type=Path, metavar="PATH",
                     help=".ubx, .ubx.gz or .mcap recording (a session's later parts follow)")
    parser.add_argument("--baud", metavar="N",
                        help="serial baud rate, = the receiver's UART1 rate (default 115200; "
                        "the lea6t-5hz profile sets 57600)")
    parser.add_argument("--rate", metavar="BYTES_PER_S", type=float,
                        help="pace a --file source (0 = as fast as possible)")
    parser.add_argument("--station", help="station name (names the recording files)")
    parser.add_argument("--out-dir", type=Path, metavar="DIR",
                        help="directory for recordings (default flights)")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    add_zenoh_daemon(parser)


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The command-line layer of the configuration (only what was given)."""
    layer: dict[str, Any] = {}
    source: dict[str, Any] = {}
    if args.port is not None:
        source["port"] = args.port
    if args.tcp is not None:
        source["address"] = args.tcp
    if args.file is not None:
        source["path"] = args.file
    if args.baud is not None:
        source["baud"] = convert(Key("int"), "source.baud", args.baud, from_text=True,
                                 origin="command line")
    if args.rate is not None:
        source["rate_bytes_per_s"] = args.rate
    if source:
        layer["source"] = source
    if args.station is not None:
        layer["station"] = args.station
    if args.out_dir is not None:
        layer["recorder"] = {"out_dir": args.out_dir}
    if args.duration is not None:
        layer["duration_s"] = args.duration
    zenoh = zenoh_layer(args)
    if zenoh:
        layer["zenoh"] = zenoh
    return layer


def _print_summary(summary: RunSummary) -> None:
    print(f"session {summary.session_id} stopped by {summary.stopped_by} "
          f"after {summary.duration_s:.1f} s")
    print(f"  received {summary.bytes_in} bytes in {summary.chunks} chunks; "
          f"{summary.frames} frames, {summary.garbage_bytes} garbage bytes, "
          f"{summary.records} records, {summary.events} events, {summary.outages} outage(s)")
    for name, n in summary.frames_by_type.items():
        print(f"    {name:<14} {n}")
    if summary.write_failures:
        lost = (f"{summary.dropped_raw_bytes} raw bytes and {summary.dropped_records} records "
                "dropped beyond the memory bound" if summary.dropped_raw_bytes
                or summary.dropped_records else "nothing dropped")
        held = (f"; {summary.lost_held_bytes} bytes still held in memory at the end were lost"
                if summary.lost_held_bytes else "")
        print(f"  recording failed {summary.write_failures} time(s) (disk full?): {lost}{held}")
    for q in summary.queues:
        print(f"  sink {q.name}: delivered {q.delivered}, dropped {q.dropped}, "
              f"over limit {q.over_limit}, high water {q.high_water}")
    for path in summary.files:
        print(f"  wrote {path}")
    for path in summary.sidecars:
        print(f"  wrote {path}")
    for path in summary.lost_files:
        print(f"  lost {path} (deleted while recording)")


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.config, overrides=overrides_from_args(args))
    if settings.source.kind == "file":
        from groundstation.offline.inspect import require_ubx_frames

        require_ubx_frames(settings.source.path)

    def on_file(path: Path) -> None:
        print(f"recording to {path}", flush=True)

    summary = asyncio.run(run_daemon(settings, handle_signals=True, on_file=on_file))
    _print_summary(summary)
    sys.stdout.flush()
    if summary.bytes_in == 0:
        # Not "0 outages" and exit 0: a session that received nothing is a failure to say.
        src = settings.source
        where = {"serial": lambda: f"serial port {getattr(src, 'port', '?')}",
                 "tcp": lambda: f"TCP {getattr(src, 'host', '?')}:{getattr(src, 'port', '?')}",
                 "file": lambda: f"file {getattr(src, 'path', '?')}"}[src.kind]()
        print(f"groundstation run: error: no data received from the {where} in "
              f"{summary.duration_s:.0f} s (see the source lines above: wrong device, cable, "
              "baud rate or server?)", file=sys.stderr)
        return 1
    return 0
