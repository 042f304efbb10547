"""``groundstation inspect``: a recording's span, messages, damage, epochs, gaps and marks."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from groundstation import gpstime
from groundstation.offline.inspect import Summary, inspect_path, require_ubx_frames
from groundstation.offline.merge import one_recording

NAME = "inspect"
HELP = "summary of a recording: span, epochs, gaps, marks, satellites"
MAX_GAPS_SHOWN = 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", nargs="+", metavar="RECORDING",
                        help="recording: .ubx, .ubx.gz, raw log or .mcap; several copies of "
                        "one receiver's recording (the radio link's and an on-board log) are "
                        "inspected as merged frame by frame")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--max-payload", type=int, default=8192, metavar="BYTES",
        help="longest UBX payload accepted",
    )


def run(args: argparse.Namespace) -> int:
    paths = [Path(p) for p in args.path]
    if len(paths) == 1:
        # No UBX frame at all: an error (exit 2), not an all-zero report that reads like a
        # result.
        require_ubx_frames(paths[0], max_payload=args.max_payload)
    with one_recording(paths) as (source, merged):
        summary = inspect_path(source, max_payload=args.max_payload)
    if merged is not None:  # the copies' names, not the temporary file's
        summary = replace(summary, path=" + ".join(str(p) for p in paths) + " (merged)")
    if args.json:
        from groundstation import jsonio  # msgspec only for --json (start-up time of inspect)

        obj = summary.as_json()
        if merged is not None:
            obj["merged_from"] = merged.text()
        sys.stdout.write(jsonio.dumps(obj, indent=2).decode())
        sys.stdout.write("\n")
    else:
        if merged is not None:
            sys.stdout.write(merged.text() + "\n")
        sys.stdout.write(format_summary(summary))
    return 0


def format_summary(s: Summary) -> str:
    size = (f"{s.file_bytes:,} bytes on disk, {s.bytes:,} bytes of receiver stream"
            if s.format == "mcap" or s.file_bytes != s.bytes else f"{s.bytes:,} bytes")
    lines = [f"{s.path}  ({s.format}, {size})"]
    if s.first_epoch_t_gps_ns is not None and s.last_epoch_t_gps_ns is not None:
        dur = (s.last_epoch_t_gps_ns - s.first_epoch_t_gps_ns) / 1e9
        first = gpstime.gps_to_datetime(s.first_epoch_t_gps_ns)
        last = gpstime.gps_to_datetime(s.last_epoch_t_gps_ns)
        lines.append(
            f"span      {gpstime.format_gps(s.first_epoch_t_gps_ns)} .. "
            f"{gpstime.format_gps(s.last_epoch_t_gps_ns)}  ({dur:.1f} s)"
        )
        lines.append(f"          {first:%Y-%m-%d %H:%M:%S} .. {last:%H:%M:%S} UTC")
    else:
        lines.append("span      no epochs with a GPS time")
    lines.append(
        f"frames    {s.frames:,} valid, {s.damaged_frames} damaged "
        f"(bad checksum {s.damage['bad_checksum']}, too long {s.damage['too_long']}, "
        f"truncated {s.damage['truncated']}), {s.garbage_bytes:,} garbage bytes"
    )
    if s.skipped:
        lost = sum(k.bytes for k in s.skipped)
        many = "es" if len(s.skipped) > 1 else ""
        lines.append(f"unread    {len(s.skipped)} damaged stretch{many} of the file skipped "
                     f"({lost:,} bytes): what they held is missing below")
        lines.extend(f"  {k.describe()}" for k in s.skipped)
    if s.orphan_messages:
        lines.append(f"          {s.orphan_messages:,} messages after them on channels defined "
                     "only in the skipped bytes: not read")
    if s.nmea_sentences or s.rtcm3_frames:
        lines.append(f"foreign   {s.nmea_sentences} NMEA sentences, {s.rtcm3_frames} RTCM3 frames")
    if s.undecodable:
        lines.append(f"          {s.undecodable} frames pyubx2 could not parse (bytes kept)")
    if s.implausible:
        parts = ", ".join(f"{name} {n}" for name, n in s.implausible.items())
        lines.append(f"          {sum(s.implausible.values())} frames with a time that cannot "
                     f"belong to the session, not used (bytes kept): {parts}")
    if s.time_jumps:
        lines.append(f"          the receiver's time jumped {s.time_jumps} time(s), each "
                     "confirmed by the next epoch (the epoch before it not used)")
    lines.append("messages")
    for name, n in s.messages.items():
        lines.append(f"  {name:<14} {n:>8}")
    interval = f"{s.epoch_interval_s:g} s" if s.epoch_interval_s else "n/a"
    extra = f", {s.empty_epochs} without time or measurements" if s.empty_epochs else ""
    lines.append(
        f"epochs    {s.epochs} at {interval} interval, up to {s.max_sats_per_epoch} "
        f"measurements{extra}"
    )
    lines.append(f"gaps      {len(s.gaps)} gaps, {s.missing_epochs} epochs missing")
    for g in s.gaps[:MAX_GAPS_SHOWN]:
        utc = gpstime.gps_to_datetime(g.after_t_gps_ns)
        lines.append(
            f"  after {gpstime.format_gps(g.after_t_gps_ns)} ({utc:%H:%M:%S.%f}"[:-3]
            + f" UTC): {g.missing_epochs} missing ({g.duration_s:.1f} s between epochs)"
        )
    if len(s.gaps) > MAX_GAPS_SHOWN:
        lines.append(f"  ... {len(s.gaps) - MAX_GAPS_SHOWN} more (use --json for all)")
    tm = s.timemarks
    if not tm.records:
        lines.append("marks     none: no camera marks in this recording (hot-shoe cable on the "
                     "receiver's EXTINT0 pin? time-mark output on: groundstation configure)")
    else:
        lines.append(
            f"marks     {tm.records} time-mark records: {tm.falling} falling edges, "
            f"{tm.rising} rising edges, {tm.count_jumps} count jumps "
            f"({tm.missed_marks} marks missed), {tm.repeated_counts} repeated"
        )
    if tm.missed_marks:
        lines.append(
            f"          missed: {tm.lost_on_link} lost on the radio link (their epochs did "
            f"not arrive either: check the link, or log on board), {tm.not_reported} not "
            "received although the epochs around them were (damaged bytes, or two pulses in "
            "one measurement period)")
    if tm.records:
        lines.append(
            f"          count {tm.first_count} .. {tm.last_count} (the receiver's, at each "
            f"falling edge: mark_NNNN), time base "
            f"{', '.join(tm.time_bases)}"
        )
    unknown = (f" (+ {s.unknown_slot_signals} measurements of GLONASS satellites the receiver "
               "had not identified yet: no satellite number, not usable)"
               if s.unknown_slot_signals else "")
    lines.append(f"satellites {len(s.satellites)}: {' '.join(s.satellites)}{unknown}")
    return "\n".join(lines) + "\n"
