"""Command-line options shared by the commands that read a configuration or join Zenoh.

The options only collect what the user typed; :func:`groundstation.config.resolve` merges it
over the file and the environment, so a value typed here is validated like one from a file.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from groundstation.config import CLIENT_ZENOH, DEFAULT_ENDPOINT, Scope


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
