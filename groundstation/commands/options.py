"""Command-line options shared by the commands that read a configuration or join Zenoh.

The options only collect what the user typed; :func:`groundstation.config.resolve` merges it
over the file and the environment, so a value typed here is validated like one from a file.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from groundstation.config import CLIENT_ZENOH, DEFAULT_ENDPOINT, Scope
from groundstation.errors import ConfigError


def add_config(parser: argparse.ArgumentParser, scope: Scope, example: str) -> None:
    """``--config FILE`` for ``scope``."""
    parser.add_argument(
        "--config", type=Path, metavar="FILE",
        help=f"TOML configuration (see {example}); default ${scope.config_variable} if set. "
        f"Precedence: defaults < file < {scope.env_prefix}* environment < options",
    )


def add_zenoh_client(parser: argparse.ArgumentParser, mode: str = CLIENT_ZENOH.mode) -> None:
    """The Zenoh options of a client (a view, the solver): connect to the daemon, listen nowhere.

    The names are the daemon's (``--zenoh-connect`` ...); the short ones stay as aliases.
    """
    parser.add_argument(
        "--zenoh-connect", "--connect", dest="zenoh_connect", action="append",
        metavar="ENDPOINT",
        help=f"Zenoh endpoint of the daemon (default {', '.join(CLIENT_ZENOH.connect)}; "
        "repeatable)",
    )
    parser.add_argument("--zenoh-listen", "--listen", dest="zenoh_listen", action="append",
                        metavar="ENDPOINT",
                        help="Zenoh endpoint to listen on (default: none; repeatable)")
    parser.add_argument("--zenoh-mode", "--mode", dest="zenoh_mode", choices=("peer", "client"),
                        help=f"Zenoh mode (default {mode})")


def add_zenoh_daemon(parser: argparse.ArgumentParser) -> None:
    """The Zenoh options of a publishing daemon (``run``, ``replay``)."""
    parser.add_argument("--no-zenoh", action="store_true", help="do not publish on Zenoh")
    parser.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                        help=f"Zenoh listen endpoint (default {DEFAULT_ENDPOINT}; repeatable)")
    parser.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                        help="Zenoh endpoint to connect to (a router or the solver; repeatable)")
    parser.add_argument("--zenoh-mode", choices=("peer", "client", "router"),
                        help="Zenoh mode (default peer)")


def zenoh_layer(args: argparse.Namespace) -> dict[str, Any]:
    """The ``[zenoh]`` table of the command-line layer (only what was given)."""
    zen: dict[str, Any] = {}
    if getattr(args, "no_zenoh", False):
        zen["enabled"] = False
    for k in ("listen", "connect"):
        if getattr(args, f"zenoh_{k}", None):
            zen[k] = list(getattr(args, f"zenoh_{k}"))
    if getattr(args, "zenoh_mode", None):
        zen["mode"] = args.zenoh_mode
    return zen


def layer(args: argparse.Namespace, keys: dict[str, str]) -> dict[str, Any]:
    """The command-line layer: option attribute -> top-level key, plus ``[zenoh]``."""
    out: dict[str, Any] = {k: getattr(args, opt) for opt, k in keys.items()
                           if getattr(args, opt, None) is not None}
    zen = zenoh_layer(args)
    if zen:
        out["zenoh"] = zen
    return out


# -- the base station's position, in every form a surveyor has it ----------------------------

def add_base_position(parser: argparse.ArgumentParser, *, without: str,
                      antenna_default: str = "") -> None:
    """``--base-xyz``, ``--base-llh``, ``--base-en`` with ``--base-crs``, ``--base-position``,
    ``--base-antenna-height``, ``--base-antenna`` and ``--antex``: the base antenna's position
    as ``solve`` and ``rtk`` both take it (:func:`base_from`). ``without`` says what happens
    when none is given; ``antenna_default`` where the antenna type comes from otherwise."""
    parser.add_argument("--base-xyz", metavar="X,Y,Z",
                        help="known base position, ECEF metres (not lat,lon,h; a value starting "
                        f"with '-' is written --base-xyz=-3976219.2,...); {without}")
    parser.add_argument("--base-llh", metavar="LAT,LON,H",
                        help="known base position instead: WGS84 latitude, longitude (degrees) "
                        "and ellipsoidal height (m)")
    parser.add_argument("--base-en", metavar="E,N,H",
                        help="known base position instead: easting, northing and height (m) in "
                        "the projected CRS of --base-crs")
    parser.add_argument("--base-crs", metavar="CODE",
                        help="EPSG code of --base-en: projected (height ellipsoidal), or "
                        "projected+vertical for a height above the geoid, e.g. 32629+5773 "
                        "(UTM 29N + EGM96) or 2157+5731 (Irish ITM + Malin Head), if PROJ has "
                        "the geoid grid")
    parser.add_argument("--base-position", metavar="FILE",
                        help="the base position (and its sigma) from groundstation locate-base "
                        "--out (JSON: ecef_m [x, y, z], optional sigma_enu_m [e, n, u], metres), "
                        "or an NRCan CSRS-PPP summary (.sum: its ITRF/IGS position)")
    parser.add_argument("--base-antenna", metavar="TYPE",
                        help="the base antenna's type as ANTEX spells it, radome after a space "
                        f"(e.g. 'TRM55971.00 NONE'{antenna_default}): with --antex "
                        "its L1 phase-centre offset is added to the base position")
    parser.add_argument("--antex", metavar="FILE",
                        help="ANTEX file with the base antenna's calibration (igs20.atx, .gz "
                        "too); without it the base position is taken as the antenna's phase "
                        "centre")
    parser.add_argument("--base-antenna-height", metavar="M",
                        help="the base position given is the ground mark; the antenna reference "
                        "point is M metres vertically above it")


Xyz = tuple[float, float, float]

BASE_OPTION_KEYS = {"base_xyz": "base_xyz", "base_llh": "base_llh", "base_en": "base_en",
                    "base_crs": "base_crs", "base_antenna_height": "base_antenna_height_m",
                    "base_antenna": "base_antenna", "antex": "antex"}
""":func:`add_base_position`'s options (attribute -> the configuration key that checks it)."""


def base_options(args: argparse.Namespace) -> dict[str, Any]:
    """The base position's options that were typed, converted and checked by their
    configuration keys (the solver's rules), an error naming the option."""
    from groundstation.config import SOLVER_STATION_KEYS, convert

    out: dict[str, Any] = {}
    for attr, key in BASE_OPTION_KEYS.items():
        text = getattr(args, attr, None)
        if text is not None:
            option = "--" + attr.replace("_", "-")
            out[key] = convert(SOLVER_STATION_KEYS[key], option, text, from_text=True)
    return out


def base_from(values: dict[str, Any], position_file: str | None,
              ) -> tuple[Xyz | None, str, Xyz | None]:
    """The base antenna's position from whichever form was given (``values``: the checked
    configuration keys ``base_xyz``, ``base_llh``, ``base_en``, ``base_crs``,
    ``base_antenna_height_m``, ``base_antenna``, ``antex``; ``position_file``:
    ``--base-position``): ECEF metres or None, how it was given, and the file's sigma
    (east, north, up) if it has one.

    Raises:
        ConfigError: naming the option: two forms at once, a file that is not there, or what
            :func:`groundstation.solve.base.base_position` refuses.
    """
    from groundstation.solve.base import base_position
    from groundstation.solve.locate import read_base_position

    xyz, given = base_position(
        values.get("base_xyz"), values.get("base_llh"), values.get("base_antenna_height_m"),
        en=values.get("base_en"), crs=values.get("base_crs"),
        antenna=values.get("base_antenna"), antex_file=values.get("antex"))
    if position_file is None:
        return xyz, given, None
    if xyz is not None or values.get("base_antenna_height_m") is not None or values.get("antex"):
        raise ConfigError("--base-position", "give the base as one of --base-position, "
                          "--base-xyz, --base-llh or --base-en (the file is the antenna's "
                          "position)")
    if not Path(position_file).is_file():
        raise ConfigError("--base-position", f"{position_file}: no such file")
    xyz, sd, given = read_base_position(Path(position_file))
    return xyz, given, sd
