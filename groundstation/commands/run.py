"""``groundstation run``: the live daemon (config file, environment and command-line overrides)."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import difflib
import glob
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from groundstation.commands.options import add_config, add_zenoh_daemon, zenoh_layer
from groundstation.config import DAEMON, Key, convert, load_settings
from groundstation.live.daemon import RunSummary, run_daemon
from groundstation.outpaths import check_output_dir, make_output_dir

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
    if summary.implausible_by_type:
        parts = ", ".join(f"{name} {n}" for name, n in sorted(summary.implausible_by_type.items()))
        print(f"  {sum(summary.implausible_by_type.values())} frames with a time that cannot "
              f"belong to the session (recorded, not decoded): {parts}")
    if summary.time_jumps:
        print(f"  the receiver's time jumped {summary.time_jumps} time(s), each confirmed by a "
              "second epoch (decoder.time_jump)")
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


SERIAL_GLOBS = ("/dev/ttyUSB*", "/dev/ttyACM*", "/dev/ttyAMA*", "/dev/serial/by-id/*")
"""Where a receiver's serial port usually is (USB adapters, CDC-ACM, a Raspberry Pi's UART)."""


def missing_port_line(port: str, present: Sequence[str] | None = None,
                      prog: str = "groundstation run") -> str:
    """One line for a serial device that does not exist, naming the nearest of the ``present``
    ones (default: those :data:`SERIAL_GLOBS` find); ``prog`` starts it."""
    if present is None:
        present = sorted({p for g in SERIAL_GLOBS for p in glob.glob(g)})
    near = difflib.get_close_matches(port, present, n=3, cutoff=0.0)
    hint = (f"existing: {', '.join(near)}" if near
            else "no serial device present: none of " + ", ".join(SERIAL_GLOBS))
    return (f"{prog}: error: {port} does not exist ({hint}); plug the receiver in "
            "or name its device with --port")


def port_problem(port: str, prog: str = "groundstation run") -> str | None:
    """The one line that refuses to start on ``port``, or None when it can be opened.

    Checked before the daemon starts, so that nothing is recorded, announced or served over
    Zenoh for a session that cannot receive anything (a device that goes away later is waited
    for: the source reconnects). A path that is not a device is the source's configuration
    error (exit 2); a device held by another process is refused by the source's claim.
    ``configure`` makes the same check (``prog`` names the command in the line).
    """
    if not os.path.exists(port):
        return missing_port_line(port, prog=prog)
    if not os.access(port, os.R_OK | os.W_OK):
        return (f"{prog}: error: cannot open {port}: permission denied (is this "
                "user in the dialout group?)")
    return None


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.config, overrides=overrides_from_args(args))
    if settings.source.kind == "file":
        from groundstation.offline.inspect import require_ubx_frames

        require_ubx_frames(settings.source.path)
    port = getattr(settings.source, "port", None)
    problem = port_problem(port) if settings.source.kind == "serial" and isinstance(
        port, str) else None
    if problem is not None:
        print(problem, file=sys.stderr, flush=True)
        return 1
    # The recording's directory, as every writer checks and makes it (outpaths): a file or a
    # directory that cannot be created is one line and exit 2, before anything starts.
    out_key = "--out-dir" if args.out_dir is not None else "recorder.out_dir"
    check_output_dir(settings.recorder.out_dir, key=out_key)
    created = make_output_dir(settings.recorder.out_dir, out_key)

    def on_file(path: Path) -> None:
        print(f"recording to {path}", flush=True)

    try:
        summary = asyncio.run(run_daemon(settings, handle_signals=True, on_file=on_file))
    except BaseException:
        if created:  # a source refused at start (a FIFO as --port): no empty directory left
            with contextlib.suppress(OSError):
                settings.recorder.out_dir.rmdir()  # only if empty
        raise
    empty = summary.bytes_in == 0
    # A device that was there and stayed silent keeps its files: they hold the session's
    # events (an operator's acknowledgement, the alerts).
    _print_summary(summary)
    sys.stdout.flush()
    if empty:
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
