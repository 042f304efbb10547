"""A solve's record, and re-basing a finished result without solving again.

Every solve that used a base position leaves beside its exports ``solve.json`` (the settings it
ran with, the recordings by absolute path, the base position and how it was given, the mean of
the base receiver's own fixes), ``trajectory.npz`` (the antenna trajectory after the integrity
stage: positions, sigmas, qualities, grades), ``marks.npz`` (the antenna interpolated at the
marks and at photos timed by the camera clock) and ``flight.npz`` (what was read from the flight
recording: marks, epochs, damage, satellites, station events). ``solve --rebase DIR`` with new
base coordinates takes them, moves the trajectory and the interpolated positions by the base's
move and runs the rest of the chain as a solve does (photos, lever arm, exports, report) without
the engine, without reading the recordings again and without drawing again the report's figures
whose inputs are as they were (``report.figures_in``: taken from the result's page; the map,
drawn from the base, moves rigidly with it).
A result without ``marks.npz`` or ``flight.npz`` (made before they were kept) is interpolated
and read again: the same result, slower.

Why a shift is enough: the engine positions the rover relative to the base (double
differences), so moving the base by d moves every rover position by d. What does not move
alike is second order: the directions to the satellites change by the baseline over the range
(1 km / 20 000 km: 0.05 mm per metre moved) and the tropospheric delay modelled at the base
changes with its height (about 0.3 mm in the zenith per metre, more at low elevation). On the
2018-10-09 flight, a base moved by 1.2 m (0.96 m of it in height) and solved again gave fixed
camera positions within 2.7 mm of the shifted ones (median 0.4 mm): what the report says. A
move whose first-order error (the move times the longest baseline over the range, 20 000 km)
could exceed 2 mm is refused: solve again. The engine's own files (``rtklib/``) are kept as
they were, relative to the base the engine used.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable, Sequence
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation import jsonio
from groundstation.errors import ConfigError, InputError
from groundstation.geodesy import ecef_to_llh, enu_rotation
from groundstation.solve import flight as fl
from groundstation.solve import interpolate as mi
from groundstation.solve import trajectory as tr
from groundstation.solve.engine import is_rinex_obs_name
from groundstation.solve.report import HTML_NAME, figures_in
from groundstation.solve.settings import SolveSettings

log = logging.getLogger("groundstation.solve")

RECORD_NAME = "solve.json"
TRAJECTORY_NAME = "trajectory.npz"
MARKS_NAME = "marks.npz"
"""The antenna at every mark (and photo timed by the camera clock), as interpolated (a re-base
moves them as the trajectory)."""
FLIGHT_NAME = "flight.npz"
"""What the solve took from the flight recording (marks, epochs, observations): a re-base
takes it instead of reading the recording again."""
ENGINE_DIR = "rtklib"
"""The engine's files (solution, options, conditioning): carried over into a re-based result."""
FORMAT = "groundstation solve record 1"
SATELLITE_RANGE_MIN_M = 2.0e7
"""The shortest range to a GPS satellite (overhead, about 20 200 km)."""
REBASE_MAX_ERROR_M = 0.002
"""A re-base whose geometric error could exceed this is refused (solve again)."""
_HERE = "{result}/"
"""Stands for the result's folder in the recorded trajectory's notes."""

_PATHS = ("flight", "out_dir", "positions", "base", "photos", "eo", "geoid", "rtk_conf",
          "rebase", "antex")
_TRIPLES = ("base_ecef_m", "base_sd_enu_m", "lever_arm_m", "base_fix_mean_m")
_NOT_RECORDED = ("flight_copies", "recordings", "rebase", "previous_bases")


def write(s: SolveSettings, traj: tr.Trajectory, made: Interpolations,
          flight: fl.FlightRecords | None, out_dir: Path, final_dir: Path) -> None:
    """Write the run's record into ``out_dir`` (the staging folder of ``final_dir``): the
    settings, the trajectory, the positions interpolated from it and what was taken from the
    flight."""
    settings: dict[str, Any] = {}
    for f in fields(SolveSettings):
        if f.name in _NOT_RECORDED:
            continue
        v = getattr(s, f.name)
        settings[f.name] = (str(v.resolve()) if isinstance(v, Path) else
                            [list(p) for p in v] if f.name == "rtk_options" else
                            list(v) if isinstance(v, tuple) else v)
    settings["out_dir"] = str(final_dir.resolve())
    recordings = s.recordings or (s.flight, *s.flight_copies)
    doc = {
        "format": FORMAT,
        "recordings": [str(p.resolve()) for p in recordings],
        "settings": settings,
        "previous_bases": [{"ecef_m": list(xyz), "given": given}
                           for xyz, given in s.previous_bases],
    }
    (out_dir / RECORD_NAME).write_bytes(jsonio.dumps(doc, indent=1))
    # the notes name the engine's files by where the result is: kept by a placeholder, so
    # that a result moved elsewhere is still re-based whole
    notes = tuple(n.replace(f"{out_dir}/", _HERE) for n in traj.notes)
    tr.save_npz(replace(traj, notes=notes), out_dir / TRAJECTORY_NAME)
    mi.save_npz(made.made, out_dir / MARKS_NAME)
    if flight is not None:
        fl.save_npz(flight, out_dir / FLIGHT_NAME)


BasePosition = tuple[tuple[float, float, float], str, tuple[float, float, float] | None]
"""A base position: ECEF, how it was given, its sigma east/north/up (None: exact)."""


def rebase_settings(
    result: Path, out_dir: Path, position: Callable[[SolveSettings], BasePosition],
) -> SolveSettings:
    """The settings of the solve that made ``result``, with the new base position, writing to
    ``out_dir`` (``result`` itself to re-base in place). ``position`` gives the new base
    position from the old settings (the antenna's height and offsets as solved, unless given
    again).

    Raises:
        ConfigError: naming ``--rebase``: not a finished result with a record, a result made
            without a base position, or a recording it was made from that is gone.
    """
    doc = _read(result)
    try:
        raw = dict(doc["settings"])
        recordings = [Path(p) for p in doc["recordings"]]
        previous = [(_triple(b["ecef_m"]), str(b["given"])) for b in doc["previous_bases"]]
        kwargs: dict[str, Any] = {}
        for f in fields(SolveSettings):
            if f.name not in raw:
                continue
            v = raw[f.name]
            kwargs[f.name] = (Path(v) if f.name in _PATHS and v is not None else
                              _triple(v) if f.name in _TRIPLES and v is not None else
                              tuple((str(k), str(x)) for k, x in v) if f.name == "rtk_options"
                              else _count(v) if f.name == "base_fix_count" else v)
        old = SolveSettings(**kwargs)
    except (KeyError, TypeError, ValueError) as err:
        raise ConfigError("--rebase", f"{result / RECORD_NAME}: not a record this program "
                          f"wrote ({err})") from err
    if old.base_ecef_m is None or old.base is None:
        raise ConfigError("--rebase", f"{result} was solved without a base position (an "
                          "imported solution or the receiver's own fixes): there is no base to "
                          "move")
    if not (result / TRAJECTORY_NAME).is_file():
        raise ConfigError("--rebase", f"{result}: {TRAJECTORY_NAME} is missing (the record "
                          "is incomplete: solve again)")
    # What the record keeps need not be read again: the recordings (flight.npz) and the base
    # recording (the mean of its fixes in solve.json). Photos, EO file and geoid grid are.
    kept = (result / FLIGHT_NAME).is_file()
    base_kept = old.base_fix_count >= 0 or is_rinex_obs_name(old.base)  # (RINEX: no fixes)
    needed = [*(() if kept else recordings), None if kept and base_kept else old.base,
              old.photos, old.eo, old.geoid]
    for p in needed:
        if p is not None and not p.exists():
            why = ("" if p not in (*recordings, old.base) else
                   f" ({result / FLIGHT_NAME}, which would stand for the recordings, is missing: "
                   "a result made before it was kept, or removed)" if not kept else
                   f" ({RECORD_NAME} keeps no mean of its receiver's fixes: a result made "
                   "before it was kept)")
            raise ConfigError("--rebase", f"{p}: no longer there; the result was made from "
                              f"it, and the marks, photos and report are drawn from it again"
                              f"{why}: put it back where it was")
    base_ecef_m, base_given, base_sd_enu_m = position(old)
    return replace(
        old, flight=recordings[0], flight_copies=tuple(recordings[1:]) if not kept else (),
        recordings=tuple(recordings) if kept else (), out_dir=out_dir,
        base_ecef_m=base_ecef_m, base_given=base_given, base_sd_enu_m=base_sd_enu_m,
        base_estimated=False, rebase=result,
        previous_bases=(*previous, (old.base_ecef_m, _short(old.base_given))))


def _short(given: str) -> str:
    """How a base was given, for the record of earlier bases (a base that was the mean of its
    receiver's own fixes in a few words, not the whole warning)."""
    if given.startswith("not given"):
        return "the mean of the base receiver's own fixes, known to metres"
    return given


def _read(result: Path) -> dict[str, Any]:
    """``result``'s record.

    Raises:
        ConfigError: naming ``--rebase``: no such directory, no record in it, or a record
            that is not ours.
    """
    if not result.is_dir():
        raise ConfigError("--rebase", f"{result}: " + (
            "not a directory" if result.exists() else "no such directory"))
    path = result / RECORD_NAME
    try:
        doc = jsonio.loads(path.read_bytes())
    except FileNotFoundError as err:
        raise ConfigError("--rebase", f"{result}: no {RECORD_NAME} in it (not a result of "
                          "groundstation solve, or one made before it kept a record)") from err
    except (OSError, ValueError) as err:
        raise ConfigError("--rebase", f"{path}: cannot read it ({err})") from err
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ConfigError("--rebase", f"{path}: not a record this program wrote")
    return doc


def _count(v: Any) -> int:
    if not isinstance(v, int) or isinstance(v, bool):
        raise TypeError(f"base_fix_count {v!r}")
    return v


def _triple(v: Sequence[Any]) -> tuple[float, float, float]:
    a, b, c = (float(x) for x in v)
    return a, b, c


def carry_engine_files(result: Path, stage: Path) -> None:
    """Copy the engine's files of ``result`` into the new run's staging folder (the report
    reads their options and conditioning; they stay relative to the base the engine used)."""
    src = result / ENGINE_DIR
    if src.is_dir():
        shutil.copytree(src, stage / ENGINE_DIR, symlinks=True)


def _move(s: SolveSettings) -> npt.NDArray[np.float64]:
    """The base's move from the result's base to the new one (ECEF, m)."""
    assert s.base_ecef_m is not None and s.previous_bases
    return np.asarray(np.array(s.base_ecef_m) - np.array(s.previous_bases[-1][0]),
                      dtype=np.float64)


class Interpolations:
    """Positions interpolated from the trajectory (at the marks, at photos timed by the camera
    clock), each kept for the run's record; for a re-base, those the finished result kept are
    taken again moved by the base's move (interpolation is linear in the positions: the moved
    trajectory gives the moved positions), not computed again."""

    def __init__(self, kept: Sequence[mi.MarkPositions] = (),
                 move: npt.NDArray[np.float64] | None = None) -> None:
        self._kept = list(kept)
        self._move = np.zeros(3) if move is None else move
        self.made: list[mi.MarkPositions] = []

    @classmethod
    def of(cls, s: SolveSettings) -> Interpolations:
        """A solve's (nothing kept), or a re-base's (what its result kept, if anything: kept
        positions that cannot be read are said in a warning and interpolated again)."""
        if s.rebase is None or not (s.rebase / MARKS_NAME).is_file():
            return cls()
        try:
            return cls(mi.load_npz(s.rebase / MARKS_NAME), _move(s))
        except InputError as err:
            log.warning("%s: interpolated again instead", err)
            return cls()

    def __call__(self, traj: tr.Trajectory, times: Sequence[int | None], method: str,
                 max_gap_s: float) -> mi.MarkPositions:
        want = np.array([-1 if t is None else t for t in times], dtype=np.int64)
        for mp in self._kept:
            if mp.method == method and np.array_equal(
                    np.where(mp.t_gps_ns >= 0, mp.t_gps_ns, -1), want):
                out = replace(mp, ecef_m=mp.ecef_m + self._move)
                break
        else:
            out = mi.interpolate(traj, times, method, max_gap_s)
        self.made.append(out)
        return out


def flight_records(result: Path) -> fl.FlightRecords | None:
    """What ``result``'s solve took from the flight recording (None when it kept nothing, or
    what it kept cannot be read, said in a warning: read the recording again)."""
    path = result / FLIGHT_NAME
    if not path.is_file():
        return None
    try:
        return fl.load_npz(path)
    except InputError as err:
        log.warning("%s: the recording is read again instead", err)
        return None


def kept_figures(result: Path) -> dict[str, str]:
    """The figures of ``result``'s report a re-base keeps as they are (none when the report
    is gone or of another layout: they are drawn again)."""
    try:
        return figures_in((result / HTML_NAME).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError):
        return {}


def shifted_trajectory(s: SolveSettings, stage: Path) -> tuple[tr.Trajectory, str]:
    """The re-based result's trajectory moved by the base's move, its notes naming the new
    staging folder; and a note saying what moved.

    Raises:
        InputError: the trajectory cannot be read.
    """
    assert s.rebase is not None and s.base_ecef_m is not None and s.previous_bases
    traj = tr.load_npz(s.rebase / TRAJECTORY_NAME)
    old_xyz, old_given = s.previous_bases[-1]
    move = _move(s)
    lat, lon, _ = ecef_to_llh(*old_xyz)
    east, north, up = (round(v, 4) + 0.0 for v in (np.array(enu_rotation(lat, lon)) @ move))
    notes = tuple(t.replace(_HERE, f"{stage}/") for t in traj.notes)
    # The shift is exact but for the directions to the satellites, which move by the base's
    # move over their range: at most |move| x baseline / range on the baseline.
    baseline = float(np.max(np.linalg.norm(traj.ecef_m - np.array(old_xyz), axis=1)))
    bound = float(np.linalg.norm(move)) * baseline / SATELLITE_RANGE_MIN_M
    if bound > REBASE_MAX_ERROR_M:
        raise ConfigError("--rebase", (
            f"the base moves {float(np.linalg.norm(move)):.1f} m with baselines up to "
            f"{baseline / 1000:.2f} km: moving the result would be off by up to "
            f"{bound * 1000:.0f} mm; solve again with the new base instead"))
    moved = replace(traj, ecef_m=traj.ecef_m + move, notes=notes)
    text = (f"re-based without solving again (solve --rebase): the base moved by east {east:+.4f}, "
            f"north {north:+.4f}, up {up:+.4f} m ({float(np.linalg.norm(move)):.4f} m) from ECEF "
            f"{old_xyz[0]:.4f}, {old_xyz[1]:.4f}, {old_xyz[2]:.4f} ({old_given}); every "
            "position moved with it (what the base's height changes in the modelled "
            "troposphere is left out: millimetres per metre moved); the engine's files in "
            f"{ENGINE_DIR}/ are relative to the base it ran with, ECEF "
            + ", ".join(f"{v:.4f}" for v in s.previous_bases[0][0]))
    return moved, text

