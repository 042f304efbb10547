"""``groundstation configure``: send a receiver profile's CFG messages and check every ACK."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TextIO

from groundstation.errors import ConfigError
from groundstation.serialport import SerialLink
from groundstation.ubx.cfg import Profile, load_profile
from groundstation.ubx.configure import (
    DEFAULT_RETRIES,
    DEFAULT_SETTLE_S,
    DEFAULT_TIMEOUT_S,
    MessageResult,
    Outcome,
    send_messages,
)

NAME = "configure"
HELP = "send receiver configuration (CFG-*) and check ACKs"
DEFAULT_BAUD = 9600  # u-blox factory default on UART1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", help="serial device of the receiver, e.g. /dev/wi232")
    parser.add_argument(
        "--baud", type=int, default=DEFAULT_BAUD,
        help=f"the rate the receiver's port runs at now (default {DEFAULT_BAUD})",
    )
    parser.add_argument(
        "--profile", required=True,
        help="profile name (config/profiles/NAME.toml or /etc/groundstation/profiles) "
        "or a path to a .toml file",
    )
    parser.add_argument(
        "--profile-dir", type=Path, action="append", default=None,
        help="look for profiles here instead (repeatable)",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="print each message's bytes; open nothing"
    )
    parser.add_argument(
        "--timeout", type=float, default=DEFAULT_TIMEOUT_S,
        help=f"seconds to wait for each ACK (default {DEFAULT_TIMEOUT_S:g})",
    )
    parser.add_argument(
        "--retries", type=int, default=DEFAULT_RETRIES,
        help=f"further attempts after a timeout (default {DEFAULT_RETRIES})",
    )
    parser.add_argument(
        "--via", choices=("uart1", "other"), default="uart1",
        help="the receiver port this device is wired to: after a UART1 baud change, "
        "configure follows it only when connected through UART1 (default)",
    )
    parser.add_argument(
        "--settle", type=float, default=DEFAULT_SETTLE_S,
        help=f"seconds to wait after reopening at a new baud (default {DEFAULT_SETTLE_S:g})",
    )


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    profile = load_profile(args.profile, args.profile_dir)
    if not args.dry_run:
        from groundstation.commands.run import port_problem

        problem = port_problem(args.port, prog="groundstation configure")
        if problem is not None:  # the daemon's one line, not pyserial's nested errno text
            print(problem, file=sys.stderr, flush=True)
            return 1
    out = sys.stdout
    out.write(f"profile {profile.name}: {profile.receiver}  ({profile.path})\n")
    if args.dry_run:
        out.write(format_dry_run(profile))
        return 0
    link = SerialLink(args.port, args.baud)
    out.write(f"port {args.port} at {args.baud} baud, {len(profile.messages)} messages\n")
    results: list[MessageResult] = []
    try:
        for result in send_messages(
            link, profile.messages, timeout_s=args.timeout, retries=args.retries,
            follow_baud=args.via == "uart1", settle_s=args.settle,
        ):
            results.append(result)
            out.write(format_result(result) + "\n")
            out.flush()
    finally:
        link.close()
    return _summary(results, args.baud, out)


def _check_args(args: argparse.Namespace) -> None:
    if not args.dry_run and not args.port:
        raise ConfigError("port", "--port is required unless --dry-run is given")
    if args.baud <= 0:
        raise ConfigError("baud", f"must be a positive baud rate, not {args.baud}")
    if not args.timeout > 0:
        raise ConfigError("timeout", f"must be > 0 seconds, not {args.timeout:g}")
    if args.retries < 0:
        raise ConfigError("retries", f"must be >= 0, not {args.retries}")
    if args.settle < 0:
        raise ConfigError("settle", f"must be >= 0 seconds, not {args.settle:g}")


def format_dry_run(profile: Profile) -> str:
    """Each message: number, name, what it does, length and bytes in hex."""
    lines = []
    for m in profile.messages:
        baud = f"  [UART1 -> {m.uart1_baud} baud after the ACK]" if m.uart1_baud else ""
        lines.append(f"{m.index:2d} {m.name:<10} {m.summary}{baud}")
        lines.append(f"   {len(m.frame)} bytes: {m.hex}")
    return "\n".join(lines) + "\n"


def format_result(r: MessageResult) -> str:
    """One report line: number, name, length, result, attempts, time, and why if not ACK."""
    m = r.message
    line = (
        f"{m.index:2d} {m.name:<10} {len(m.frame):3d} bytes  {r.outcome.value:<7} "
        f"attempts {r.attempts}  {r.elapsed_s * 1e3:6.0f} ms  {m.summary}"
    )
    return f"{line}\n   -> {r.detail}" if r.detail else line


def _summary(results: list[MessageResult], baud_before: int, out: TextIO) -> int:
    by = {o: sum(r.outcome is o for r in results) for o in Outcome}
    ok = by[Outcome.ACK] == len(results)
    verdict = "receiver configured" if ok else "CONFIGURATION INCOMPLETE"
    out.write(
        f"{verdict}: {by[Outcome.ACK]} acknowledged, {by[Outcome.NAK]} refused (NAK), "
        f"{by[Outcome.TIMEOUT]} without reply, {by[Outcome.SKIPPED]} skipped "
        f"of {len(results)}\n"
    )
    baud_after = results[-1].baud if results else baud_before
    if baud_after != baud_before:
        out.write(f"receiver UART1 now at {baud_after} baud: set the daemon to match\n")
    return 0 if ok else 1
