"""``groundstation rinex``: a recording to RINEX observation and navigation files + marks table."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

from groundstation.errors import ConfigError
from groundstation.offline import rinex
from groundstation.offline.merge import one_recording
from groundstation.outpaths import check_output_dir, existing_outputs, make_output_dir
from groundstation.rules.marks import MARK_EDGES
from groundstation.storage.reading import Recording

NAME = "rinex"
HELP = "MCAP/.ubx -> RINEX 2.11/3.04 obs + nav + time-mark table"
PROGRESS_MIN_BYTES = 4 << 20
"""Inputs at least this large show progress on stderr."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", nargs="+", metavar="RECORDING",
                        help="recording: .ubx, .ubx.gz, raw log or .mcap; several copies of "
                        "one receiver's recording (the radio link's and an on-board log) are "
                        "merged frame by frame first")
    parser.add_argument("-o", "--out-dir", required=True, metavar="DIR", help="output directory")
    parser.add_argument(
        "--rinex", choices=rinex.RINEX_VERSIONS, default="3.04", help="RINEX version"
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
        metavar="MS",
        help="added to every event time (camera shutter lag after the hot-shoe edge)",
    )
    parser.add_argument("--no-events", action="store_true",
                        help="write no event epochs (the marks stay in the marks table): "
                        "RTKLIB's RINEX reader drops the epoch after an event where the "
                        "epochs' spacing changed, as after radio gaps")
    parser.add_argument("--marker", default=None,
                        help="MARKER NAME, 1 to 60 characters, written in ASCII (accents taken "
                        "off; default: input stem)")
    parser.add_argument(
        "--progress",
        choices=("auto", "always", "never"),
        default="auto",
        help="progress on stderr (auto: for inputs over 4 MiB, on a terminal only)",
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
    if args.marker is not None and not 0 < len(args.marker.strip()) <= 60:
        raise ConfigError("--marker", f"{args.marker!r}: a RINEX MARKER NAME has 1 to 60 "
                          "characters")
    opts = rinex.RinexOptions(
        version=args.rinex,
        marks=args.marks,
        shutter_delay_ns=round(args.shutter_delay_ms * 1e6),
        marker=args.marker,
        events=not args.no_events,
    )
    inputs = [Path(p) for p in args.input]
    # a missing, non-regular or unreadable input: one line
    recordings = [Recording(p) for p in inputs]
    stem = inputs[0].name
    for suffix in (".gz", ".ubx", ".mcap", ".log"):  # rinex.convert's names
        stem = stem.removesuffix(suffix)
    if len(inputs) > 1:
        stem = f"{inputs[0].name.split('.')[0]}_merged"  # merge.one_recording's name
    writes = (f"{stem}.obs", f"{stem}.nav", f"{stem}.marks.csv")
    check_output_dir(Path(args.out_dir), [q for r in recordings for q in r.parts],
                     key="--out-dir", writes=writes)
    replaced = existing_outputs(Path(args.out_dir), writes)
    if replaced:  # an earlier conversion (another RINEX version, another edge): not silently
        print(f"rinex: replacing the earlier {', '.join(replaced)} in {args.out_dir}",
              file=sys.stderr)
    show = args.progress == "always"
    if args.progress == "auto":
        show = (sum(r.size_bytes for r in recordings) >= PROGRESS_MIN_BYTES
                and sys.stderr.isatty())
    out = Path(args.out_dir)
    prog = _Progress() if show else None
    with one_recording(inputs) as (source, merged):
        created = make_output_dir(out, "--out-dir")
        try:
            res = rinex.convert(source, args.out_dir, opts, prog)
        except BaseException:
            if created:  # nothing of a failed run is left behind
                with contextlib.suppress(OSError):
                    out.rmdir()  # only if empty
            raise
        finally:
            if prog is not None:
                prog.done()
    if merged is not None:
        print(merged.text())
    if res.obs_written:
        print(f"{res.obs_path}: {res.epochs} epochs ({res.source}), {res.events} event epochs")
    names = {"R": "GLONASS", "E": "Galileo", "C": "BeiDou"}
    others = "".join(f", {n} {names.get(s, s)}" for s, n in res.other_ephemerides)
    print(f"{res.nav_path}: {res.ephemerides} GPS ephemerides{others}")
    if res.obs_written:
        print(f"{res.marks_path}: {res.marks} marks, {res.marks_in_dropout} inside a dropout")
    print(
        f"frames: {res.frames} valid, {res.damaged_frames} damaged sync words; "
        f"{res.dropped_epochs} epochs not written (empty or out of order); "
        f"{res.nav_parity_errors} subframes failed parity"
    )
    if res.implausible:
        print(f"implausible: {res.implausible} epochs and marks with a time that cannot "
              "belong to the session, left out")
    if res.skipped_systems:
        print(f"not in RINEX 2.11, left out: {' '.join(res.skipped_systems)}")
    for note in res.notes:
        print(f"note: {note}")
    return 0
