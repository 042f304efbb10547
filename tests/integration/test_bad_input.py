"""Bad input, every command, as a user types it: one clear line, the documented exit status.

Each case runs the real command line in a subprocess (timeout 30 s: a hang fails) in a
workspace of prepared inputs, and checks: the exit status the README documents (2 for bad input
or configuration, 1 for a runtime failure), exactly one line on stderr that says what is wrong
(the expected text), no traceback and no "internal error", nothing created or changed in the
workspace (every file's content hash before and after: no output before validation, inputs
unchanged).
"""

from __future__ import annotations

import gzip
import hashlib
import os
import stat
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from peers import cli_env
from streams import flight_stream

TIMEOUT_S = 30
MCAP_MAGIC = b"\x89MCAP0\r\n"
LONG = "s" * 65
BASE_XYZ = "4146349.2471,612312.5498,4791750.8505"


@dataclass(frozen=True)
class Case:
    """One bad invocation: ``argv`` after ``groundstation``, extra environment, the exit
    status and a piece of the one stderr line."""

    id: str
    argv: tuple[str, ...]
    status: int
    says: str
    env: dict[str, str] = field(default_factory=dict)
    logs: bool = False
    """The command fails only after it started working: its progress and log lines come
    first, the error line is the last one and the only one that says ``groundstation``."""


def c(id_: str, argv: str | tuple[str, ...], status: int, says: str, *, logs: bool = False,
      **env: str) -> Case:
    args = tuple(argv.split()) if isinstance(argv, str) else argv
    return Case(id_, args, status, says, env, logs)


RUN = "run --file good.ubx --no-zenoh --out-dir rec"
BAD_STATION = "is not a station name"
STATIONS = ["$", "#", "?", "*", "**", "..", "../x", "a/b", "a b", "-x", ".hidden", LONG, "a\tb",
            "é"]

CASES: list[Case] = [
    # -- inspect: files ---------------------------------------------------------------------
    c("inspect-fifo", "inspect fifo", 2, "is a FIFO"),
    c("inspect-dev-zero", "inspect /dev/zero", 2, "is a device"),
    c("inspect-dir", "inspect adir", 2, "is a directory"),
    c("inspect-missing", "inspect nope.ubx", 2, "no such file"),
    c("inspect-corrupt-gzip", "inspect corrupt.ubx.gz", 2, "corrupt gzip"),
    c("inspect-corrupt-gzip-named-mcap", "inspect corrupt.mcap", 2, "corrupt gzip"),
    c("inspect-link-to-fifo", "inspect fifo-link.ubx", 2, "is a FIFO"),
    c("inspect-json-fifo", "inspect --json fifo", 2, "is a FIFO"),
    c("inspect-rinex-obs", "inspect rover.obs", 2,
      "no UBX frames in this file (1,008 bytes, a RINEX 3.04 observation file, not a receiver "
      "recording)"),
    c("inspect-rinex-nav-gz", "inspect base.nav.gz", 2, "a RINEX 2.11 navigation file"),
    # -- rinex --------------------------------------------------------------------------------
    c("rinex-fifo", "rinex fifo -o out", 2, "is a FIFO"),
    c("rinex-dev-zero", "rinex /dev/zero -o out", 2, "is a device"),
    c("rinex-dir", "rinex adir -o out", 2, "is a directory"),
    c("rinex-marker-long", "rinex good.ubx -o out --marker " + "M" * 61, 2, "--marker"),
    c("rinex-marker-empty", "rinex good.ubx -o out --marker=", 2, "--marker"),
    c("rinex-missing", "rinex nope.ubx -o out", 2, "no such file"),
    c("rinex-corrupt-gzip", "rinex corrupt.ubx.gz -o out", 2, "corrupt gzip"),
    c("rinex-out-is-a-file", "rinex good.ubx -o good.ubx", 2, "not a directory"),
    c("rinex-out-is-a-recording", "rinex good.ubx -o rec.mcap", 2, "not a directory"),
    c("rinex-out-in-proc", "rinex good.ubx -o /proc/nope", 2, "cannot create"),
    c("rinex-out-under-a-file", "rinex good.ubx -o good.ubx/sub", 2, "--out-dir"),
    c("rinex-shutter-delay-huge", "rinex good.ubx -o out --shutter-delay-ms 1e9", 2,
      "shutter-delay-ms"),
    c("rinex-shutter-delay-nan", "rinex good.ubx -o out --shutter-delay-ms nan", 2,
      "shutter-delay-ms"),
    c("rinex-bad-marks", "rinex good.ubx -o out --marks sideways", 2, "invalid choice"),
    c("rinex-no-out", "rinex good.ubx", 2, "required"),
    # a photo or a RINEX file is named as inspect names it (it asked about the receiver's raw
    # output), before the output directory is made
    c("rinex-jpeg", "rinex X/a.jpg -o out", 2, "X/a.jpg: no raw measurements and no "
      "navigation data: no UBX frames in this file (4 bytes, a JPEG image)"),
    c("rinex-rinex-obs", "rinex rover.obs -o out", 2, "a RINEX 3.04 observation file"),
    # -- replay -------------------------------------------------------------------------------
    c("replay-fifo", "replay fifo --no-zenoh", 2, "is a FIFO"),
    c("replay-dev-zero", "replay /dev/zero --no-zenoh", 2, "is a device"),
    c("replay-dir", "replay adir --no-zenoh", 2, "is a directory"),
    c("replay-missing", "replay nope.ubx --no-zenoh", 2, "no such file"),
    c("replay-speed-zero", "replay good.ubx --no-zenoh --speed 0", 2, "speed"),
    c("replay-speed-text", "replay good.ubx --no-zenoh --speed fast", 2, "speed"),
    *(c(f"replay-station-{i}", ("replay", "good.ubx", "--no-zenoh", "--station", s), 2,
        BAD_STATION) for i, s in enumerate(STATIONS[:6])),
    # -- run: files, stations, configuration, environment -------------------------------------
    c("run-file-fifo", "run --file fifo --no-zenoh --out-dir rec", 2, "is a FIFO"),
    c("run-file-dev-zero", "run --file /dev/zero --no-zenoh --out-dir rec", 2, "is a device"),
    c("run-file-dir", "run --file adir --no-zenoh --out-dir rec", 2, "is a directory"),
    c("run-file-missing", "run --file nope.ubx --no-zenoh --out-dir rec", 2, "no such file"),
    *(c(f"run-station-{i}", (*RUN.split(), f"--station={s}"), 2, BAD_STATION)
      for i, s in enumerate(STATIONS)),
    c("run-station-empty", (*RUN.split(), "--station", ""), 2, BAD_STATION),
    c("run-station-nul-in-config", f"{RUN} --config nul_station.toml", 2, BAD_STATION),
    c("run-station-env", RUN, 2, "GROUNDSTATION_STATION", GROUNDSTATION_STATION="$"),
    c("run-config-not-utf8", f"{RUN} --config not_utf8.toml", 2, "not UTF-8"),
    c("run-config-dir", f"{RUN} --config adir", 2, "is a directory"),
    c("run-config-fifo", f"{RUN} --config fifo", 2, "not a regular file"),
    c("run-config-missing", f"{RUN} --config nope.toml", 2, "file not found"),
    c("run-config-not-toml", f"{RUN} --config not_toml.toml", 2, "invalid TOML"),
    c("run-config-unknown-key", f"{RUN} --config unknown_key.toml", 2, "recorder.colour"),
    c("run-config-nan", f"{RUN} --config nan.toml", 2, "recorder.flush_interval_s"),
    c("run-config-inf", f"{RUN} --config inf.toml", 2, "recorder.rotate_size_mb"),
    c("run-config-tiny-status", f"{RUN} --config tiny_status.toml", 2, "status_interval_s"),
    c("run-config-huge-read", f"{RUN} --config huge_read.toml", 2, "source.read_size_bytes"),
    c("run-config-retry-text", f"{RUN} --config retry_text.toml", 2, "recorder.retry_s"),
    c("run-config-table-as-value", f"{RUN} --config table_value.toml", 2, "recorder"),
    c("run-env-unknown", RUN, 2, "GROUNDSTATION_BOGUS", GROUNDSTATION_BOGUS="1"),
    c("run-env-nan", RUN, 2, "recorder.flush_interval_s",
      GROUNDSTATION_RECORDER_FLUSH_INTERVAL_S="nan"),
    c("run-env-baud", RUN, 2, "source.baud", GROUNDSTATION_SOURCE_BAUD="12"),
    c("run-env-config-dir", RUN, 2, "is a directory", GROUNDSTATION_CONFIG="adir"),
    c("run-env-config-fifo", RUN, 2, "not a regular file", GROUNDSTATION_CONFIG="fifo"),
    c("run-port-fifo", "run --port fifo --no-zenoh --out-dir rec", 2, "is a FIFO"),
    c("run-port-dir", "run --port adir --no-zenoh --out-dir rec", 2, "is a directory"),
    c("run-port-file", "run --port good.ubx --no-zenoh --out-dir rec", 2, "use --file"),
    # a character device that is no serial port: refused before any file, not retried for ever
    # with an empty recording left behind
    c("run-port-dev-null", "run --port /dev/null --no-zenoh --out-dir rec", 2,
      "source.port: /dev/null is a character device without a terminal interface"),
    c("run-no-source", "run --no-zenoh --out-dir rec", 2, "no source configured"),
    # -- simulate -----------------------------------------------------------------------------
    c("simulate-out-exists", "simulate --out notes.txt --duration 5", 2, "without --force"),
    c("simulate-out-recording", "simulate --out good.ubx --duration 5", 2,
      "existing recording"),
    c("simulate-out-recording-forced", "simulate --out rec.mcap --duration 5 --force", 2,
      "existing recording"),
    c("simulate-truth-exists", "simulate --out new.ubx --truth notes.txt --duration 5", 2,
      "--truth"),
    c("simulate-base-out-dir", "simulate --out new.ubx --base-out adir --duration 5", 2,
      "is a directory"),
    c("simulate-truth-is-out", "simulate --out new.ubx --truth new.ubx --duration 5", 2,
      "is also the --out file"),
    c("simulate-out-no-dir", "simulate --out nodir/x.ubx --duration 5", 2, "does not exist"),
    # an output that cannot be created names its option, exit 2, as the others do (it was a
    # bare errno, exit 1, after the simulation)
    c("simulate-out-in-proc", "simulate --out /proc/x.ubx --duration 5", 2,
      "--out: cannot write /proc/x.ubx"),
    c("simulate-base-out-in-proc", "simulate --out new.ubx --base-out /proc/b.ubx --duration 5",
      2, "--base-out: cannot write /proc/b.ubx"),
    c("simulate-truth-in-proc", "simulate --out new.ubx --truth /proc/t.json --duration 5", 2,
      "--truth: cannot write /proc/t.json"),
    c("simulate-duration-zero", "simulate --out new.ubx --duration 0", 2, "duration"),
    c("simulate-faults-fifo", "simulate --out new.ubx --duration 5 --faults fifo", 2,
      "not a regular file"),
    c("simulate-faults-not-utf8", "simulate --out new.ubx --duration 5 --faults not_utf8.toml",
      2, "faults"),
    c("simulate-faults-negative", "simulate --out new.ubx --duration 5 --faults neg.toml", 2,
      "faults.dropout_per_min"),
    # -- simulate --from-recording ------------------------------------------------------------
    c("simulate-from-missing", "simulate --from-recording nope.ubx --out new.ubx", 2,
      "nope.ubx: no such file"),
    c("simulate-from-dir", "simulate --from-recording adir --out new.ubx", 2, "is a directory"),
    c("simulate-from-fifo", "simulate --from-recording fifo --out new.ubx", 2, "is a FIFO"),
    c("simulate-from-text", "simulate --from-recording notes.txt --out new.ubx", 2,
      "notes.txt: no UBX frames in this file"),
    c("simulate-from-jpeg", "simulate --from-recording X/a.jpg --out new.ubx", 2,
      "a JPEG image"),
    c("simulate-from-no-epochs", "simulate --from-recording nav_only.ubx --out new.ubx", 2,
      "no measurement epochs"),
    c("simulate-from-out-is-input", "simulate --from-recording good.ubx --out good.ubx --force",
      2, "is the input"),
    c("simulate-from-out-recording", "simulate --from-recording good.ubx --out rec.mcap --force",
      2, "existing recording"),
    c("simulate-from-out-exists", "simulate --from-recording good.ubx --out notes.txt", 2,
      "without --force"),
    c("simulate-from-truth-is-out",
      "simulate --from-recording good.ubx --out new.ubx --truth new.ubx", 2,
      "is also the --out file"),
    c("simulate-from-out-no-dir", "simulate --from-recording good.ubx --out nodir/x.ubx", 2,
      "does not exist"),
    c("simulate-from-out-in-proc", "simulate --from-recording good.ubx --out /proc/x.ubx", 2,
      "--out: cannot write /proc/x.ubx"),
    c("simulate-from-truth-in-proc",
      "simulate --from-recording good.ubx --out new.ubx --truth /proc/x.json", 2,
      "--truth: cannot write /proc/x.json"),
    c("simulate-from-no-out", "simulate --from-recording good.ubx", 2, "needs --out"),
    c("simulate-from-with-profile",
      "simulate --from-recording good.ubx --out new.ubx --profile seed", 2, "--profile"),
    c("simulate-from-with-base-out",
      "simulate --from-recording good.ubx --out new.ubx --base-out b.ubx", 2, "--base-out"),
    c("simulate-from-faults-missing",
      "simulate --from-recording good.ubx --out new.ubx --faults nope.toml", 2, "faults"),
    c("simulate-from-bad-form", "simulate --from-recording good.ubx --out new.ubx --as lea4t",
      2, "invalid choice"),
    c("simulate-as-without-recording", "simulate --as original --out new.ubx --duration 5", 2,
      "--as"),
    # -- solve --------------------------------------------------------------------------------
    c("solve-out-is-a-file", "solve good.ubx --positions x.pos --out good.ubx", 2,
      "not a directory"),
    c("solve-out-replaces-eo", "solve good.ubx --positions x.pos --eo X/cameras.csv --out X", 2,
      "would replace the input"),
    c("solve-out-inside-photos", "solve good.ubx --positions x.pos --photos X --out X/o", 2,
      "inside the input"),
    c("solve-flight-fifo", "solve fifo --positions x.pos --out o", 2, "is a FIFO"),
    c("solve-flight-dev-zero", "solve /dev/zero --positions x.pos --out o", 2, "is a device"),
    c("solve-flight-dir", "solve adir --positions x.pos --out o", 2, "is a directory"),
    c("solve-flight-corrupt-gzip", "solve corrupt.ubx.gz --positions x.pos --out o", 2,
      "corrupt gzip"),
    # a symbolic link loop (issue 27: an internal error, exit 1)
    c("solve-flight-symlink-loop", "solve loop1 --positions x.pos --out o", 2,
      "symbolic link loop"),
    c("solve-flight-symlink-loop-receiver", "solve loop1 --source receiver --out o", 2,
      "symbolic link loop"),
    c("solve-out-symlink-loop", "solve good.ubx --positions x.pos --out loop1", 2,
      "symbolic link loop"),
    c("rinex-symlink-loop", "rinex loop1 -o out", 2, "symbolic links"),
    c("inspect-symlink-loop", "inspect loop1", 2, "symbolic links"),
    c("solve-positions-fifo", "solve good.ubx --positions fifo --out o", 2, "not a regular"),
    c("solve-positions-corrupt-gzip", "solve good.ubx --positions corrupt.pos.gz --out o", 2,
      "damaged gzip"),
    c("solve-eo-fifo", "solve good.ubx --positions x.pos --eo fifo --out o", 2,
      "not a regular file"),
    c("solve-positions-missing", "solve good.ubx --positions nope.pos --out o", 2,
      "no such file"),
    c("solve-photos-file", "solve good.ubx --positions x.pos --photos good.ubx --out o", 2,
      "not a directory"),
    c("solve-base-without-xyz", "solve good.ubx --base good.ubx --out o", 2, "--base-xyz"),
    c("solve-base-xyz-two", "solve good.ubx --base good.ubx --base-xyz 1,2 --out o", 2,
      "--base-xyz"),
    c("solve-base-en-no-crs", "solve good.ubx --base good.ubx --base-en 501190,5903719,30 "
      "--out o", 2, "--base-crs"),
    c("solve-base-crs-geographic", "solve good.ubx --base good.ubx --base-en 501190,5903719,30 "
      "--base-crs 4326 --out o", 2, "not a projected CRS"),
    c("solve-base-crs-typo", "solve good.ubx --base good.ubx --base-en 501190,5903719,30 "
      "--base-crs 3262x --out o", 2, "--base-crs"),
    c("solve-lever-arm-nan", "solve good.ubx --positions x.pos --lever-arm nan,0,0 --out o", 2,
      "--lever-arm"),
    c("solve-epsg-text", "solve good.ubx --positions x.pos --epsg abc --out o", 2, "--epsg"),
    c("solve-interp", "solve good.ubx --positions x.pos --interp cubic --out o", 2, "--interp"),
    c("solve-max-gap", "solve good.ubx --positions x.pos --max-gap -1 --out o", 2, "--max-gap"),
    # the flight and the base are checked as inspect checks them, before anything is written
    c("solve-flight-text", "solve notes.txt --positions x.pos --out o", 2,
      "no UBX frames in this file"),
    c("solve-flight-jpeg", "solve X/a.jpg --positions x.pos --out o", 2, "a JPEG image"),
    c("solve-base-text", f"solve good.ubx --base notes.txt --base-xyz {BASE_XYZ} --out o", 2,
      "notes.txt: no UBX frames in this file"),
    c("solve-base-not-rinex", f"solve good.ubx --base bad.obs --base-xyz {BASE_XYZ} --out o", 2,
      "not a RINEX observation file"),
    c("solve-positions-jpeg", "solve good.ubx --positions X/a.jpg --out o", 2,
      "not an RTKLIB .pos text file"),
    c("solve-out-in-proc", "solve good.ubx --positions x.pos --out-dir /proc/nope", 2,
      "--out-dir: cannot create /proc/nope"),
    # failures after the output directory was created leave nothing behind (the snapshot)
    c("solve-positions-text", "solve good.ubx --positions notes.txt --out o", 2,
      "cannot parse", logs=True),
    c("solve-base-is-the-flight", f"solve good.ubx --base good.ubx --base-xyz {BASE_XYZ} "
      "--out o --no-progress", 2, "--base: good.ubx is the flight's own recording"),
    c("solve-engine-no-solution", f"solve good.ubx --base base.ubx --base-xyz {BASE_XYZ} "
      "--out o --no-progress", 1, "no navigation data", logs=True),
    # -- locate-base --------------------------------------------------------------------------
    c("locate-base-no-reference-file", "locate-base good.ubx --reference nope.crx.gz", 2,
      "--reference: nope.crx.gz: no such file"),
    c("locate-base-base-dir", "locate-base adir --reference good.ubx", 2,
      "BASE: adir: not a regular file"),
    c("locate-base-reference-not-rinex", "locate-base good.ubx --reference notes.txt", 2,
      "notes.txt: not RINEX observations"),
    c("locate-base-reference-xyz-llh", "locate-base good.ubx --reference notes.txt "
      "--reference-xyz 53.2,-8.9,90", 2, "--reference-xyz:"),
    c("locate-base-out-is-the-base", "locate-base good.ubx --reference notes.txt --out good.ubx",
      2, "--out: good.ubx is the input"),
    c("locate-base-negative-xyz", "locate-base good.ubx --reference notes.txt --reference-xyz "
      "-3978241.9,3382840.2,3649900.8", 2, "goes after '='"),
    # -- configure ----------------------------------------------------------------------------
    c("configure-unknown-profile", "configure --port /dev/null --profile nope --dry-run", 2,
      "unknown profile"),
    c("configure-no-port", "configure --profile lea6t-5hz", 2, "--port"),
    # -- watch, dashboard, solver, demo: stations and configuration ---------------------------
    *(c(f"watch-station-{i}", ("watch", "--station", s), 2, BAD_STATION)
      for i, s in enumerate(STATIONS[:5])),
    c("watch-station-env", "watch", 2, BAD_STATION, GROUNDSTATION_WATCH_STATION="a/b"),
    c("watch-config-fifo", "watch --config fifo", 2, "not a regular file"),
    c("watch-duration", "watch --duration -1", 2, "duration"),
    c("watch-endpoint", "watch --zenoh-connect nowhere", 2, "zenoh.connect"),
    # -- rtk: the live engine ---------------------------------------------------------------------
    c("rtk-rover-name", ("rtk", "--rover", "a/b", "--base", "b", "--base-xyz",
                         "4146349.2,612312.5,4791750.9"), 2, "--rover: 'a/b' is not a station"),
    c("rtk-negative-duration", "rtk --rover a --base b --base-xyz 4146349.2,612312.5,4791750.9 "
      "--duration -5", 2, "--duration: must be >= 0"),
    c("rtk-no-base-position", "rtk --rover a --base b", 2, "--base-xyz: give the base's position"),
    c("rtk-endpoint", "rtk --rover a --base b --base-xyz 4146349.2,612312.5,4791750.9 "
      "--zenoh-connect nowhere", 2, "zenoh.connect"),
    c("rtk-base-env", "rtk --rover a --base-xyz 4146349.2,612312.5,4791750.9", 2, BAD_STATION,
      GROUNDSTATION_RTK_BASE="x y"),
    c("dashboard-station", ("dashboard", "--station", "**"), 2, BAD_STATION),
    c("dashboard-station-in-config", "dashboard --config stations.toml", 2, BAD_STATION),
    c("dashboard-port", "dashboard --port 70000", 2, "port"),
    c("dashboard-port-env", "dashboard", 2, "port", GROUNDSTATION_DASHBOARD_PORT="abc"),
    c("dashboard-config-dir", "dashboard --config adir", 2, "is a directory"),
    c("solver-station-wildcard", ("solver", "--station", "**"), 2, BAD_STATION),
    c("solver-station-dollar", ("solver", "--station", "$"), 2, BAD_STATION),
    c("solver-station-table", "solver --config solver_bad_station.toml", 2, BAD_STATION),
    c("solver-rate", "solver --config solver_rate.toml", 2, "max_sessions_per_min"),
    c("solver-config-not-utf8", "solver --config not_utf8.toml", 2, "not UTF-8"),
    c("solver-queue-env", "solver", 2, "queue_size", GROUNDSTATION_SOLVER_QUEUE_SIZE="0"),
    c("demo-station-space", ("demo", "--station", "a b", "--no-zenoh"), 2, BAD_STATION),
    c("demo-station-dollar", ("demo", "--station", "$", "--no-zenoh"), 2, BAD_STATION),
    c("demo-short-flight", "demo --flight 10 --no-zenoh", 2, "flight"),
    c("router-listen", "router --listen foo --duration 1", 2, "not a Zenoh endpoint"),
    c("router-config-dir", "router --config adir", 2, "is a directory"),
    c("router-duration-env", "router", 2, "duration_s", GROUNDSTATION_ROUTER_DURATION_S="nan"),
    c("router-config-not-utf8", "router --config not_utf8.toml", 2, "not UTF-8"),
    c("unknown-command", "bogus", 2, "invalid choice"),
]


def _rinex_line(text: str, label: str) -> str:
    return f"{text:<60}{label:<20}\n"


RINEX_OBS = "".join((
    _rinex_line("     3.04           OBSERVATION DATA    G (GPS)", "RINEX VERSION / TYPE"),
    _rinex_line(f"{'groundstation 0.1.0':<40}20261127 120000 UTC", "PGM / RUN BY / DATE"),
    _rinex_line("rover", "MARKER NAME"),
    _rinex_line("", "OBSERVER / AGENCY"),
    _rinex_line("", "REC # / TYPE / VERS"),
    _rinex_line("", "ANT # / TYPE"),
    _rinex_line("  4146349.2471   612312.5498  4791750.8505", "APPROX POSITION XYZ"),
    _rinex_line("        0.0000        0.0000        0.0000", "ANTENNA: DELTA H/E/N"),
    _rinex_line("G    4 C1C L1C D1C S1C", "SYS / # / OBS TYPES"),
    _rinex_line("  2026    11    27    12     0    0.0000000     GPS", "TIME OF FIRST OBS"),
    _rinex_line("", "END OF HEADER"),
    "> 2026 11 27 12 00  0.0000000  0  1\n",
    "G05  21000000.000 1      110000000.000 1          -100.000 1            45.000 1\n",
))
"""A RINEX 3.04 observation file of one epoch (1 008 bytes)."""
RINEX_NAV = _rinex_line("     2.11           N: GPS NAV DATA", "RINEX VERSION / TYPE") + \
    _rinex_line("", "END OF HEADER")


def _workspace(root: Path) -> None:
    """The inputs every case may name."""
    data, _ = flight_stream(10)
    (root / "good.ubx").write_bytes(data)
    (root / "base.ubx").write_bytes(flight_stream(10, pr_offset_m=300.0)[0])  # no ephemerides
    (root / "nav_only.ubx").write_bytes(bytes.fromhex(  # one NAV-POSLLH, no epoch
        "b56201021c00" + "00" * 28 + "1fa6"))
    (root / "rec.mcap").write_bytes(MCAP_MAGIC + b"\x00" * 32)
    (root / "notes.txt").write_text("mine\n")
    (root / "bad.obs").write_text("not RINEX\n")
    (root / "rover.obs").write_text(RINEX_OBS)  # what `rinex` writes, handed back to it
    with gzip.open(root / "base.nav.gz", "wt") as f:
        f.write(RINEX_NAV)
    (root / "x.pos").write_text("% not used: the command stops before reading it\n")
    # gzip header, then a deflate block of an invalid type: zlib.error when read
    bad = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03" + b"\xff" * 64
    (root / "corrupt.ubx.gz").write_bytes(bad)
    (root / "corrupt.mcap").write_bytes(bad)
    (root / "corrupt.pos.gz").write_bytes(bad)
    os.mkfifo(root / "fifo")
    (root / "fifo-link.ubx").symlink_to(root / "fifo")
    (root / "loop1").symlink_to(root / "loop2")
    (root / "loop2").symlink_to(root / "loop1")
    (root / "adir").mkdir()
    (root / "X").mkdir()
    (root / "X" / "a.jpg").write_bytes(bytes.fromhex("ffd8ffd9"))  # --photos X has a JPEG
    (root / "X" / "cameras.csv").write_text("name,x,y,z,omega,phi,kappa\nA.JPG,1,2,3,0,0,0\n")
    (root / "not_utf8.toml").write_bytes(b"station = \"\xff\xfe\"\n")
    (root / "not_toml.toml").write_text("station = \n")
    (root / "unknown_key.toml").write_text("[recorder]\ncolour = \"red\"\n")
    (root / "nan.toml").write_text("[recorder]\nflush_interval_s = nan\n")
    (root / "inf.toml").write_text("[recorder]\nrotate_size_mb = inf\n")
    (root / "tiny_status.toml").write_text("status_interval_s = 1e-9\n")
    (root / "huge_read.toml").write_text("[source]\nread_size_bytes = 1000000000000\n")
    (root / "retry_text.toml").write_text("[recorder]\nretry_s = \"soon\"\n")
    (root / "table_value.toml").write_text("recorder = 3\n")
    (root / "nul_station.toml").write_text("station = \"a\\u0000b\"\n")
    (root / "neg.toml").write_text("dropout_per_min = -1\n")
    (root / "stations.toml").write_text("stations = [\"ok\", \"a$b\"]\n")
    (root / "solver_bad_station.toml").write_text("[stations.\"a/b\"]\ninterp = \"linear\"\n")
    (root / "solver_rate.toml").write_text("max_sessions_per_min = 0\n")


def _snapshot(root: Path) -> dict[str, str]:
    """Every path under ``root``: its type and, for a file, its content hash."""
    out: dict[str, str] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            mode = p.lstat().st_mode
            if stat.S_ISREG(mode):
                out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
            else:
                out[str(p.relative_to(root))] = oct(stat.S_IFMT(mode))
    return out


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("bad_input")
    _workspace(root)
    return root


def test_the_table_is_large_and_every_command_is_in_it() -> None:
    from groundstation.commands import COMMANDS

    assert len(CASES) >= 80
    assert len({k.id for k in CASES}) == len(CASES)
    assert set(COMMANDS) <= {k.argv[0] for k in CASES}


@pytest.mark.parametrize("case", CASES, ids=[k.id for k in CASES])
def test_bad_input(case: Case, workspace: Path) -> None:
    env = cli_env(**case.env)
    before = _snapshot(workspace)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "groundstation.cli", *case.argv], cwd=workspace, env=env,
            capture_output=True, text=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{case.argv} hung (no answer in {TIMEOUT_S} s)")
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert "internal error" not in proc.stderr, proc.stderr
    if case.logs:
        assert [ln for ln in lines if ln.startswith("groundstation")] == lines[-1:], lines
        lines = lines[-1:]
    assert len(lines) == 1, proc.stderr
    assert case.says in lines[0], lines[0]
    assert proc.returncode == case.status, proc.stderr
    assert _snapshot(workspace) == before  # nothing created, nothing changed
