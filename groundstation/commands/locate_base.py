"""``groundstation locate-base``: the base's position from a static baseline to a reference
station (a CORS or IGS station's RINEX), for ``solve --base-position``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from groundstation import jsonio
from groundstation.config import SOLVER_STATION_KEYS, convert
from groundstation.errors import ConfigError
from groundstation.outpaths import check_output_file
from groundstation.solve import engine as ppk
from groundstation.solve.locate import locate_base

NAME = "locate-base"
HELP = "the base's position from a reference station's RINEX (static baseline)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("base", help="the base's recording (.ubx, .ubx.gz, .mcap) or RINEX")
    parser.add_argument("--reference", required=True, metavar="RINEX",
                        help="the reference station's observations: RINEX 2/3/4, Hatanaka "
                        "(.crx, .YYd) and .gz/.Z too; navigation files beside it are used")
    parser.add_argument("--reference-xyz", metavar="X,Y,Z",
                        help="the reference station's published position, ECEF metres "
                        "(default: its RINEX header's approximate position, said so); a value "
                        "starting with '-' is written --reference-xyz=-3978241.9,...")
    parser.add_argument("--engine", default=ppk.DEFAULT_ENGINE,
                        metavar="{" + ",".join(ppk.ENGINES) + "}", help="PPK engine")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", metavar="FILE",
                        help="write the position (JSON) for solve --base-position FILE")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")


def run(args: argparse.Namespace) -> int:
    base, reference = Path(args.base), Path(args.reference)
    for opt, p in (("BASE", base), ("--reference", reference)):
        if not p.is_file():
            what = "no such file" if not p.exists() else "not a regular file"
            raise ConfigError(opt, f"{p}: {what}")
    ref_xyz = (convert(SOLVER_STATION_KEYS["base_xyz"], "--reference-xyz", args.reference_xyz,
                       from_text=True) if args.reference_xyz is not None else None)
    ppk.get_engine(args.engine)
    out = Path(args.out) if args.out else None
    if out is not None:
        check_output_file(out, [base, reference], key="--out", force=args.force)
    where = locate_base(base, reference, ref_xyz, engine=args.engine)
    doc = where.as_json()
    if out is not None:
        out.write_bytes(jsonio.dumps(doc, indent=1) + b"\n")
    if args.json:
        sys.stdout.write(jsonio.dumps(doc).decode() + "\n")
    else:
        sys.stdout.write(where.text())
        if out is not None:
            sys.stdout.write(f"wrote          {out} (give it to solve --base-position)\n")
    return 0
