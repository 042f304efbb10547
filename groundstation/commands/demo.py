"""``groundstation demo``: a simulated flight through a pty into the daemon, with a live view."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

from groundstation.commands.options import add_config, add_zenoh_daemon, layer
from groundstation.commands.simulate import add_profile_arguments, parse_speed
from groundstation.config import DAEMON, DEFAULT_ENDPOINT
from groundstation.errors import ConfigError
from groundstation.invocation import command
from groundstation.outpaths import check_output_dir, check_output_file, make_output_dir
from groundstation.view.summary import status_lines

NAME = "demo"
HELP = "simulator + daemon + live view, the embedded default"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--flight", type=float, default=None, metavar="S",
                        help="length of the simulated flight, static ends included (default 300; "
                        "seed profile 3000)")
    parser.add_argument("--speed", default="1", help="1 (real time, default), N or max")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="stop sending S seconds of wall time after the first byte, read what "
                        "was sent, then stop (default: end of the flight)")
    parser.add_argument("--seed", type=int, default=1, help="simulation seed")
    parser.add_argument("--faults", default=None, metavar="none|default|seed|FILE",
                        help="link and mark faults to inject (default: default; seed profile: "
                        "seed)")
    add_profile_arguments(parser)
    add_config(parser, DAEMON, "config/groundstation.toml; the source is the simulator's pty")
    parser.add_argument("--out-dir", type=Path, metavar="DIR",
                        help="directory for the recording, the base stream and the truth "
                        "(default flights)")
    parser.add_argument("--photos", type=Path, metavar="DIR",
                        help="also write the camera's photos (JPEG with EXIF) for every "
                        f"exposure, to try `solve --photos`; {camera_clock_text()}")
    parser.add_argument("--force", action="store_true",
                        help="replace photos of the same names in --photos (never a recording)")
    parser.add_argument("--station", help="station name (default demo)")
    add_zenoh_daemon(parser)
    parser.add_argument("--serve-after", type=float, metavar="S",
                        help="after the flight, keep serving the recording to remote solvers "
                        "for up to S seconds (until fetched; [zenoh] serve_after_s, default 0)")
    parser.add_argument("--no-view", action="store_true", help="no live view, just the summary")
    parser.add_argument("--no-base", action="store_true",
                        help="no live carrier-phase positions against the simulated base")


def run(args: argparse.Namespace) -> int:
    from groundstation.live.demo import DemoOptions, demo_settings, run_demo, simulate_flight

    cli = layer(args, {"station": "station"})
    if args.out_dir is not None:
        cli["recorder"] = {"out_dir": args.out_dir}
    if args.serve_after is not None:
        cli.setdefault("zenoh", {})["serve_after_s"] = args.serve_after
    settings = demo_settings(args.config, overrides=cli)
    if args.flight is None:
        args.flight = 3000.0 if args.profile == "seed" else 300.0
    if args.flight < 60:
        raise ConfigError("flight", "must be at least 60 s (static, take-off, lines, landing)")
    if args.duration < 0:
        raise ConfigError("duration", "must be >= 0")
    opts = DemoOptions(
        flight_s=args.flight, speed=parse_speed(args.speed, live=True), seed=args.seed,
        faults=args.faults or ("seed" if args.profile == "seed" else "default"),
        profile=args.profile, severity=args.severity, duration_s=args.duration,
        settings=settings, live_rtk=not args.no_base,
    )
    sim = simulate_flight(opts)
    # Every output is checked (and its directory made) before the flight: a refusal after it
    # would leave a recording behind for a command that failed.
    out_key = "--out-dir" if args.out_dir is not None else "recorder.out_dir"
    check_output_dir(settings.recorder.out_dir, key=out_key)
    if args.photos is not None:
        check_photos(args.photos, _photo_names(sim), force=args.force)
    made = make_output_dir(settings.recorder.out_dir, out_key)
    if args.photos is not None:
        try:
            make_output_dir(args.photos, "--photos")
        except ConfigError:
            if made:
                settings.recorder.out_dir.rmdir()
            raise
    speed = "as fast as possible" if opts.speed is None else f"x{opts.speed:g}"

    def ready(info: dict[str, Any]) -> None:
        print(f"demo: simulated {opts.flight_s:g} s flight ({speed}) on pty {info['pty']}",
              file=sys.stderr, flush=True)
        if info["zenoh"]:
            endpoints = info["zenoh"]
            connect = "" if endpoints == [DEFAULT_ENDPOINT] else f" --connect {endpoints[0]}"
            watch = command("watch", "--station", info["station"],
                            *(("--connect", endpoints[0]) if connect else ()))
            print(f"demo: publishing on Zenoh {', '.join(endpoints)} (watch it from another "
                  f"terminal: {watch})",
                  file=sys.stderr, flush=True)
            if info.get("base_station"):
                xyz = ",".join(f"{v:.4f}" for v in sim.truth["base"]["ecef_m"])
                rtk = command("rtk", "--rover", info["station"], "--base", info["base_station"],
                              "--base-xyz", xyz, *(("--connect", endpoints[0]) if connect else ()))
                print(f"demo: base station {info['base_station']} on pty {info['base_pty']}; "
                      f"carrier-phase positions from the bus, from another terminal:\n  {rtk}",
                      file=sys.stderr, flush=True)
        print("demo: Ctrl-C stops it early (files closed cleanly; exit status 130)",
              file=sys.stderr, flush=True)

    interactive = sys.stdout.isatty() and not args.no_view
    if interactive:
        result = _run_with_view(opts, sim, ready)
    else:
        result = asyncio.run(run_demo(opts, sim=sim, on_payload=lambda k, p: None, ready=ready))
    photos = _write_photos(result, args.photos) if args.photos is not None else None
    _print_summary(result, photos)
    from groundstation.cli import EXIT_INTERRUPTED, INTERRUPTS

    return EXIT_INTERRUPTED if result.summary.stopped_by in INTERRUPTS else 0


CAMERA_CLOCK_ERROR_S = -(1 * 3600 + 51 * 60 + 2.6)
"""The simulated camera's clock error against the local time it is set to."""
CAMERA_ZONE_S = 7200
"""The simulated camera runs local time, UTC+02:00, and writes no zone tag (many do not)."""


def _duration_text(seconds: float) -> str:
    s = round(abs(seconds))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return (f"{h} h {m:02d} min {sec:02d} s" if h else f"{m} min {sec:02d} s")


def camera_clock_text() -> str:
    """What the simulated camera's EXIF times are, from the constants the photos are made with."""
    ahead = CAMERA_ZONE_S + CAMERA_CLOCK_ERROR_S
    return (f"the camera's clock runs local time UTC{CAMERA_ZONE_S / 3600:+03.0f}:00 with no zone "
            f"tag, {_duration_text(CAMERA_CLOCK_ERROR_S)} "
            f"{'slow' if CAMERA_CLOCK_ERROR_S < 0 else 'fast'}, so its EXIF times read "
            f"{_duration_text(ahead)} {'ahead of' if ahead >= 0 else 'behind'} UTC; solve "
            "finds that offset itself")


def _photo_names(sim: Any) -> list[str]:
    """The names of the photos of every exposure of the flight (a cut run writes the first)."""
    from groundstation.solve.photosim import photos_at_times

    times = [e["falling_t_gps_ns"] for e in sim.truth["exposures"]]
    return [p.name for p in photos_at_times(times, clock_error_s=CAMERA_CLOCK_ERROR_S,
                                            zone_s=CAMERA_ZONE_S)]


def check_photos(directory: Path, names: list[str], *, force: bool) -> None:
    """Refuse a ``--photos`` directory that is a file, or where a photo the demo writes exists
    (the camera's own ``IMG_NNNN.JPG``): outpaths' rule for each file, one line for all.

    Raises:
        ConfigError: naming ``--photos``.
    """
    check_output_dir(directory, key="--photos")
    refused: list[tuple[str, ConfigError]] = []
    for name in names if directory.is_dir() else ():  # a new directory: make_output_dir's
        try:
            check_output_file(directory / name, key="--photos", force=force)
        except ConfigError as err:
            refused.append((name, err))
    if refused:
        also = [name for name, _ in refused[1:4]]
        if len(refused) > 4:
            also.append(f"{len(refused) - 4} more")
        more = f" (also {', '.join(also)})" if also else ""
        raise ConfigError("--photos", f"{refused[0][1].message}{more}; name an empty or new "
                          "directory" + ("" if force else " or pass --force"))


def _write_photos(result: Any, directory: Path) -> Path:
    """The simulated camera's JPEGs, one per exposure of the truth (solve/photosim.py)."""
    from groundstation.solve.photosim import photos_at_times, write_photo_set

    # The exposures up to the stop: a cut run's camera stopped with it.
    times = [e["falling_t_gps_ns"] for e in result.sent().exposures]
    write_photo_set(photos_at_times(times, clock_error_s=CAMERA_CLOCK_ERROR_S,
                                    zone_s=CAMERA_ZONE_S), directory)
    return directory


def _run_with_view(opts: Any, sim: Any, ready: Any) -> Any:
    from rich.console import Console
    from rich.live import Live

    from groundstation.live.demo import run_demo
    from groundstation.view.watch import WatchState, render

    state = WatchState(opts.settings.station if opts.settings else opts.station)
    console = Console()
    _log_through(console)

    async def main() -> Any:
        with Live(render(state), console=console, auto_refresh=False, transient=False) as live:

            async def refresh() -> None:
                while True:
                    live.update(render(state), refresh=True)
                    await asyncio.sleep(0.25)

            task = asyncio.create_task(refresh(), name="view")
            try:
                return await run_demo(opts, sim=sim, on_payload=state.on_payload, ready=ready)
            finally:
                task.cancel()
                live.update(render(state), refresh=True)

    return asyncio.run(main())


def _log_through(console: Any) -> None:
    """Log lines above the live view instead of through it."""
    import logging

    from rich.logging import RichHandler

    root = logging.getLogger()
    level = root.level
    for h in list(root.handlers):
        root.removeHandler(h)
    root.addHandler(RichHandler(console=console, show_path=False, level=level))


def live_text(live: Any) -> str:
    """The live engine's epochs by quality, and its fixed share over the last minute."""
    from collections import Counter

    n = Counter(s.quality for s in live)
    last = live[-300:]
    return (f"{len(live)} rover epochs solved during the flight: "
            + ", ".join(f"{k} {n[k]}" for k in ("fix", "float", "dgps", "single") if n[k])
            + (f", none {n['none']} (no position yet: waiting for the ephemerides, or the "
               "base)" if n["none"] else "")
            + f"; fixed {sum(s.quality == 'fix' for s in last) / len(last):.0%} of the last "
            f"{len(last) / 5:.0f} s")


def _print_summary(result: Any, photos: Path | None = None) -> None:
    from groundstation.live.demo import base_station_name

    s = result.summary
    truth = result.sim.truth
    sent = result.sent()
    st = result.last_status
    print(f"demo finished: {s.stopped_by} after {s.duration_s:.1f} s")
    if not sent.whole_flight:
        planned = (int(truth["end_gps_ns"]) - int(truth["start_gps_ns"])) / 1e9
        print(f"  cut short: {sent.flight_s:.1f} s of the {planned:g} s flight sent; the "
              "simulator's figures below are those up to the stop")
    lost = result.bytes_written - s.bytes_in
    print(f"  received {s.bytes_in:,} of the {result.bytes_written:,} bytes written into the pty"
          f"{'' if lost == 0 else f' ({lost:,} not read before the end)'}: {s.frames:,} frames, "
          f"{s.garbage_bytes:,} garbage bytes, {s.records:,} records")
    if st is not None:
        at = "at the end of the flight" if sent.whole_flight else "when it stopped"
        for line in status_lines(st, injected_lost_epochs=sent.lost_epochs,
                                 exposures=len(sent.exposures), at=at,
                                 cleared=result.alerts_cleared):
            print(line)
    for path in s.files:
        print(f"  MCAP:        {path}")
    for path in s.sidecars:
        print(f"  raw UBX:     {path}")
    print(f"  base UBX:    {result.base_path}")
    bs = result.base_station
    if bs is not None and bs.files:
        print(f"  base station {base_station_name(result.station)} (its own daemon): "
              f"{bs.files[0]}, "
              f"{bs.records:,} records")
    if result.live:
        print(f"  live RTK:    {live_text(result.live)} (groundstation/{result.station}/rtk)")
    elif result.live_missing:
        print(f"  live RTK:    not run: {result.live_missing}")
    else:
        print("  live RTK:    off (--no-base)")
    print(f"  truth:       {result.truth_path}")
    if photos is not None:
        print(f"  photos:      {photos} ({len(sent.exposures)} JPEGs)")
    if result.endpoint:
        print(f"  Zenoh:       groundstation/{result.station}/** on {result.endpoint}")
    if s.files and not s.frames_by_type.get("TIM-TM2"):  # no "next: ... solve" that fails
        print(f"the flight was cut short ({s.stopped_by} after {s.duration_s:.1f} s) before "
              "its first time mark: nothing to solve; let the demo run to its end")
    elif s.files:
        print(f"next: {command('inspect', str(s.files[0]))}")
        xyz = ",".join(f"{v:.4f}" for v in truth["base"]["ecef_m"])
        photo_opt = ("--photos", str(photos)) if photos is not None else ()
        print("next: " + command(
            "solve", str(s.files[0]), "--base", str(result.base_path), "--base-xyz", xyz,
            *photo_opt, "--out-dir", f"{Path(s.files[0]).with_suffix('')}_solution"))
