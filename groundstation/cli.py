"""Command-line entry point: parses arguments, sets up logging, dispatches to a subcommand.

Exit statuses (every command, README "Commands"): 0 success; 1 a runtime failure (a device,
the disk or Zenoh failing); 2 bad input or configuration (a bad option, key, variable, station
name or configuration file, the message naming it; an input file that cannot be used; an output
that would replace an input or a recording); 130 interrupted (:data:`EXIT_INTERRUPTED`: not
for the commands that run until stopped). Every failure is one line on stderr, never a
traceback (``-vv`` adds the traceback of an unexpected one to the log).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import re
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from groundstation import __version__
from groundstation.commands import COMMANDS, EXAMPLES, HELP
from groundstation.errors import ConfigError, GroundstationError, InputError
from groundstation.invocation import examples
from groundstation.launch import EXIT_INTERRUPTED as EXIT_INTERRUPTED

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CONFIG = 2
FINISH_UNREAD = frozenset({"solve", "rinex", "locate-base", "simulate"})
"""Commands whose work is files: they finish it when nobody reads what they print any more
(``| head``, a pager quit early), instead of stopping half-way with nothing written."""
INTERRUPTS = frozenset({"SIGINT", "SIGTERM"})
"""The pipeline's ``stopped_by`` when a signal ended it."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (exit status 2), like every other
    failure; ``--help`` still prints the usage."""

    def error(self, message: str) -> NoReturn:
        hint = "see --help"
        m = re.match(r"argument (--[\w-]+): expected one argument", message)
        if m is not None:  # "--base-xyz -3978241.9,..." reads as an option to argparse
            hint = f"a value that starts with '-' goes after '=': {m.group(1)}=-1.5,... ; {hint}"
        self.exit(EXIT_CONFIG, f"{self.prog}: error: {' '.join(message.split())} ({hint})\n")


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the examples' line breaks and appends every option's default to its help.

    Unlike ``ArgumentDefaultsHelpFormatter`` it says nothing for an option without a default
    (None, False, an empty list: the help text says what happens then) and nothing when the
    help already names its default.
    """

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            "default" in text
            or default is None
            or default is False
            or default == []
            or default is argparse.SUPPRESS
            or not action.option_strings
        ):
            return text
        return f"{text} (default: %(default)s)"


def _add_log_options(parser: argparse.ArgumentParser, default: object) -> None:
    """``-v``/``-q``: on the top parser with real defaults, on each command with SUPPRESS so
    that ``groundstation run -q`` works and does not reset ``groundstation -q run``."""
    parser.add_argument(
        "-v", "--verbose", action="count", default=0 if default is None else default,
        help="more log output (-vv for debug)",
    )
    parser.add_argument(
        "-q", "--quiet", action="store_true",
        default=False if default is None else default,
        help="only warnings and errors",
    )


def _sentence(text: str) -> str:
    """A command's one-line help as its description: first letter up, the rest as written
    (``str.capitalize`` lowercased "MCAP", "RINEX", "Zenoh" and "xN")."""
    return f"{text[:1].upper()}{text[1:]}." if text else ""


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="groundstation",
        description="Ground station and post-flight solver for UAV photogrammetry "
        "with a u-blox L1 receiver over a radio link.",
        epilog=examples("examples:\n  groundstation demo\n  groundstation run --port "
                        "/dev/wi232 --station rover\n  groundstation COMMAND --help")
        + "\n\n"
        "exit status: 0 ok, 1 runtime failure (device, disk, Zenoh) or a run that gave no "
        "result, 2 bad input or configuration (the message names the option, key, variable or "
        "file; an input that cannot be used), 130 interrupted (Ctrl-C or SIGTERM) for the "
        "commands that end by themselves (demo, replay, inspect, rinex, solve, simulate, "
        "configure); run, watch, dashboard, solver, router and rtk run until stopped: Ctrl-C is "
        "their normal end (0)",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"groundstation {__version__}")
    _add_log_options(parser, None)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    # Only the chosen subcommand's module is imported (Zenoh, the simulator ... are heavy).
    wanted = _command_in(argv)
    for name in COMMANDS:
        example = "\n".join(f"  {line}" for line in
                            examples(EXAMPLES.get(name, "")).splitlines())
        p = sub.add_parser(
            name, help=HELP.get(name, ""),
            description=_sentence(HELP.get(name, "")),
            epilog=f"example:\n{example}" if example else None,
            formatter_class=HelpFormatter,
        )
        _add_log_options(p, argparse.SUPPRESS)
        if name == wanted:
            importlib.import_module(COMMANDS[name]).add_arguments(p)
    return parser


class _Unread:
    """A text stream that goes on working after its reader went away: the first write or
    flush that meets a closed pipe points the descriptor at /dev/null and carries on."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return int(self._stream.write(text))
        except BrokenPipeError:
            self._drop()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._drop()

    def _drop(self) -> None:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, self._stream.fileno())
        finally:
            os.close(devnull)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    logging.basicConfig(
        level=level,
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
        stream=sys.stderr,
    )


def _command_in(argv: Sequence[str]) -> str | None:
    """The command named on a command line (the first word that is one), if any."""
    return next((a for a in argv if a in COMMANDS), None)


def main(argv: Sequence[str] | None = None) -> int:
    """The ``groundstation`` command: its exit status.

    Run as a program (``argv`` None) after a Zenoh session was opened, the process ends here,
    its output flushed, without the interpreter's finalization: zenoh-python's native threads
    may still drop a Python object then, and on CPython before 3.14 a thread that takes the
    GIL during finalization is ended by a forced unwind that Rust cannot pass through: the
    process aborted with "FATAL: exception not rethrown" after a clean run (seen once in a
    test of two demos). Every file is closed and every session ended by then.

    Ctrl-C while the command is still starting (its modules loading, which takes seconds on a
    loaded machine) is an interruption like any other: one line and exit 130.
    """
    try:
        status = _main(argv)
    except KeyboardInterrupt:
        name = _command_in(sys.argv[1:] if argv is None else argv)
        print(f"groundstation {name}: interrupted" if name else "groundstation: interrupted",
              file=sys.stderr)
        status = EXIT_INTERRUPTED
    if argv is None and "zenoh" in sys.modules:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):  # a reader gone, a stream closed
                stream.flush()
        logging.shutdown()
        os._exit(status)
    return status


def _unrecognized(parser: argparse.ArgumentParser, args: argparse.Namespace,
                  extra: list[str]) -> NoReturn:
    """The one-line error for arguments nobody takes, from the command's own parser (its
    name in front) with the options a mistyped one is closest to (``--base-xzy``: did you mean
    --base-xyz?)."""
    import difflib

    command = parser
    for action in parser._actions:  # the subcommand's parser, when one was named
        if isinstance(action, argparse._SubParsersAction) and args.command in action.choices:
            command = action.choices[args.command]
    known = [o for a in command._actions for o in a.option_strings if o.startswith("--")]
    close = [m for x in extra if x.startswith("--")
             for m in difflib.get_close_matches(x.split("=", 1)[0], known, n=1, cutoff=0.75)]
    said = f"unrecognized arguments: {' '.join(extra)}"
    if close:
        said += f"; did you mean {', '.join(dict.fromkeys(close))}?"
    command.error(said)


def _main(argv: Sequence[str] | None) -> int:
    # numpy's OpenBLAS starts one thread per core when numpy is first imported (~50 ms of a
    # command's start-up here); the project's array work is element-wise, so one thread is
    # enough (set before any command imports numpy; a user's setting wins)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    args_list = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(args_list)
    args, extra = parser.parse_known_args(args_list)
    if extra:
        _unrecognized(parser, args, extra)
    if not args.command:
        parser.print_help()
        return EXIT_CONFIG
    if args.command in FINISH_UNREAD and argv is None:
        sys.stdout = _Unread(sys.stdout)
        sys.stderr = _Unread(sys.stderr)
    setup_logging(args.verbose, args.quiet)
    module = importlib.import_module(COMMANDS[args.command])
    try:
        return int(module.run(args))
    except BrokenPipeError:  # output piped into head & co.
        sys.stderr.close()
        return EXIT_OK
    except KeyboardInterrupt:
        print(f"groundstation {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as err:
        status, line = failure(err)
        if status == EXIT_FAILURE and line.startswith("internal error"):
            logging.getLogger("groundstation").debug("unexpected failure", exc_info=True)
        print(f"groundstation {args.command}: {' '.join(line.splitlines())}", file=sys.stderr)
        return status


def _leaf(err: BaseException) -> BaseException:
    """The first exception inside (nested) exception groups (a task group's failure)."""
    while isinstance(err, BaseExceptionGroup) and err.exceptions:
        err = err.exceptions[0]
    return err


def failure(err: BaseException) -> tuple[int, str]:
    """The exit status and the one line that report ``err`` (the module docstring's rules)."""
    err = _leaf(err)
    if isinstance(err, ConfigError):
        return EXIT_CONFIG, str(err)
    if isinstance(err, InputError):
        return EXIT_CONFIG, f"error: {err}"
    if isinstance(err, GroundstationError):
        return EXIT_FAILURE, f"error: {err}"
    if isinstance(err, OSError):  # a file or device the command could not use
        where = f": {err.filename}" if err.filename else ""
        return EXIT_FAILURE, f"error: {err.strerror or err}{where}"
    if isinstance(err, MemoryError):
        return EXIT_FAILURE, "error: out of memory"
    text = " ".join(str(err).split())  # one line
    return EXIT_FAILURE, (f"internal error: {type(err).__name__}: {text} "
                          "(run with -vv for the traceback)")

if __name__ == "__main__":
    sys.exit(main())
