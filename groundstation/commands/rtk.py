"""``groundstation rtk``: carrier-phase positions of a rover during the flight, from its and a
base station's measurements on the bus (``.../obs``), published on ``.../rtk``."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from groundstation.commands.options import add_base_position, add_config, add_zenoh_client, layer
from groundstation.config import RTK, resolve, zenoh_settings
from groundstation.errors import ConfigError

NAME = "rtk"
HELP = "live carrier-phase positions of a rover against a base, from Zenoh"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config(parser, RTK, "rover, base, base_xyz or another form of the base position, "
               "and [zenoh]")
    parser.add_argument("--rover", help="the rover's station name")
    parser.add_argument("--base", help="the base's station name")
    add_base_position(parser, without="one of the base position's forms is needed (as "
                      "solve takes them)")
    add_zenoh_client(parser)
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default, or 0: until Ctrl-C or SIGTERM, "
                        "the normal end, status 0; the first fix takes a minute or more from a "
                        "cold start: ephemerides 20-40 s, then the ambiguities)")


def run(args: argparse.Namespace) -> int:
    from groundstation.commands.options import base_from, base_options
    from groundstation.live.rtk import run_rtk

    options = {"rover": "rover", "base": "base", "duration": "duration_s"}
    try:
        values = resolve(RTK, args.config, overrides=layer(args, options)
                         | base_options(args)).values
    except ConfigError as err:  # typed on the command line: name the option, not the key
        typed = {key: "--" + opt for opt, key in options.items()}
        if err.key in typed and err.message.endswith("(command line)"):
            raise ConfigError(typed[err.key], err.message.removesuffix(" (command line)")) from err
        raise
    top = values[""]
    for name in ("rover", "base"):
        if not top.get(name):
            raise ConfigError(f"--{name}", f"give the {name}'s station name (--{name} NAME)")
    if top["rover"] == top["base"]:
        raise ConfigError("--base", f"the base must be another station than the rover "
                          f"({top['rover']!r})")
    xyz, given, _ = base_from(top, args.base_position)
    if xyz is None:
        raise ConfigError("--base-xyz", "give the base's position (--base-xyz X,Y,Z, --base-llh "
                          "LAT,LON,H, --base-en E,N,H with --base-crs, or --base-position FILE)")
    print(f"rtk: base ECEF {xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f} m, {given}", flush=True)
    stop = threading.Event()  # Ctrl-C and SIGTERM are the normal end: the summary follows
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    done = run_rtk(top["rover"], top["base"], xyz, zenoh_settings(values["zenoh"]),
                   duration_s=float(top.get("duration_s", 0.0)), stop=stop.is_set,
                   base_how=given)
    counts = ", ".join(f"{k} {v}" for k, v in sorted((done.by_quality or {}).items()))
    print(f"rtk: {done.rover_epochs} rover epochs, {done.base_epochs} base epochs, "
          f"{done.subframes} subframes, {done.bad_messages} unreadable messages"
          + (f"; positions: {counts}" if counts else ""))
    missing = [f"{what} {name!r}" for what, name, n in (
        ("rover", top["rover"], done.rover_epochs), ("base", top["base"], done.base_epochs))
        if n == 0]
    if missing:  # a run that gave no result (exit 1), and why it may be
        print(f"groundstation rtk: nothing received from the {' and the '.join(missing)} on "
              f"groundstation/<station>/obs: is the daemon running under that station name, "
              "with [zenoh] publish_obs on, and reachable at the --connect endpoint?",
              file=sys.stderr)
        return 1
    return 0
