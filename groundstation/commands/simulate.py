"""``groundstation simulate``: a realistic LEA-6T stream to a file, a pty or a TCP port."""

from __future__ import annotations

import argparse
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from groundstation.errors import ConfigError
from groundstation.outpaths import check_output_file
from groundstation.pacing import paced
from groundstation.sim.faults import FaultConfig
from groundstation.sim.profiles import DEFAULT_DURATION_S, DEFAULT_FAULTS, PROFILES, sim_config
from groundstation.sim.ptylink import PtyLink
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
    add_profile_arguments(parser)
    parser.add_argument("--truth", metavar="FILE", help="write the truth JSON here")
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


def run(args: argparse.Namespace) -> int:
    if args.duration is None:
        args.duration = DEFAULT_DURATION_S[args.profile]
    if args.duration <= 0:
        raise ConfigError("duration", "must be positive")
    live = bool(args.pty or args.tcp)
    outs = [("--out", None if live else (args.out or "sim_rover.ubx")),
            ("--base-out", args.base_out), ("--truth", args.truth)]
    given = [(opt, Path(v)) for opt, v in outs if v]
    for i, (opt, path) in enumerate(given):
        for other_opt, other in given[:i]:  # two options naming one file: both are outputs
            if path.resolve() == other.resolve():
                raise ConfigError(opt, f"{path} is also the {other_opt} file: name another file")
        check_output_file(path, key=opt, force=args.force)
    faults = FaultConfig.load(args.faults or DEFAULT_FAULTS[args.profile])
    speed = parse_speed(args.speed, live)
    started = time.monotonic()
    result = simulate(sim_config(args.profile, duration_s=args.duration, seed=args.seed,
                                 severity=args.severity, faults=faults,
                                 with_base=bool(args.base_out) or not live))
    gen_s = time.monotonic() - started
    if args.truth:
        result.write_truth(args.truth)
    if args.base_out:
        Path(args.base_out).write_bytes(result.base_bytes)
    log = result.fault_log
    summary = (
        f"simulated {args.duration:.0f} s in {gen_s:.1f} s: "
        f"{result.truth['receivers']['rover']['epochs']} epochs, "
        f"{len(result.truth['exposures'])} exposures, {log.frames_sent} frames, "
        f"{log.frames_sent - log.frames_intact} damaged by faults"
    )
    if args.pty:
        print(summary, file=sys.stderr)
        _serve_pty(result.rover_chunks, speed)
        return 0
    if args.tcp:
        print(summary, file=sys.stderr)
        _serve_tcp(args.tcp, paced(result.rover_chunks, speed))
        return 0
    out = args.out or "sim_rover.ubx"
    with open(out, "wb") as fh:
        for _, chunk in paced(result.rover_chunks, speed):
            fh.write(chunk)
    print(summary)
    print(f"rover stream: {out}")
    if args.base_out:
        print(f"base stream: {args.base_out}")
    if args.truth:
        print(f"truth: {args.truth}")
    return 0
