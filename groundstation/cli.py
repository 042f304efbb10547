"""Command-line entry point: parses arguments, sets up logging, dispatches to a subcommand."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from groundstation import __version__
from groundstation.commands import COMMANDS, HELP
from groundstation.errors import ConfigError, GroundstationError

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="groundstation",
        description="Ground station and post-flight solver for UAV photogrammetry "
        "with a u-blox L1 receiver over a radio link.",
    )
    parser.add_argument("--version", action="version", version=f"groundstation {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    # Only the chosen subcommand's module is imported (Zenoh, the simulator ... are heavy).
    wanted = next((a for a in argv if a in COMMANDS), None)
    for name in COMMANDS:
        p = sub.add_parser(name, help=HELP.get(name, ""))
        if name == wanted:
            importlib.import_module(COMMANDS[name]).add_arguments(p)
    return parser


def setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    logging.basicConfig(
        level=level,
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
        stream=sys.stderr,
    )


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(args_list)
    args = parser.parse_args(args_list)
    if not args.command:
        parser.print_help()
        return EXIT_CONFIG
    setup_logging(args.verbose, args.quiet)
    module = importlib.import_module(COMMANDS[args.command])
    try:
        return int(module.run(args))
    except ConfigError as err:
        print(f"groundstation {args.command}: {err}", file=sys.stderr)
        return EXIT_CONFIG
    except GroundstationError as err:
        print(f"groundstation {args.command}: error: {err}", file=sys.stderr)
        return EXIT_FAILURE
    except BrokenPipeError:  # output piped into head & co.
        sys.stderr.close()
        return EXIT_OK
    except KeyboardInterrupt:
        print(f"groundstation {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
