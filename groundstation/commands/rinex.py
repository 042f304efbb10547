"""``groundstation rinex``: a recording to RINEX observation and navigation files + marks table."""

from __future__ import annotations

import argparse
import sys
import time

from groundstation.errors import ConfigError, GroundstationError
from groundstation.offline import rinex
from groundstation.rules.marks import MARK_EDGES
from groundstation.storage.reading import Recording

NAME = "rinex"
HELP = "MCAP/.ubx -> RINEX 2.11/3.04 obs + nav + time-mark table"
PROGRESS_MIN_BYTES = 4 << 20
"""Inputs at least this large show progress on stderr."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="recording: .ubx, .ubx.gz, raw log or .mcap")
    parser.add_argument("-o", "--out-dir", required=True, metavar="DIR", help="output directory")
    parser.add_argument(
        "--rinex", choices=rinex.RINEX_VERSIONS, default="3.04", help="RINEX version (3.04)"
    )
    parser.add_argument(
        "--marks",
        choices=MARK_EDGES,
        default="falling",
        help="edge of each time mark written as event epoch: falling (default), rising, "
        "both, or mid (the middle of the pulse)",
    )
    parser.add_argument(
        "--shutter-delay-ms",
        type=float,
        default=0.0,
        help="added to every event time (camera shutter lag after the hot-shoe edge)",
    )
    parser.add_argument("--marker", default=None, help="MARKER NAME (default: input stem)")
    parser.add_argument(
        "--progress",
        choices=("auto", "always", "never"),
        default="auto",
        help="progress on stderr (auto: for inputs over 4 MiB on a terminal or not)",
    )


class _Progress:
    """One updating stderr line: stage and percentage, at most every 0.2 s."""

    def __init__(self) -> None:
        self._last = 0.0

    def __call__(self, stage: str, fraction: float) -> None:
        now = time.monotonic()
        if now - self._last < 0.2 and fraction < 1.0:
            return
        self._last = now
        sys.stderr.write(f"\rrinex: {stage:<6} {fraction * 100:5.1f} %")
        sys.stderr.flush()

    def done(self) -> None:
        sys.stderr.write("\r" + " " * 30 + "\r")
        sys.stderr.flush()


def run(args: argparse.Namespace) -> int:
    if not -10_000.0 <= args.shutter_delay_ms <= 10_000.0:
        raise ConfigError("shutter-delay-ms", "must be between -10000 and 10000 ms")
    opts = rinex.RinexOptions(
        version=args.rinex,
        marks=args.marks,
        shutter_delay_ns=round(args.shutter_delay_ms * 1e6),
        marker=args.marker,
    )
    show = args.progress == "always"
    if args.progress == "auto":
        try:
            show = Recording(args.input).size_bytes >= PROGRESS_MIN_BYTES
        except GroundstationError:
            show = False
    prog = _Progress() if show else None
    try:
        res = rinex.convert(args.input, args.out_dir, opts, prog)
    finally:
        if prog is not None:
            prog.done()
    print(f"{res.obs_path}: {res.epochs} epochs ({res.source}), {res.events} event epochs")
    print(f"{res.nav_path}: {res.ephemerides} GPS ephemerides")
    print(f"{res.marks_path}: {res.marks} marks, {res.marks_in_dropout} inside a dropout")
    print(
        f"frames: {res.frames} valid, {res.damaged_frames} damaged sync words; "
        f"{res.dropped_epochs} epochs not written (empty or out of order); "
        f"{res.nav_parity_errors} subframes failed parity"
    )
    if res.skipped_systems:
        print(f"not in RINEX 2.11, left out: {' '.join(res.skipped_systems)}")
    for note in res.notes:
        print(f"note: {note}")
    return 0
