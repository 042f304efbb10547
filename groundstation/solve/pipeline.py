"""The post-flight chain: flight -> marks -> positions -> photos -> lever arm -> output files.

:func:`solve` is what ``groundstation solve`` and the solver service call; it takes resolved
:class:`SolveSettings` and an optional progress callback and returns a :class:`SolveResult`.

Every input is checked (its content too: a flight or base without UBX frames is refused as
``inspect`` refuses it; given base coordinates against the base receiver's own fixes) before
the output directory is created. The run writes into a staging folder that replaces the
earlier result in the output directory only when the run is complete
(:func:`groundstation.outpaths.staged_output`): a run that fails or is interrupted leaves the
directory as it was, and a result is always one run's, whole.
"""

from __future__ import annotations

import gzip
import logging
import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from groundstation import outpaths
from groundstation.errors import ConfigError, GroundstationError, InputError
from groundstation.geodesy import ecef_to_llh, enu_rotation
from groundstation.gpstime import utc_span
from groundstation.offline.inspect import require_ubx_frames
from groundstation.rules.marks import LOST_ON_LINK, Mark, build_marks
from groundstation.solve import (
    camclock,
    clockoffset,
    exif,
    leverarm,
    outputs,
    photos,
    posfile,
    positions,
    record,
    report,
)
from groundstation.solve import interpolate as mi
from groundstation.solve.base import (
    OwnFixes,
    base_from_own_fixes,
    check_base,
    check_distance,
    check_pairing,
    fix_positions,
    own_fixes,
)
from groundstation.solve.engine import is_rinex_obs_name
from groundstation.solve.flight import FlightObservations, FlightRecords, read_flight
from groundstation.solve.integrity import grade as gr
from groundstation.solve.report_data import LostMarks, ReportInput, lost_marks_text
from groundstation.solve.settings import SolveSettings
from groundstation.solve.trajectory import Q_FIX, Trajectory
from groundstation.storage.reading import check_regular

log = logging.getLogger("groundstation.solve")

Progress = Callable[[str, float], None]
BaseCheck = tuple[str, bool]
"""How the base coordinates were checked: (text, doubtful) (:func:`base.check_base`)."""


class NothingPositionedError(GroundstationError):
    """The solve positioned no camera mark (exit status 1: a run that gave no result)."""


@dataclass(frozen=True, slots=True)
class SolveResult:
    """Everything a solve produced, for the command line, the service and the tests."""

    rows: tuple[outputs.CameraRow, ...]
    marks: tuple[Mark, ...]
    mark_positions: mi.MarkPositions
    trajectory: Trajectory
    match: photos.MatchResult | None
    lever: leverarm.LeverArmEstimate | None
    files: tuple[Path, ...]
    epsg: int | str
    notes: tuple[str, ...] = field(default_factory=tuple)
    reconciliation: tuple[str, ...] = field(default_factory=tuple)
    flight: FlightRecords | None = None
    """What was taken from the flight recording (kept in the run's record for a re-base)."""
    interpolations: record.Interpolations | None = None
    """The positions interpolated from the trajectory (kept in the run's record)."""

    def summary(self) -> dict[str, object]:
        """Counts as plain JSON values (for the service's ``solution`` message)."""
        mp = self.mark_positions
        return {
            "marks": len(self.marks),
            "marks_positioned": mp.positioned,
            "marks_in_gap": int(np.sum((mp.flags & mi.FLAG_GAP) != 0)),
            "marks_fixed": int(np.sum(mp.quality == Q_FIX)),
            "marks_by_grade": {name: int(np.sum(mp.grade == code))
                               for code, name in gr.GRADE_NAMES.items()
                               if np.any(mp.grade == code)},
            "photos_paired": len(self.match.pairs) if self.match else 0,
            "photos_unmatched": len(self.match.unmatched_photos) if self.match else 0,
            "orphan_marks": len(self.match.orphan_marks) if self.match else 0,
            "clock_offset_s": self.match.gps_minus_camera_s if self.match else None,
            "epochs": len(self.trajectory),
            "fixed_fraction": self.trajectory.fixed_fraction,
            "epsg": self.epsg,
            "files": [str(p) for p in self.files],
            "notes": list(self.notes),
        }


def _validate(s: SolveSettings) -> tuple[SolveSettings, BaseCheck | None, FlightRecords | None]:
    """Every check made before anything is written; the base check when it can be made now.

    Returns:
        The settings, with the base position the base's own fixes give when none was given
        (and its sigma); the base check; the flight's records when a check read them (the
        marks stage takes them instead of reading the flight again).
    """
    read: list[FlightRecords] = []

    def flight() -> FlightRecords:
        if not read:
            read.append(_flight_records(s))
        return read[0]

    if s.interp not in mi.INTERPOLATORS:
        raise ConfigError("--interp", f"unknown method {s.interp!r}")
    if s.edge not in mi.EDGES:
        raise ConfigError("--edge", f"unknown edge {s.edge!r}")
    if not s.max_gap_s > 0:
        raise ConfigError("--max-gap", "must be positive")
    if not math.isfinite(s.shutter_delay_ms):
        raise ConfigError("--shutter-delay-ms", "must be a number")
    if s.source_name() not in positions.POSITION_SOURCES:
        raise ConfigError("--source", f"unknown position source {s.source!r}")
    if s.photos is not None and not s.photos.is_dir():
        raise ConfigError("--photos", f"{s.photos} is not a directory")
    if s.epsg is not None or s.geoid is not None:
        # the CRS, its heights and the geoid grid, before any work (a grid PROJ does not have,
        # or that does not cover the base, would be found out after the engine)
        proj = outputs.Projector(s.epsg or 4326, s.geoid)
        if s.base_ecef_m is not None:
            lat, lon, h = ecef_to_llh(*s.base_ecef_m)
            proj.heights(np.array([lat]), np.array([lon]), np.array([h]))
    # never write over an input or a recording (groundstation.outpaths)
    outputs.check_output_dir(s.out_dir, [s.photos, s.flight, s.positions, s.base, s.eo])
    # The inputs' contents, before anything is created: a JPEG or a text file given as the
    # flight or the base gets inspect's verdict, not a later "no camera marks" or half a run.
    # (a re-base's recordings were checked when it was solved; its record may stand for them)
    if s.rebase is None:
        require_ubx_frames(s.flight)
    if s.positions is not None:
        posfile.check_pos_file(s.positions)
    if s.base is not None and s.rebase is None:
        if is_rinex_obs_name(s.base):
            _require_rinex_obs(s.base)
        else:
            require_ubx_frames(s.base)
    if s.photos is not None:  # photos of another flight: said now, not after the engine
        marks = build_marks(flight().timemarks)
        times = _mark_times(s, marks)
        photos.check_belongs(photos.match(clockoffset.photo_times(exif.scan_photos(s.photos)),
                                          times), times)
    own = s.base is not None and s.base_ecef_m is None and s.positions is None
    if own and s.base is not None:
        s = _base_from_own_fixes(s.base, s)
    if s.base is None or s.base_ecef_m is None:
        return s, None, (read[0] if read else None)
    # Before the engine: coordinates kilometres off give no solution at all, and a half hour
    # of engine work before saying so (base.BASE_REFUSED_M).
    base, base_ecef_m = s.base, s.base_ecef_m
    if own:
        text, doubtful = s.base_given, False
    else:
        s, fixes = _base_own_fixes(s)
        text, doubtful = check_base(base, base_ecef_m, None, s.positions, s.base_given, fixes)
    if s.positions is None and s.rebase is None:  # (a re-based result was checked so)
        # The same for a base of another day, the flight's own recording, or a base hundreds
        # of kilometres away.
        covered = check_pairing(s.flight, base)
        check_distance(base_ecef_m, fix_positions(flight().nav))
        text = f"{text}; {covered}" if covered else text
    return s, (text, doubtful), (read[0] if read else None)


def _base_own_fixes(s: SolveSettings) -> tuple[SolveSettings, OwnFixes | None]:
    """The mean of the base receiver's own fixes: as the settings keep it (a re-base's
    record), else read now and kept in the settings; None when there are none to read (no
    u-blox base recording, or one that cannot be read: the base check says why)."""
    if s.base_fix_count >= 0:
        return s, OwnFixes(s.base_fix_mean_m, s.base_fix_count)
    if s.base is None:
        return s, None
    try:
        fixes = own_fixes(s.base)
    except GroundstationError:
        return s, None
    if fixes is None:
        return s, None
    return replace(s, base_fix_mean_m=fixes.mean_ecef_m, base_fix_count=fixes.count), fixes


def _base_from_own_fixes(path: Path, s: SolveSettings) -> SolveSettings:
    """No base coordinates given: the mean of the base receiver's own fixes, known to metres.

    Raises:
        ConfigError: naming ``--base-xyz``: a RINEX base, or a recording without fixes.
    """
    if is_rinex_obs_name(path):
        raise ConfigError("--base-xyz", (
            f"the coordinates of the base {path.name} are needed (--base-xyz X,Y,Z or --base-llh "
            "LAT,LON,H): RINEX observations carry no receiver fixes to average instead"))
    xyz, sd, n = base_from_own_fixes(fix_positions(read_flight(path).nav))
    sd_text = "/".join(f"{v:.1f}" for v in sd)
    return replace(s, base_ecef_m=xyz, base_sd_enu_m=sd, base_estimated=True,
                   base_fix_mean_m=xyz, base_fix_count=n, base_given=(
        f"not given: the mean of the base receiver's own {n} stand-alone fixes, σ east/north/"
        f"up {sd_text} m (camera positions are relative to a base known to metres only; give "
        "--base-xyz or --base-llh for a surveyed point)"))


def _require_rinex_obs(path: Path) -> None:
    """Refuse a base named like RINEX observations that does not start like them.

    Raises:
        InputError: unreadable, or no ``RINEX VERSION / TYPE`` header line.
    """
    check_regular(path)
    try:
        with (gzip.open(path, "rb") if path.name.lower().endswith(".gz")
              else path.open("rb")) as f:
            first = f.read(80)
    except (OSError, EOFError, zlib.error) as err:
        raise InputError(f"{path}: cannot read: {err}") from err
    if b"RINEX VERSION / TYPE" not in first:
        raise InputError(f"{path}: not a RINEX observation file (no RINEX VERSION / TYPE "
                         "header line)")


def solve(settings: SolveSettings, progress: Progress | None = None) -> SolveResult:
    """Run the whole chain and write every output into ``settings.out_dir``.

    The stages, in order: validate, marks, positions, positions at marks, photos, camera
    rows (coordinates, attitude, lever arm), output files, report.

    Raises:
        ConfigError: inconsistent settings (names the option).
        InputError: unreadable inputs, no marks, no epochs.
        engine.protocol.ToolMissingError: the RTKLIB engine was chosen and rnx2rtkp is missing.
        positions.NoSolutionError: the engine positioned no epoch.
        NothingPositionedError: no mark was positioned (nothing is written).
    """
    if settings.flight_copies:
        return _solve_merged(settings, progress)
    s, base_check, rec = _validate(settings)
    with outpaths.staged_output(s.out_dir, "--out-dir") as stage:
        if s.rebase is not None:
            record.carry_engine_files(s.rebase, stage)
        result = _solve(replace(s, out_dir=stage), progress, base_check, rec)
        record.write(s, result.trajectory, result.interpolations or record.Interpolations(),
                     result.flight, stage, s.out_dir)
    return _relocated(result, stage, s.out_dir)


def _solve_merged(settings: SolveSettings, progress: Progress | None) -> SolveResult:
    """Several recordings of the flight's receiver (the radio's and an on-board log): merged
    frame by frame (:mod:`groundstation.offline.merge`) into one, solved as the flight."""
    from groundstation.offline.merge import one_recording

    copies = (settings.flight, *settings.flight_copies)
    outputs.check_output_dir(settings.out_dir, copies)
    with one_recording(copies) as (merged, report):
        assert report is not None
        log.info("%s", report.text())
        return solve(replace(settings, flight=merged, flight_copies=(), recordings=copies,
                             merged_from=report.text()), progress)


def _relocated(r: SolveResult, stage: Path, out_dir: Path) -> SolveResult:
    """The result with the staging folder's paths (files, notes) as they are now, in
    ``out_dir``."""
    files = tuple(out_dir / p.relative_to(stage) if p.is_relative_to(stage) else p
                  for p in r.files)
    notes = tuple(outpaths.unstaged(n, stage) for n in r.notes)
    return replace(r, files=files, notes=notes, trajectory=_traj_unstaged(r.trajectory, stage))


def _traj_unstaged(traj: Trajectory, stage: Path) -> Trajectory:
    """The trajectory with its notes naming the final place of the staging folder's files."""
    return replace(traj, notes=tuple(outpaths.unstaged(n, stage) for n in traj.notes))


def _solve(s: SolveSettings, progress: Progress | None,
           base_check: BaseCheck | None, rec_read: FlightRecords | None = None) -> SolveResult:
    """:func:`solve` after the checks, into the (staging) folder ``s.out_dir``."""
    notes: list[str] = [s.merged_from] if s.merged_from else []
    rec, marks = _marks(s, progress, rec_read)
    traj = _positions(s, rec, notes, progress)
    interp = record.Interpolations.of(s)
    times, mp = _positions_at_marks(s, traj, marks, notes, progress, interp)
    if mp.positioned == 0:  # every export would be empty: a failed run, nothing written
        raise NothingPositionedError(_why_nothing(s, traj, marks, times))
    photo_list, match, recon = _photos(s, times, progress)
    if match is not None:  # an ambiguous pairing is said on stderr, in the printout and report
        for w in match.warnings:
            log.warning("%s", w)
        notes.extend([*match.notes, *(f"WARNING {w}" for w in match.warnings)])
    if s.photos is None:
        notes.append(f"no photos given: marks named {outputs.MARK_NAME_PREFIX}NNNN (the "
                     "receiver's mark count) in geo.txt, reference.csv, pix4d.csv")
    by_clock, numbers = _clock_photos(s, traj, marks, times, match, notes, interp)
    lost = rec.lost_by_cause(marks, by_clock.t_gps_ns.tolist() if by_clock else ())
    # photos no count jump accounts for (before the first received mark, after the last, or
    # never counted): lost on the link where their epoch was, else never counted
    unnumbered = ([int(t) for p, t in zip(by_clock.photo, by_clock.t_gps_ns.tolist(), strict=True)
                   if p not in numbers] if by_clock is not None else [])
    on_link = [t for t in unnumbered if rec.cause_at(t) == LOST_ON_LINK]
    lost[LOST_ON_LINK].extend([-1] * len(on_link))
    not_counted = len(unnumbered) - len(on_link)
    notes.extend(lost_marks_text(lost))
    if s.base_estimated:
        notes.append(f"WARNING base position {s.base_given}")
    if s.base_sd_enu_m is not None:
        notes.append(
            "base position σ east/north/up " + "/".join(f"{v:.3f}" for v in s.base_sd_enu_m)
            + " m: in the absolute sigmas of cameras.csv (abs_sd_*); the photogrammetry exports "
            "carry the relative ones (weight the cameras by them: the base's error moves the "
            "whole block alike)")
    cams = _cameras(s, marks, mp, traj, photo_list, match, notes, by_clock, numbers)
    files = outputs.write_all(cams.output(traj, mp, notes, s.base_sd_enu_m), s.out_dir)
    report_files, report_notes = _report(s, traj, marks, mp, photo_list, match, cams, notes,
                                         base_check, lost, not_counted,
                                         rec.observed or FlightObservations())
    files.extend(report_files)
    notes.extend(report_notes)
    if s.exif_copies and s.photos is not None:
        outputs.write_exif_copies(cams.rows, s.photos, s.out_dir / "photos")
        notes.append(f"EXIF GPS tags written to copies in {s.out_dir / 'photos'}")
    return SolveResult(
        cams.rows, marks, mp, traj, match, cams.lever, tuple(files), cams.epsg, tuple(notes),
        tuple(recon), rec, interp,
    )


def _clock_photos(
    s: SolveSettings, traj: Trajectory, marks: tuple[Mark, ...],
    times: list[int | None], match: photos.MatchResult | None, notes: list[str],
    interp: record.Interpolations,
) -> tuple[camclock.ClockPositions | None, dict[int, int]]:
    """Stage 4b: the photos without a received mark, positioned at their own time through the
    camera clock fitted on the paired ones, and the lost marks' numbers they stand for (where a
    count jump accounts for them)."""
    if match is None or not match.unmatched_photos:
        return None, {}
    mark_s = np.array([t / 1e9 if t is not None else np.nan for t in times])
    pairs = match.pairs
    precise = np.zeros(match.photo_s.size, dtype=np.bool_)
    if match.photo_precise.size == precise.size:
        precise = match.photo_precise.astype(np.bool_)
    clock = camclock.fit(
        np.array([match.photo_s[p.photo] for p in pairs]),
        np.array([mark_s[p.mark] for p in pairs]),
        np.array([precise[p.photo] for p in pairs], dtype=bool))
    timed = [i for i in match.unmatched_photos if math.isfinite(match.photo_s[i])]
    if clock is None or not timed:
        return None, {}
    by_clock = camclock.position_photos(traj, clock, match.photo_s, precise, timed,
                                        s.interp, s.max_gap_s, interp)
    gps_s = [float(t) / 1e9 for t in by_clock.t_gps_ns]
    numbers = {by_clock.photo[j]: n for j, n in camclock.lost_numbers(
        gps_s, marks, mark_s.tolist()).items()}
    notes.append(clock.text())
    positioned = int(np.sum(np.all(np.isfinite(by_clock.ecef_m), axis=1)))
    notes.append(
        f"{len(timed)} photo(s) without a received mark timed by the camera clock, "
        f"{positioned} positioned there (flag camera_clock; timing sigma median "
        f"{float(np.median(by_clock.timing_sd_s)) * 1e3:.0f} ms, times the speed added to "
        f"their sigma); {len(numbers)} named by the lost mark they stand for")
    return by_clock, numbers


def _why_nothing(s: SolveSettings, traj: Trajectory, marks: tuple[Mark, ...],
                 times: list[int | None]) -> str:
    """Why no mark was positioned, in one line: the time spans when they do not overlap."""
    head = f"no camera position computed ({len(marks)} marks, 0 positioned)"
    known = [t for t in times if t is not None]
    if not known:
        return f"{head}: no mark has a time" if marks else f"{head}: the flight has no marks"
    p0, p1 = int(traj.t_gps_ns[0]), int(traj.t_gps_ns[-1])
    m0, m1 = min(known), max(known)
    spans = (f"the positions ({traj.source}) span {utc_span((p0, p1))}, the marks "
             f"{utc_span((m0, m1))}")
    if m1 < p0 or m0 > p1:
        what = "another day's or flight's solution?" if s.positions else "wrong recordings?"
        return f"{head}: {spans}: no overlap ({what})"
    return (f"{head}: {spans}: every mark falls in a gap of the positions longer than "
            f"--max-gap {s.max_gap_s:g} s")


def _marks(s: SolveSettings, progress: Progress | None, rec: FlightRecords | None = None,
           ) -> tuple[FlightRecords, tuple[Mark, ...]]:
    """Stage 1: the flight's TIM-TM2 records (and receiver fixes) and the marks they make
    (``rec``: already read by the checks)."""
    rec = rec if rec is not None else _flight_records(s, progress)
    marks = tuple(build_marks(rec.timemarks))
    if not marks and s.photos is None:
        raise InputError(f"{s.flight}: no camera marks in this flight: nothing to position "
                         "(hot-shoe cable on the receiver's EXTINT0 pin? time-mark output on: "
                         "groundstation configure)")
    log.info("%s: %d camera marks (%d time-mark records)", s.flight.name, len(marks),
             len(rec.timemarks))
    return rec, marks


def _flight_records(s: SolveSettings, progress: Progress | None = None) -> FlightRecords:
    """The flight's records: a re-based result's own (what its solve read), else read from
    the recording."""
    kept = record.flight_records(s.rebase) if s.rebase is not None else None
    if kept is not None:
        return kept
    if s.rebase is not None and not s.flight.exists():
        raise ConfigError("--rebase", (
            f"{s.rebase / record.FLIGHT_NAME} cannot stand for the recording, and "
            f"{s.flight}: no longer there: put the recording back where it was"))
    return read_flight(s.flight, progress, observations=True)


def _positions(
    s: SolveSettings, rec: FlightRecords, notes: list[str], progress: Progress | None
) -> Trajectory:
    """Stage 2: the antenna's trajectory from the chosen position source (a .pos file, RTKLIB
    against the base, or the receiver's own fix). An engine run has stages of its own
    (``engine.run_engine``): RINEX and phase conditioning, "dynamics" (a forward pass measures
    the rover's accelerations and sets the filter's acceleration noise), the solve."""
    if s.rebase is not None:  # the finished result's trajectory, moved with the base
        traj, moved = record.shifted_trajectory(s, s.out_dir)
        notes.append(moved)
        notes.extend(outpaths.unstaged(n, s.out_dir) for n in traj.notes)
        return traj
    src = positions.get_source(s.source_name())
    opts = positions.SourceOptions(
        flight=s.flight, positions=s.positions, base=s.base, base_ecef_m=s.base_ecef_m,
        work_dir=s.out_dir / "rtklib", nav_solutions=rec.nav,
        engine=s.engine, rtk_conf=s.rtk_conf, rtklib_overrides=dict(s.rtk_options),
    )
    traj = src.trajectory(opts, progress)
    if len(traj) == 0:
        raise InputError(f"{traj.source}: no epochs")
    # The report quotes these notes: they name the engine's files where they will be once the
    # run is moved into place (the trajectory's own notes name them where they are now, for
    # the report to read engine.json; see _relocated).
    notes.extend(outpaths.unstaged(n, s.out_dir) for n in traj.notes)
    if traj.metre_level:
        notes.append("positions are the receiver's own fix: metre level, not for mapping")
    return traj


def _positions_at_marks(
    s: SolveSettings, traj: Trajectory, marks: tuple[Mark, ...], notes: list[str],
    progress: Progress | None, interp: record.Interpolations,
) -> tuple[list[int | None], mi.MarkPositions]:
    """Stage 3: each mark's exposure time (edge and shutter delay) and the antenna there."""
    times = _mark_times(s, marks)
    stage = ("positions at the marks, moved with the base" if s.rebase is not None
             else f"interpolate ({s.interp})")
    if progress is not None:
        progress(stage, 0.0)
    mp = interp(traj, times, s.interp, s.max_gap_s)
    if progress is not None:
        progress(stage, 1.0)
    notes.append(
        f"marks: {len(marks)}, positioned {mp.positioned}, edge {s.edge}, shutter delay "
        f"{s.shutter_delay_ms:g} ms, interpolation {mi.METHOD_TEXT[s.interp]} (--interp), "
        f"{int(np.sum((mp.flags & mi.FLAG_GAP) != 0))} in gaps > {s.max_gap_s:g} s"
    )
    return times, mp


def _mark_times(s: SolveSettings, marks: Sequence[Mark]) -> list[int | None]:
    """Each mark's exposure time (the chosen edge and the shutter delay)."""
    return [mi.mark_time_ns(m.falling_t_gps_ns, m.rising_t_gps_ns, s.edge, s.shutter_delay_ms)
            for m in marks]


def _photos(
    s: SolveSettings, times: list[int | None], progress: Progress | None
) -> tuple[list[exif.Photo], photos.MatchResult | None, list[str]]:
    """Stage 4: the photos, paired with the marks by time (none without ``--photos``)."""
    if s.photos is None:
        return [], None, []
    photo_list = exif.scan_photos(s.photos)
    if progress is not None:
        progress("photos", 0.5)
    match = photos.match(clockoffset.photo_times(photo_list), times)
    recon = photos.reconciliation_lines(match, photo_list, times)
    if progress is not None:
        progress("photos", 1.0)
    return photo_list, match, recon


@dataclass(frozen=True, slots=True)
class _Cameras:
    """Stage 5's result: one row per photo (or mark), antenna and camera coordinates."""

    rows: tuple[outputs.CameraRow, ...]
    epsg: int | str
    proj: outputs.Projector
    traj_llh: npt.NDArray[np.float64]
    mark_llh: npt.NDArray[np.float64]
    cam: npt.NDArray[np.float64]
    lever: leverarm.LeverArmEstimate | None

    def output(
        self, traj: Trajectory, mp: mi.MarkPositions, notes: list[str],
        base_sd_enu_m: tuple[float, float, float] | None = None,
    ) -> outputs.SolveOutput:
        return outputs.SolveOutput(
            rows=self.rows, epsg=self.epsg, crs_name=self.proj.name,
            projected=self.proj.projected, trajectory_llh=self.traj_llh,
            trajectory_quality=traj.quality, trajectory_t_gps_ns=traj.t_gps_ns,
            mark_llh=self.mark_llh, mark_t_gps_ns=mp.t_gps_ns, notes=tuple(notes),
            height_datum=self.proj.height_datum, base_sd_enu_m=base_sd_enu_m,
        )


def _row_entries(
    n_marks: int, photo_list: list[exif.Photo], match: photos.MatchResult | None
) -> list[tuple[str, int]]:
    """Which marks become rows: photos (paired or not), then orphan marks; or every mark."""
    if match is None:
        return [("", k) for k in range(n_marks)]
    by_photo = match.mark_of_photo()
    entries = [(ph.name, by_photo.get(i, -1)) for i, ph in enumerate(photo_list)]
    entries += [("", k) for k in match.orphan_marks]
    return entries


def _attitude(
    s: SolveSettings, entries: list[tuple[str, int]], row_t: npt.NDArray[np.float64],
    ant_x: npt.NDArray[np.float64], ant_y: npt.NDArray[np.float64],
    proj: outputs.Projector, llh: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], list[str], dict[str, leverarm.ExteriorOrientation]]:
    """Attitude per row: EO file by photo name, else nadir with kappa along the track."""
    opk = np.full((len(entries), 3), np.nan)
    attitude = ["none"] * len(entries)
    eo_by_name: dict[str, leverarm.ExteriorOrientation] = {}
    if s.eo is not None:
        eo_by_name = {e.name: e for e in leverarm.read_eo(s.eo)}
        for i, (name, _) in enumerate(entries):
            e = eo_by_name.get(name) or eo_by_name.get(Path(name).stem)
            if e is not None:
                opk[i] = (e.omega_deg, e.phi_deg, e.kappa_deg)
                attitude[i] = "eo"
    # κ from the direction of travel: track order of the positioned marks.
    if any(a == "none" for a in attitude):
        order = np.argsort(np.where(np.isfinite(row_t), row_t, np.inf), kind="stable")
        ok = order[np.isfinite(ant_x[order])]
        if ok.size:
            # κ from metric east/north: in a geographic CRS x/y are degrees, and a degree of
            # longitude is cos(latitude) of a degree of latitude (48.6 instead of 59.5 deg).
            east, north = ant_x[ok], ant_y[ok]
            if not proj.projected:
                lat0 = float(np.nanmean(llh[ok, 0]))
                east = (llh[ok, 1] - llh[ok[0], 1]) * math.cos(math.radians(lat0))
                north = llh[ok, 0] - llh[ok[0], 0]
            kap = leverarm.kappa_from_track_deg(east, north, s.kappa_offset_deg)
            for j, row in enumerate(ok.tolist()):
                if attitude[row] == "none":
                    opk[row] = (0.0, 0.0, kap[j])
                    attitude[row] = "nadir-track"
    return opk, attitude, eo_by_name


def _lever_arm(
    s: SolveSettings, proj: outputs.Projector, epsg: int | str, llh: npt.NDArray[np.float64],
    ant: npt.NDArray[np.float64], opk: npt.NDArray[np.float64], attitude: list[str],
    entries: list[tuple[str, int]], eo_by_name: dict[str, leverarm.ExteriorOrientation],
    notes: list[str],
) -> tuple[npt.NDArray[np.float64], leverarm.LeverArmEstimate | None]:
    """Camera positions from antenna positions (the configured lever arm), and the lever arm
    estimated from EO images when there are some."""
    cam = ant.copy()
    lever_est: leverarm.LeverArmEstimate | None = None
    if not proj.projected:
        notes.append(f"EPSG:{epsg} is not projected: lever arm applied in local east/north/up")
    if s.lever_arm_m is not None:
        use = np.isfinite(cam[:, 0]) & np.isfinite(opk[:, 0])
        if proj.projected:
            cam[use] = leverarm.apply_lever_arm(cam[use], opk[use], s.lever_arm_m)
        else:
            cam[use] = _apply_enu(llh[use], opk[use], s.lever_arm_m)
        notes.append(
            "lever arm (camera frame) " + ", ".join(f"{v:.3f}" for v in s.lever_arm_m) + " m "
            "applied as camera = antenna - M^T L (L from projection centre to antenna)"
        )
    if any(a == "nadir-track" for a in attitude):
        whose = ("no attitude for some photos" if any(a == "eo" for a in attitude)
                 else "no attitude given (--eo)")
        notes.append(
            f"{whose}: nadir camera assumed (omega = phi = 0), kappa from the "
            "direction of travel (image x axis along track)"
            + (f" + {s.kappa_offset_deg:g} deg" if s.kappa_offset_deg else "")
        )
    if eo_by_name:
        sel = [i for i, a in enumerate(attitude) if a == "eo" and np.isfinite(ant[i, 0])]
        if len(sel) >= 2 and proj.projected:
            eos = [eo_by_name.get(entries[i][0]) or eo_by_name[Path(entries[i][0]).stem]
                   for i in sel]
            eo_cam = np.array([(e.x_m, e.y_m, e.z_m) for e in eos])
            lever_est = leverarm.estimate_lever_arm(ant[sel], eo_cam, opk[sel])
            notes.append(
                "lever arm from EO images: "
                + ", ".join(f"{v:.3f}" for v in lever_est.mean_m) + " m, sigma "
                + ", ".join(f"{v:.3f}" for v in lever_est.sigma_m)
                + f" m, {lever_est.inliers} images, {int(lever_est.outlier.sum())} outliers"
            )
    return cam, lever_est


def _cameras(
    s: SolveSettings, marks: tuple[Mark, ...], mp: mi.MarkPositions,
    traj: Trajectory, photo_list: list[exif.Photo],
    match: photos.MatchResult | None, notes: list[str],
    by_clock: camclock.ClockPositions | None = None, numbers: dict[int, int] | None = None,
) -> _Cameras:
    """Stage 5: the rows, in the output CRS, with attitude and the lever arm applied (photos
    without a mark at their camera-clock position, ``by_clock``, named by ``numbers``)."""
    mark_llh = np.full((len(marks), 3), np.nan)
    for i, xyz in enumerate(mp.ecef_m.tolist()):
        if math.isfinite(xyz[0]):
            mark_llh[i] = ecef_to_llh(*xyz)
    traj_llh = np.array([ecef_to_llh(*xyz) for xyz in traj.ecef_m.tolist()])
    epsg = s.epsg or outputs.utm_epsg(float(traj_llh[0, 0]), float(traj_llh[0, 1]))
    proj = outputs.Projector(epsg, s.geoid)
    entries = _row_entries(len(marks), photo_list, match)
    mk = np.array([k for _, k in entries], dtype=np.int64)
    has = mk >= 0
    llh = np.full((len(entries), 3), np.nan)
    llh[has] = mark_llh[mk[has]]
    row_t = np.full(len(entries), np.nan)
    row_t[has] = np.where(mp.t_gps_ns[mk[has]] >= 0, mp.t_gps_ns[mk[has]], np.nan)
    clock_at = by_clock.index() if by_clock is not None else {}
    for i, j in clock_at.items():  # entry i is photo i (photos come first, in order)
        if math.isfinite(by_clock.ecef_m[j, 0]):  # type: ignore[union-attr]
            llh[i] = ecef_to_llh(*by_clock.ecef_m[j].tolist())  # type: ignore[union-attr]
            row_t[i] = by_clock.t_gps_ns[j]  # type: ignore[union-attr]
    ant_x, ant_y = proj.forward(llh[:, 0], llh[:, 1])
    ant_h = llh[:, 2]
    opk, attitude, eo_by_name = _attitude(s, entries, row_t, ant_x, ant_y, proj, llh)
    cam, lever_est = _lever_arm(s, proj, epsg, llh, np.column_stack([ant_x, ant_y, ant_h]),
                                opk, attitude, entries, eo_by_name, notes)
    if proj.projected:
        lat, lon = proj.inverse(cam[:, 0], cam[:, 1])
    else:
        lat, lon = cam[:, 1], cam[:, 0]
    # Heights as the output CRS has them (ellipsoidal, or above its geoid)
    h_out, ant_h_out = proj.heights(lat, lon, cam[:, 2]), proj.heights(llh[:, 0], llh[:, 1], ant_h)
    # Without photos every mark is exported under its name (mark_0031), for pairing by hand.
    names = outputs.mark_names([m.number for m in marks]) if s.photos is None else None
    rows: list[outputs.CameraRow] = []
    numbers = numbers or {}
    for i, (name, k) in enumerate(entries):
        # where the row's instant and position came from: its mark, the camera clock, nothing
        src: tuple[mi.MarkPositions | camclock.ClockPositions, int] | None = (
            (mp, k) if k >= 0 else
            (by_clock, clock_at[i]) if by_clock is not None and i in clock_at else None)
        m = marks[k] if k >= 0 else None
        if src is None:
            t, sd, q, fl, g, c = -1, np.full(3, np.nan), 0, 0, "none", ""
        else:
            pos, j = src
            t, sd, q, fl = (int(pos.t_gps_ns[j]), pos.sd_enu_m[j], int(pos.quality[j]),
                            int(pos.flags[j]))
            g, c = gr.GRADE_NAMES[int(pos.grade[j])], gr.CHECK_NAMES[int(pos.check[j])]
        rows.append(outputs.CameraRow(
            photo=name, mark=k, mark_count=m.number if m else numbers.get(i, -1),
            t_gps_ns=t,
            lat_deg=float(lat[i]), lon_deg=float(lon[i]), h_m=float(h_out[i]),
            x_m=float(cam[i, 0]), y_m=float(cam[i, 1]),
            sd_e_m=float(sd[0]), sd_n_m=float(sd[1]), sd_u_m=float(sd[2]),
            quality=q, flags=fl,
            omega_deg=float(opk[i, 0]), phi_deg=float(opk[i, 1]), kappa_deg=float(opk[i, 2]),
            attitude=attitude[i],
            antenna_x_m=float(ant_x[i]), antenna_y_m=float(ant_y[i]),
            antenna_h_m=float(ant_h_out[i]), ellipsoidal_h_m=float(cam[i, 2]),
            mark_name=names[k] if names is not None and k >= 0 else "",
            grade=g, check=c,
        ))
    return _Cameras(tuple(rows), epsg, proj, traj_llh, mark_llh, cam, lever_est)


def _report(
    s: SolveSettings, traj: Trajectory, marks: tuple[Mark, ...],
    mp: mi.MarkPositions, photo_list: list[exif.Photo], match: photos.MatchResult | None,
    cams: _Cameras, notes: list[str], base_check_made: BaseCheck | None,
    lost: LostMarks, not_counted: int, observed: FlightObservations,
) -> tuple[list[Path], list[str]]:
    """Stage 7: ``report.html`` and ``report.pdf`` (summary, counts, per-mark table, figures,
    warnings); returns the files written and notes on what could not be written."""
    proj, traj_llh = cams.proj, cams.traj_llh
    rows, epsg, lever_est = cams.rows, cams.epsg, cams.lever
    te, tn = proj.forward(traj_llh[:, 0], traj_llh[:, 1])
    engine, version, engine_opts = positions.engine_of(traj, dict(s.rtk_options), s.positions)
    base_check, base_doubtful = base_check_made or check_base(
        s.base, s.base_ecef_m, traj, s.positions, s.base_given)
    if base_doubtful:
        notes.append(f"WARNING base coordinates: {base_check}")
        log.warning("base coordinates doubtful: %s", base_check)
    unmatched = tuple(
        (photo_list[i].name, photo_list[i].error or "no mark within the pairing window")
        for i in match.unmatched_photos
    ) if match else ()
    data = ReportInput(
        flight=s.flight.name, engine_name=engine, engine_version=version,
        engine_options=engine_opts, position_source=f"{traj.source}: {len(traj)} epochs",
        base_name=s.base.name if s.base else None,
        base_ecef_m=s.base_ecef_m or posfile.pos_header(s.positions).ref_ecef_m,
        base_check=base_check, base_doubtful=base_doubtful, base_sd_enu_m=s.base_sd_enu_m,
        base_before=tuple(f"ECEF {x:.4f}, {y:.4f}, {z:.4f} m ({given})"
                          for (x, y, z), given in s.previous_bases),
        epsg=epsg, crs_name=proj.name,
        projected=proj.projected, height_datum=proj.height_datum, lever_arm_m=s.lever_arm_m,
        shutter_delay_ms=s.shutter_delay_ms, edge=s.edge, interp=s.interp, max_gap_s=s.max_gap_s,
        rows=tuple(rows), marks_total=len(marks),
        marks_duplicate=len(match.duplicate_marks) if match else 0,
        track_t_gps_ns=traj.t_gps_ns, track_x_m=te if proj.projected else traj_llh[:, 1],
        track_y_m=tn if proj.projected else traj_llh[:, 0], track_quality=traj.quality,
        photos_total=len(photo_list), photos_unmatched=unmatched,
        photos_given=s.photos is not None, lost_marks=lost,
        photos_not_counted=not_counted,
        orphan_marks=match.orphan_marks if match else (),
        clock_offset_s=match.gps_minus_camera_s if match else None,
        clock_leap_s=match.leap_s if match else 0,
        pairing_warnings=match.warnings if match else (),
        pair_window_s=match.tolerance_s if match else None,
        pair_t_gps_ns=np.array([mp.t_gps_ns[p.mark] for p in match.pairs], dtype=np.int64)
        if match else np.zeros(0, np.int64),
        pair_residual_s=np.array([p.residual_s for p in match.pairs]) if match else np.zeros(0),
        radio_gaps=observed.radio_gaps, source_outages=observed.source_outages,
        station_events=observed.station_events, satellites=observed.satellites,
        lever_residual_m=lever_est.residual_m if lever_est else np.zeros(0),
        lever_outlier=lever_est.outlier if lever_est else np.zeros(0, bool),
        metre_level=traj.metre_level, notes=tuple(notes),
        integrity=(positions.engine_info(traj) or {}).get("integrity"),
        map_origin=_map_origin(s, proj),
        kept_figures=record.kept_figures(s.rebase) if s.rebase is not None else {},
    )
    cond = positions.conditioning_of(traj)
    if cond is not None:  # the receiver's flags plus the slips hidden in radio gaps
        data = replace(data, slips_found=cond[0], slips_repaired=cond[1])
    elif data.satellites is not None:
        data = replace(data, slips_found=int(data.satellites.slip.sum()))
    return report.write_report(data, s.out_dir, pdf=s.report_pdf)


def _map_origin(s: SolveSettings, proj: outputs.Projector) -> tuple[float, float] | None:
    """The base in a projected output CRS, where the report's map is drawn from (None: no
    base, or a geographic CRS, whose map stays in degrees)."""
    if s.base_ecef_m is None or not proj.projected:
        return None
    lat, lon, _ = ecef_to_llh(*s.base_ecef_m)
    x, y = proj.forward(np.array([lat]), np.array([lon]))
    return float(x[0]), float(y[0])


def _apply_enu(
    llh: npt.NDArray[np.float64], opk: npt.NDArray[np.float64], lever: tuple[float, float, float]
) -> npt.NDArray[np.float64]:
    """Lever arm in the local east/north/up frame of each point; returns (lon, lat, h) rows."""
    from groundstation.geodesy import llh_to_ecef

    off = leverarm.lever_offsets(opk, lever)
    out = np.empty_like(llh)
    for i, ((la, lo, h), d) in enumerate(zip(llh.tolist(), off.tolist(), strict=True)):
        rot = np.array(enu_rotation(la, lo))
        xyz = np.array(llh_to_ecef(la, lo, h)) - rot.T @ np.array(d)
        nla, nlo, nh = ecef_to_llh(*xyz)
        out[i] = (nlo, nla, nh)
    return out
