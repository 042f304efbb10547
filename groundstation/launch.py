"""The ``groundstation`` program's entry point: a Ctrl-C while the command line's own modules
load (before :func:`groundstation.cli.main` can catch it; a fraction of a second, seconds on a
loaded machine) is one line and exit 130 like any later one, never a traceback."""

from __future__ import annotations

import sys

EXIT_INTERRUPTED = 130
"""Ctrl-C or SIGTERM ended a command that ends by itself (``demo``, ``replay``, the offline
commands). For the commands that run until stopped (``run``, ``watch``, ``dashboard``,
``solver``, ``router``, ``rtk``) Ctrl-C is the normal end: status 0."""


def main() -> int:
    """Load the command line and run it: its exit status."""
    try:
        from groundstation import cli
    except KeyboardInterrupt:
        sys.stderr.write("groundstation: interrupted\n")
        return EXIT_INTERRUPTED
    return cli.main()
