"""The subcommands of the ``groundstation`` command line, one module each.

Each module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``; it is
registered here by name, and :mod:`groundstation.cli` builds the parser from this list. Modules
are imported lazily so that ``groundstation inspect`` does not pay for Zenoh or the simulator.
"""

from __future__ import annotations

COMMANDS: dict[str, str] = {
    "inspect": "groundstation.commands.inspect",
    "run": "groundstation.commands.run",
    "simulate": "groundstation.commands.simulate",
    "rinex": "groundstation.commands.rinex",
    "configure": "groundstation.commands.configure",
    "watch": "groundstation.commands.watch",
    "dashboard": "groundstation.commands.dashboard",
    "demo": "groundstation.commands.demo",
    "replay": "groundstation.commands.replay",
    "solve": "groundstation.commands.solve",
    "solver": "groundstation.commands.solver",
    "router": "groundstation.commands.router",
}
"""Subcommand name -> module implementing it."""

HELP: dict[str, str] = {
    "inspect": "summary of a recording: span, epochs, gaps, marks, satellites",
    "run": "the live daemon: receive, decode and record a station's stream",
    "simulate": "realistic u-blox stream to a pty, TCP port or file, with faults",
    "rinex": "MCAP/.ubx -> RINEX 2.11/3.04 obs + nav + time-mark table",
    "configure": "send receiver configuration (CFG-*) and check ACKs",
    "watch": "live terminal view of a station over Zenoh",
    "dashboard": "local web dashboard of the stations on Zenoh",
    "demo": "simulator + daemon + live view, the embedded default",
    "replay": "MCAP/.ubx through the live pipeline (to Zenoh), at xN or max speed",
    "solve": "post-flight: positions -> marks -> photos -> lever arm -> outputs",
    "solver": "the solver service (listens on Zenoh, solves when a session ends)",
    "router": "a Zenoh router: TLS, mutual TLS, access control per station (from TOML)",
}
