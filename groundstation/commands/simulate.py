"""``groundstation simulate``: a realistic LEA-6T stream to a file, a pty or a TCP port; or a real
recording through the same radio link, as it was or as a LEA-6T would have sent it
(``--from-recording``, :mod:`groundstation.sim.rewrite`)."""

from __future__ import annotations

import argparse
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from groundstation import jsonio
from groundstation.errors import ConfigError
from groundstation.outpaths import check_output_file, staged_files
from groundstation.pacing import paced
from groundstation.sim.faults import FaultConfig
from groundstation.sim.profiles import DEFAULT_DURATION_S, DEFAULT_FAULTS, PROFILES, sim_config
from groundstation.sim.ptylink import PtyLink
from groundstation.sim.rewrite import FORMS, RewriteConfig, rewrite
from groundstation.sim.stream import simulate

NAME = "simulate"
HELP = "realistic u-blox stream to a pty, TCP port or file, with faults"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    out = parser.add_mutually_exclusive_group()
    out.add_argument("--out", metavar="FILE.ubx", help="write the rover stream to a file")
    out.add_argument("--pty", action="store_true", help="serve the stream on a new pty")
    out.add_argument("--tcp", metavar="PORT", type=int, help="serve on 127.0.0.1:PORT")
    parser.add_argument("--base-out", metavar="FILE.ubx", help="write the base stream here")
    parser.add_argument("--duration", metavar="S", type=float, default=None,
                        help="simulated span in seconds (default 600; seed profile 3000)")
    parser.add_argument("--speed", default=None,
                        help="1 (real time), N (N times faster) or max; default: max for "
                        "--out, 1 for --pty/--tcp")
    parser.add_argument("--seed", type=int, default=1,
                        help="simulation seed (same seed, same stream)")
    parser.add_argument("--faults", default=None, metavar="none|default|seed|FILE",
                        help="link and mark faults (default: none; seed profile: seed)")
    parser.add_argument("--from-recording", metavar="FILE",
                        help="replay a real recording (.ubx, .ubx.gz, .mcap) through the link "
                        "instead of simulating a flight: see what the radio would have cost it")
    parser.add_argument("--as", dest="as_form", choices=FORMS, default="lea6t",
                        help="with --from-recording: lea6t = as a LEA-6T would have sent it "
                        "(GPS L1 RXM-RAW, LLI from the lock times, RXM-SFRB); original = its "
                        "own frames unchanged")
    add_profile_arguments(parser)
    parser.add_argument("--truth", metavar="FILE", help="write the truth JSON here (with "
                        "--from-recording: what was converted and what the link did)")
    parser.add_argument("--force", action="store_true",
                        help="replace existing output files (never a recording)")


def add_profile_arguments(parser: argparse.ArgumentParser) -> None:
    """``--profile`` and ``--severity``, shared by ``simulate`` and ``demo``."""
    parser.add_argument("--profile", choices=PROFILES, default="default",
                        help="default: a gentle flight; seed: the field report's failed flight")
    parser.add_argument("--severity", type=float, default=1.0, metavar="S",
                        help="seed profile: loss-of-lock rate relative to the field flight "
                        "(1 = every 20 s per satellite, 0.5 half, 2 double)")


def parse_speed(value: str | None, live: bool) -> float | None:
    """``--speed``: 1 (real time), N (N times faster) or max (None); default by output."""
    if value is None:
        return 1.0 if live else None
    if value == "max":
        return None
    try:
        speed = float(value)
    except ValueError as err:
        raise ConfigError("speed", f"expected 1, N or max, not {value!r}") from err
    if speed <= 0:
        raise ConfigError("speed", "must be positive")
    return speed


def _serve_pty(chunks: list[tuple[int, bytes]], speed: float | None) -> None:
    link = PtyLink()
    print(link.path, flush=True)
    try:
        link.feed(chunks, speed)
        # Let the reader drain the buffer before the pty disappears.
        time.sleep(1.0)
    finally:
        link.close()


def _serve_tcp(port: int, chunks: Iterator[tuple[int, bytes]]) -> None:
    with socket.create_server(("127.0.0.1", port)) as server:
        print(f"listening on tcp://127.0.0.1:{port}", flush=True)
        conn, peer = server.accept()
        print(f"client {peer[0]}:{peer[1]} connected", file=sys.stderr, flush=True)
        with conn:
            for _, chunk in chunks:
                conn.sendall(chunk)


def _check_outputs(outs: list[tuple[str, str | None]], force: bool,
                   inputs: tuple[Path, ...] = ()) -> None:
    given = [(opt, Path(v)) for opt, v in outs if v]
    for i, (opt, path) in enumerate(given):
        for other_opt, other in given[:i]:  # two options naming one file: both are outputs
            if path.resolve() == other.resolve():
                raise ConfigError(opt, f"{path} is also the {other_opt} file: name another file")
        check_output_file(path, inputs, key=opt, force=force)


def _serve(chunks: list[tuple[int, bytes]], args: argparse.Namespace,
           speed: float | None) -> None:
    if args.pty:
        _serve_pty(chunks, speed)
    else:
        _serve_tcp(args.tcp, paced(chunks, speed))


def run(args: argparse.Namespace) -> int:
    if args.from_recording is not None:
        return run_recording(args)
    if args.as_form != "lea6t":
        raise ConfigError("--as", "only with --from-recording")
    if args.duration is None:
        args.duration = DEFAULT_DURATION_S[args.profile]
    if args.duration <= 0:
        raise ConfigError("duration", "must be positive")
    live = bool(args.pty or args.tcp)
    _check_outputs([("--out", None if live else (args.out or "sim_rover.ubx")),
                    ("--base-out", args.base_out), ("--truth", args.truth)], args.force)
    faults = FaultConfig.load(args.faults or DEFAULT_FAULTS[args.profile])
    speed = parse_speed(args.speed, live)
    # Every output opened (hidden, staged) before the work: one that cannot be written
    # (/proc, no permission) is a line naming its option, and the outputs appear only complete.
    outs = [(opt, Path(path)) for opt, path in (
        ("--out", None if live else args.out or "sim_rover.ubx"), ("--base-out", args.base_out),
        ("--truth", args.truth)) if path]
    with staged_files(outs) as handles:
        files = {opt: fh for (opt, _), fh in zip(outs, handles, strict=True)}
        started = time.monotonic()
        result = simulate(sim_config(args.profile, duration_s=args.duration, seed=args.seed,
                                     severity=args.severity, faults=faults,
                                     with_base=bool(args.base_out) or not live))
        gen_s = time.monotonic() - started
        if args.truth:
            files["--truth"].write(jsonio.dumps(result.truth))
        if args.base_out:
            files["--base-out"].write(result.base_bytes)
        log = result.fault_log
        summary = (
            f"simulated {args.duration:.0f} s in {gen_s:.1f} s: "
            f"{result.truth['receivers']['rover']['epochs']} epochs, "
            f"{len(result.truth['exposures'])} exposures, {log.frames_sent} frames, "
            f"{log.frames_sent - log.frames_intact} damaged by faults"
        )
        if not live:
            for _, chunk in paced(result.rover_chunks, speed):
                files["--out"].write(chunk)
    if args.pty:
        print(summary, file=sys.stderr)
        _serve_pty(result.rover_chunks, speed)
        return 0
    if args.tcp:
        print(summary, file=sys.stderr)
        _serve_tcp(args.tcp, paced(result.rover_chunks, speed))
        return 0
    print(summary)
    print(f"rover stream: {args.out or 'sim_rover.ubx'}")
    if args.base_out:
        print(f"base stream: {args.base_out}")
    if args.truth:
        print(f"truth: {args.truth}")
    return 0


def run_recording(args: argparse.Namespace) -> int:
    """``--from-recording``: a real recording through the link (every check before any
    output is created; the outputs appear only complete)."""
    from groundstation.offline.inspect import require_ubx_frames

    for opt, given in (("--base-out", args.base_out is not None),
                       ("--duration", args.duration is not None),
                       ("--profile", args.profile != "default"),
                       ("--severity", args.severity != 1.0)):
        if given:
            raise ConfigError(opt, "does not apply to --from-recording (the recording is the "
                              "flight; replay a base recording with its own --from-recording)")
    live = bool(args.pty or args.tcp)
    if not live and not args.out:
        raise ConfigError("--out", "--from-recording needs --out FILE.ubx (or --pty / --tcp)")
    source = Path(args.from_recording)
    require_ubx_frames(source)  # missing, a directory, a FIFO, not a recording: one line
    _check_outputs([("--out", args.out), ("--truth", args.truth)], args.force, (source,))
    faults = FaultConfig.load(args.faults or "none")
    speed = parse_speed(args.speed, live)
    started = time.monotonic()
    result = rewrite(source, RewriteConfig(form=args.as_form, faults=faults, seed=args.seed))
    took_s = time.monotonic() - started
    log = result.log
    lost = log["fault_summary"]
    summary = (
        f"replayed {source} as {'a LEA-6T' if args.as_form == 'lea6t' else 'recorded'} "
        f"in {took_s:.1f} s: {log['epochs']} epochs, {log['marks']} marks, "
        f"{lost['frames_sent']} frames; link ({args.faults or 'none'}, seed {args.seed}): "
        f"{len(log['link_gaps'])} gaps, {len(set(lost['epochs_lost_tow_ms']))} epochs and "
        f"{len(log['marks_lost'])} marks lost ({len(log['marks_hit'])} more lost one of their "
        f"records), {lost['frames_sent'] - lost['frames_intact']} frames damaged"
    )
    if live:
        if args.truth:
            with staged_files([("--truth", Path(args.truth))]) as (fh,):
                fh.write(jsonio.dumps(log))
        print(summary, file=sys.stderr)
        _serve(result.chunks, args, speed)
        return 0
    outs = [("--out", Path(args.out))] + ([("--truth", Path(args.truth))] if args.truth else [])
    with staged_files(outs) as handles:
        for _, chunk in paced(result.chunks, speed):
            handles[0].write(chunk)
        if args.truth:
            handles[1].write(jsonio.dumps(log))
    print(summary)
    print(f"stream: {args.out}")
    if args.truth:
        print(f"log: {args.truth}")
    return 0
