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
    "rtk": "groundstation.commands.rtk",
    "dashboard": "groundstation.commands.dashboard",
    "demo": "groundstation.commands.demo",
    "replay": "groundstation.commands.replay",
    "solve": "groundstation.commands.solve",
    "locate-base": "groundstation.commands.locate_base",
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
    "rtk": "live carrier-phase positions of a rover against a base, from Zenoh",
    "dashboard": "local web dashboard of the stations on Zenoh",
    "demo": "simulator + daemon + live view, the embedded default",
    "replay": "MCAP/.ubx through the live pipeline (to Zenoh), at xN or max speed",
    "solve": "post-flight: positions -> marks -> photos -> lever arm -> outputs",
    "locate-base": "the base's position from a reference station's RINEX (static baseline)",
    "solver": "the solver service (listens on Zenoh, solves when a session ends)",
    "router": "a Zenoh router: TLS, mutual TLS, access control per station (from TOML)",
}

EXAMPLES: dict[str, str] = {
    "inspect": "groundstation inspect flights/rover_20250101T120000Z.mcap\n"
               "groundstation inspect --json rover.ubx.gz",
    "run": "groundstation run --port /dev/wi232 --station rover\n"
           "groundstation run --tcp 127.0.0.1:5000 --station rover --out-dir flights\n"
           "groundstation run --file rover.ubx --no-zenoh",
    "simulate": "groundstation simulate --out sim.ubx --duration 300 --truth truth.json\n"
                "groundstation simulate --pty --speed 1\n"
                "groundstation simulate --from-recording rover.ubx.gz --faults seed --seed 3 "
                "--out rover_lea6t.ubx --truth link.json",
    "rinex": "groundstation rinex flights/rover_20250101T120000Z.mcap --out-dir rinex/",
    "configure": "groundstation configure --port /dev/wi232 --profile lea6t-5hz --dry-run",
    "watch": "groundstation watch --station rover\n"
             "groundstation watch --station rover --connect tcp/192.168.1.10:7447",
    "rtk": "groundstation rtk --rover rover --base base --base-xyz 4146349.25,612312.55,"
           "4791750.85",
    "dashboard": "groundstation dashboard --station rover   # then open http://127.0.0.1:8080",
    "demo": "groundstation demo\n"
            "groundstation demo --flight 300 --speed max --photos photos/ --no-view",
    "replay": "groundstation replay flights/rover_20250101T120000Z.mcap --speed 4",
    "solve": "groundstation solve flight.mcap --base base.ubx "
             "--base-xyz 4201000.1,180000.2,4779000.3 --photos photos/ --out-dir solution/\n"
             "groundstation solve flight.mcap --positions flight.pos --out-dir solution/",
    "locate-base": "groundstation locate-base base.ubx --reference "
                   "ABCD00IRL_R_20250010000_01D_30S_MO.crx.gz --reference-xyz "
                   "3774696.55,-596647.91,5089485.65 --out base.json\n"
                   "groundstation solve flight.mcap --base base.ubx --base-position base.json "
                   "--out-dir solution/",
    "solver": "groundstation solver --config config/solver.toml",
    "router": "groundstation router --config config/router.toml\n"
              "groundstation router --listen tcp/0.0.0.0:7447 --duration 3600",
}
"""Subcommand name -> usage examples shown at the end of its ``--help``."""
