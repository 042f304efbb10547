"""``groundstation solve``: post-flight positions -> marks -> photos -> lever arm -> outputs."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from groundstation.commands.options import add_base_position, base_from, base_options
from groundstation.config import SOLVER_STATION_KEYS, convert
from groundstation.errors import ConfigError
from groundstation.solve import engine as ppk
from groundstation.solve import interpolate as interp
from groundstation.solve.antex import rinex_antenna
from groundstation.solve.exif import JPEG_SUFFIXES
from groundstation.solve.pipeline import SolveResult, solve
from groundstation.solve.record import rebase_settings
from groundstation.solve.report_data import checks_text, grades_text
from groundstation.solve.report_notes import printed_notes
from groundstation.solve.settings import SolveSettings

NAME = "solve"
HELP = "post-flight: positions -> marks -> photos -> lever arm -> outputs"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("flight", nargs="*",
                        help="rover recording: .mcap, .ubx or .ubx.gz; several recordings of "
                        "the same receiver (the radio's and an on-board log) are merged frame "
                        "by frame")
    parser.add_argument("--out-dir", "--out", dest="out", metavar="DIR",
                        help="output directory (created; an earlier result in it is replaced when "
                        "the run completes, other files are left alone)")
    parser.add_argument("--rebase", metavar="RESULT_DIR",
                        help="move a finished result to new base coordinates (--base-xyz, "
                        "--base-llh, --base-en or --base-position) without solving again: its "
                        "exports and report are rewritten (in RESULT_DIR, or --out-dir); its "
                        "record stands for the recordings (they may have been archived), its "
                        "photos, EO file or geoid grid must still be where they were")
    parser.add_argument("--positions", metavar="FILE",
                        help="RTKLIB solution (.pos, .pos.gz); no base needed")
    parser.add_argument("--base", metavar="FILE",
                        help="base observations (.obs RINEX or .ubx recording)")
    add_base_position(parser, without="without any base position the mean of the base "
                      "receiver's own fixes is used, known to metres (said so)",
                      antenna_default="; default: a RINEX base's header")
    parser.add_argument("--base-sigma", metavar="S|E,N,U",
                        help="the base position's own uncertainty, metres (one value or east,"
                        "north,up): added to the cameras' absolute sigmas")
    parser.add_argument(
        "--source", metavar="{pos,rtklib,receiver}",
        help="position source (default: pos with --positions, rtklib with --base)",
    )
    parser.add_argument(
        "--engine", default=ppk.DEFAULT_ENGINE, metavar="{" + ",".join(ppk.ENGINES) + "}",
        help=f"PPK engine with --base (default {ppk.DEFAULT_ENGINE})",
    )
    parser.add_argument(
        "--rtk-opt", action="append", default=[], metavar="KEY=VALUE",
        help="engine option (RTKLIB key, e.g. pos2-arthres=3); repeatable; checked against "
        "the engine's option table",
    )
    parser.add_argument("--rtk-conf", metavar="FILE",
                        help="RTKLIB options file (.conf) applied over the defaults")
    parser.add_argument("--photos", metavar="DIR", help="directory of the flight's JPEGs")
    parser.add_argument("--lever-arm", metavar="X,Y,Z",
                        help="lever arm in the camera frame, metres (default 0,0,0)")
    parser.add_argument("--eo", metavar="FILE",
                        help="exterior orientations: name, X, Y, Z, omega, phi, kappa")
    parser.add_argument("--epsg", metavar="CODE",
                        help="output CRS (default: the WGS84 UTM zone); a compound code gives "
                        "heights above its geoid: 9707 (WGS84 + EGM96), 32629+5773 (UTM 29N + "
                        "EGM96), if PROJ has the geoid grid")
    parser.add_argument("--geoid", metavar="FILE",
                        help="geoid grid (.gtx or GeoTIFF, as PROJ reads them): heights above it "
                        "instead of ellipsoidal heights, with a horizontal --epsg")
    parser.add_argument("--interp", default=interp.DEFAULT_METHOD,
                        metavar="{linear,spline,smoother}",
                        help="interpolation between epochs (default smoother: between fixed "
                        "epochs it bridges radio gaps with an honest sigma; elsewhere the "
                        "straight line)")
    parser.add_argument("--edge", default="falling", metavar="{falling,rising,mid}",
                        help="which edge of the hot-shoe pulse is the exposure")
    parser.add_argument("--shutter-delay-ms", default="0", metavar="MS",
                        help="added to the mark time")
    parser.add_argument(
        "--max-gap", default=str(interp.DEFAULT_MAX_GAP_S), metavar="S",
        help="flag marks between epochs further apart than this (s)",
    )
    parser.add_argument(
        "--exif", action="store_true", help="write copies of the photos with EXIF GPS tags"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress on stderr")
    parser.add_argument("--no-pdf", action="store_true",
                        help="write report.html only, no report.pdf (printing it takes "
                        "Chromium 1-8 s; a browser prints the HTML as the same page)")


def _option(option: str, key: str, text: str | None) -> Any:
    """An option's text converted and checked by the solver's configuration key (the same
    rules as ``config/solver.toml`` and ``GROUNDSTATION_SOLVER_*``), or None if not given."""
    if text is None:
        return None
    return convert(SOLVER_STATION_KEYS[key], option, text, from_text=True)


def _base_sigma(
    text: str | None, base_xyz: tuple[float, float, float] | None,
) -> tuple[float, float, float] | None:
    """``--base-sigma``: one value for every axis or east,north,up, metres."""
    if text is None:
        return None
    if base_xyz is None:
        raise ConfigError("--base-sigma", "goes with the base's coordinates (--base-xyz or "
                          "--base-llh); without them the base's own fixes give the sigma")
    try:
        values = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        values = []
    if len(values) not in (1, 3) or not all(math.isfinite(v) and v >= 0 for v in values):
        raise ConfigError("--base-sigma", f"expected one value or east,north,up in metres "
                          f"(>= 0), got {text!r}")
    e, n, u = values * 3 if len(values) == 1 else values
    return e, n, u


def settings_from_args(args: argparse.Namespace) -> SolveSettings:
    """Resolve and check the command line (every problem is a ConfigError naming the option)."""
    if args.rebase is not None:
        return _rebase_settings(args)
    if not args.flight:
        raise ConfigError("flight", "give the rover's recording (.mcap, .ubx or .ubx.gz), or "
                          "--rebase RESULT_DIR with new base coordinates")
    if args.out is None:
        raise ConfigError("--out-dir", "give the output directory (--out-dir DIR)")
    if args.positions is None and args.base is None and args.source != "receiver":
        raise ConfigError(
            "--positions", "give --positions FILE.pos or --base BASE --base-xyz X,Y,Z"
        )
    if args.positions is not None and args.base is not None:
        raise ConfigError("--base", "use either --positions or --base, not both")
    interp_name = _option("--interp", "interp", args.interp)
    edge = _option("--edge", "edge", args.edge)
    epsg = _option("--epsg", "epsg", args.epsg)
    max_gap = _option("--max-gap", "max_gap_s", args.max_gap)
    for opt, val in (("--positions", args.positions), ("--base", args.base), ("--eo", args.eo)):
        if val is not None and not Path(val).is_file():
            what = "no such file" if not Path(val).exists() else "not a regular file"
            raise ConfigError(opt, f"{val}: {what}")
    if args.photos is not None and not Path(args.photos).is_dir():
        raise ConfigError("--photos", f"{args.photos}: not a directory")
    if args.photos is not None and not any(
            p.suffix.lower() in JPEG_SUFFIXES for p in Path(args.photos).iterdir()):
        # Asked for by name: a folder without JPEGs would only give "offset +0.00 s" later.
        # (The solver service may be given a folder the photos have not reached yet.)
        raise ConfigError("--photos", f"{args.photos}: no JPEG files (.jpg, .jpeg) in it")
    if args.rtk_conf is not None and not Path(args.rtk_conf).is_file():
        raise ConfigError("--rtk-conf", f"{args.rtk_conf}: no such file")
    rtk_opts = ppk.options.parse_assignments(args.rtk_opt)
    setup = _antenna(args)  # read once (a RINEX base's header may name the antenna)
    base_xyz, base_given, base_sd = _base(args, setup)
    if args.base is not None:  # the engine runs: check its options now, before any work
        ppk.resolve_options(
            ppk.get_engine(args.engine), base_xyz,
            Path(args.rtk_conf) if args.rtk_conf else None, rtk_opts,
        )
    return SolveSettings(
        flight=Path(args.flight[0]),
        flight_copies=tuple(Path(f) for f in args.flight[1:]),
        out_dir=Path(args.out),
        positions=Path(args.positions) if args.positions else None,
        base=Path(args.base) if args.base else None,
        base_ecef_m=base_xyz,
        base_given=base_given,
        base_sd_enu_m=base_sd,
        base_antenna_height_m=setup[0], base_antenna=setup[1], antex=setup[2],
        source=args.source,
        photos=Path(args.photos) if args.photos else None,
        lever_arm_m=_option("--lever-arm", "lever_arm", args.lever_arm),
        eo=Path(args.eo) if args.eo else None,
        epsg=epsg,
        geoid=_option("--geoid", "geoid", args.geoid),
        interp=interp_name,
        edge=edge,
        shutter_delay_ms=_option("--shutter-delay-ms", "shutter_delay_ms", args.shutter_delay_ms),
        max_gap_s=max_gap,
        exif_copies=bool(args.exif),
        engine=args.engine,
        rtk_conf=Path(args.rtk_conf) if args.rtk_conf else None,
        rtk_options=tuple(rtk_opts.items()),
        report_pdf=not args.no_pdf,
    )


Antenna = tuple[float | None, str | None, Path | None]
"""The base antenna's height over the mark, type and ANTEX file (:func:`_antenna`)."""


def _base(args: argparse.Namespace, antenna_setup: Antenna) -> tuple[
        tuple[float, float, float] | None, str, tuple[float, float, float] | None]:
    """The base position from whichever form it was given in, how, and its sigma, the antenna
    standing as ``antenna_setup`` says (:func:`_antenna`)."""
    height, antenna, antex = antenna_setup
    base_xyz, base_given, file_sd = base_from(base_options(args) | {
        "base_antenna_height_m": height, "base_antenna": antenna, "antex": antex,
    }, args.base_position)
    return base_xyz, base_given, _base_sigma(args.base_sigma, base_xyz) or file_sd


def _antenna(args: argparse.Namespace, solved: SolveSettings | None = None) -> Antenna:
    """The base antenna's height over the mark, type and ANTEX file: as given, else (a
    re-base, not with a position file) as the result was solved with."""
    height = _option("--base-antenna-height", "base_antenna_height_m", args.base_antenna_height)
    antex = _option("--antex", "antex", args.antex)
    antenna = args.base_antenna or _rinex_antenna(args)
    if solved is not None and args.base_position is None:
        height = height if height is not None else solved.base_antenna_height_m
        if antex is None and antenna is None:
            antex, antenna = solved.antex, solved.base_antenna
    return height, antenna, antex


def _rinex_antenna(args: argparse.Namespace) -> str | None:
    """With ``--antex`` and a RINEX base: the antenna type its header names."""
    if args.antex is None or args.base is None or not ppk.is_rinex_obs_name(Path(args.base)):
        return None
    return rinex_antenna(Path(args.base))


_SOLVE_ONLY: dict[str, object] = {"flight": [], "positions": None, "base": None, "source": None,
               "engine": ppk.DEFAULT_ENGINE, "rtk_opt": [], "rtk_conf": None, "photos": None,
               "lever_arm": None, "eo": None, "epsg": None, "geoid": None,
               "interp": interp.DEFAULT_METHOD,
               "edge": "falling", "shutter_delay_ms": "0",
               "max_gap": str(interp.DEFAULT_MAX_GAP_S), "exif": False}
"""The options of a solve (and their defaults) that a re-base takes from the result's record."""


def _rebase_settings(args: argparse.Namespace) -> SolveSettings:
    """``--rebase RESULT_DIR`` with new base coordinates: the result's own settings.

    Raises:
        ConfigError: naming the option: a solve's option given too (the result's record has
            them), no new base position, or a result that cannot be re-based.
    """
    for dest, default in _SOLVE_ONLY.items():
        if getattr(args, dest) != default:
            name = "the flight" if dest == "flight" else "--" + dest.replace("_", "-")
            raise ConfigError("--rebase", "takes only the new base position (with its sigma, "
                              "antenna height and type) and --out-dir, --no-pdf; "
                              f"{name} was given: the result keeps the options it was solved "
                              "with (solve again to change them)")
    if all(v is None for v in (args.base_xyz, args.base_llh, args.base_en, args.base_position)):
        raise ConfigError("--rebase", "give the new base position: --base-xyz X,Y,Z, --base-llh "
                          "LAT,LON,H, --base-en E,N,H with --base-crs, or --base-position FILE")

    setup: list[Antenna] = []  # the antenna as it stands for the new coordinates

    def position(solved: SolveSettings) -> tuple[
            tuple[float, float, float], str, tuple[float, float, float] | None]:
        setup.append(_antenna(args, solved))
        xyz, given, sd = _base(args, setup[0])
        assert xyz is not None
        return xyz, given, sd

    result = Path(args.rebase)
    s = rebase_settings(result, Path(args.out) if args.out else result, position)
    height, antenna, antex = setup[0]
    return replace(s, base_antenna_height_m=height, base_antenna=antenna, antex=antex,
                   report_pdf=not args.no_pdf)


class _Progress:
    """One self-overwriting line per stage on stderr."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.stage = ""

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            if stage != self.stage:
                self.stage = stage
                print(f"solve: {stage} ...", file=sys.stderr)
            return
        if stage != self.stage and self.stage:
            sys.stderr.write("\n")
        self.stage = stage
        bar = "#" * int(fraction * 30)
        sys.stderr.write(f"\r{stage:<40} [{bar:<30}] {fraction:4.0%}")
        sys.stderr.flush()

    def done(self) -> None:
        if self.enabled and self.stage:
            sys.stderr.write("\n")


def run(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    progress = _Progress(not args.no_progress)
    try:
        result = solve(settings, progress if not args.no_progress else None)
    finally:
        progress.done()
    # A solve that positions nothing fails inside (pipeline.NothingPositionedError, exit 1)
    # and leaves nothing written.
    if settings.base_ecef_m is not None and settings.base is not None:
        x, y, z = settings.base_ecef_m
        sys.stdout.write(f"base       ECEF {x:.4f}, {y:.4f}, {z:.4f} m, {settings.base_given}\n")
    sys.stdout.write(format_result(result))
    return 0


def format_result(r: SolveResult) -> str:
    s = r.summary()
    checked = r.trajectory.grade is not None
    fixed_word = "fixed and checked" if checked else "fixed"
    lines = [
        (f"positions  {r.trajectory.source}{' + integrity stage' if checked else ''}: "
         f"{s['epochs']} epochs, {float(s['fixed_fraction']):.1%} {fixed_word}"),  # type: ignore[arg-type]
        (f"marks      {s['marks']}: {s['marks_positioned']} positioned, {s['marks_fixed']} "
         f"{fixed_word}, {s['marks_in_gap']} in data gaps"),
        f"grades     {grades_text(r.rows)}",
    ]
    legend = checks_text(r.rows)
    if legend:
        lines.append(f"checks     {legend}")
    if r.match is not None:
        lines.extend(r.reconciliation[:3])
    # the engine's technical notes in plain words (they stay whole in engine.json and the
    # report's notes)
    lines.extend(f"note       {n}" for n in printed_notes(r.trajectory, r.notes))
    lines.extend(f"wrote      {p}" for p in r.files)
    return "\n".join(lines) + "\n"
