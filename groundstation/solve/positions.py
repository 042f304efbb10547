"""Position sources: an RTKLIB ``.pos`` file, a PPK engine against the base, the receiver's own
fix; and what made a trajectory (the engine's ``engine.json``, an imported file's header).

Every source yields a :class:`~groundstation.solve.trajectory.Trajectory` and is registered by
name in :data:`POSITION_SOURCES`; the pipeline picks one by name.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from groundstation import gpstime, jsonio
from groundstation.errors import ConfigError, GroundstationError, InputError
from groundstation.records import NavSolution
from groundstation.solve.engine import DEFAULT_ENGINE, run_engine
from groundstation.solve.posfile import POS_LAYOUT_NOTE, EmptySolutionError, pos_header, read_pos
from groundstation.solve.trajectory import Q_SINGLE, Trajectory, make_trajectory

log = logging.getLogger("groundstation.solve")


class NoSolutionError(GroundstationError):
    """The engine ran and positioned no epoch (exit status 1: a run that gave no result)."""


# -- the receiver's own fix ---------------------------------------------------------------------


def trajectory_from_nav(solutions: Iterable[NavSolution], source: str = "receiver") -> Trajectory:
    """The receiver's own fixes (NAV-SOL / NAV-PVT / NAV-POSLLH), flagged metre-level (Q 5).

    NAV-POSLLH and NAV-PVT carry no week number; it is taken from the nearest message that does.
    """
    sols = [s for s in solutions if s.ecef_m is not None and s.fix_ok]
    weeks = [s.gps_week for s in sols if s.gps_week is not None]
    if not sols:
        raise InputError(f"{source}: the receiver recorded no valid position of its own")
    if not weeks:
        raise InputError(f"{source}: the receiver's own positions carry no GPS week")
    week = weeks[0]
    t, xyz, sd = [], [], []
    for s in sols:
        if s.gps_week is not None:
            week = s.gps_week
        assert s.ecef_m is not None
        t.append(week * gpstime.NS_PER_WEEK + s.tow_ns)
        xyz.append(s.ecef_m)
        h = s.h_acc_m if s.h_acc_m is not None else s.p_acc_m
        v = s.v_acc_m if s.v_acc_m is not None else s.p_acc_m
        hh = float("nan") if h is None else h / math.sqrt(2)
        sd.append((hh, hh, float("nan") if v is None else v))
    return make_trajectory(
        t, xyz, [Q_SINGLE] * len(t), sd_enu_m=np.array(sd), source=source, metre_level=True,
        notes=("receiver's own fix: metre-level, not a carrier-phase solution",),
    )


Progress = Callable[[str, float], None]


# -- the registry -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SourceOptions:
    """Everything a position source may need; each source reads what it uses."""

    flight: Path | None = None
    positions: Path | None = None
    base: Path | None = None
    base_ecef_m: tuple[float, float, float] | None = None
    work_dir: Path | None = None
    nav_solutions: tuple[NavSolution, ...] = field(default_factory=tuple)
    rtklib_overrides: dict[str, str] = field(default_factory=dict)
    engine: str = DEFAULT_ENGINE
    rtk_conf: Path | None = None


class PositionSource(Protocol):
    """A way of getting the antenna trajectory of a flight."""

    name: ClassVar[str]

    def trajectory(self, opts: SourceOptions, progress: Progress | None = None) -> Trajectory: ...


class PosFileSource:
    """An existing RTKLIB solution file (``--positions``)."""

    name: ClassVar[str] = "pos"

    def trajectory(self, opts: SourceOptions, progress: Progress | None = None) -> Trajectory:
        if opts.positions is None:
            raise ConfigError("--positions", "a .pos file is required")
        return read_pos(opts.positions, opts.base_ecef_m)


class RtklibSource:
    """A PPK engine (``--engine``, default demo5) on the flight and a base (``--base``)."""

    name: ClassVar[str] = "rtklib"

    def trajectory(self, opts: SourceOptions, progress: Progress | None = None) -> Trajectory:
        if opts.flight is None:
            raise ConfigError("FLIGHT", "a rover recording is required")
        if opts.base is None:
            raise ConfigError("--base", "a base recording (.obs or .ubx) is required")
        if opts.base_ecef_m is None:
            raise ConfigError("--base-xyz", "the base's known ECEF coordinates are required")
        work = opts.work_dir or opts.flight.parent / "rtklib"
        run = run_engine(
            opts.engine, opts.flight, opts.base, opts.base_ecef_m, work,
            conf=opts.rtk_conf, overrides=opts.rtklib_overrides, progress=progress,
        )
        ig = run.integrity
        tail = (f"engine {run.engine}: {run.version}", f"solution {run.pos_path}",
                f"{ENGINE_INFO_NOTE}{run.info_path}", *run.notes)
        if ig is not None and ig.t_gps_ns.size:
            return make_trajectory(
                ig.t_gps_ns, ig.ecef_m, ig.quality, sd_enu_m=ig.sd_enu_m(), source=run.engine,
                notes=(POS_LAYOUT_NOTE, *tail), grade=ig.grade, check=ig.check,
            )
        try:
            traj = read_pos(run.pos_path)
        except EmptySolutionError as err:  # said in the user's terms, not the parser's
            raise NoSolutionError(
                f"the {run.engine} engine positioned no epoch of {opts.flight.name} against the "
                f"base {opts.base.name} (its solution {run.pos_path.name} is empty): do rover "
                "and base overlap in time, and is --base-xyz this base's position?") from err
        return Trajectory(
            traj.t_gps_ns, traj.ecef_m, traj.quality, traj.sd_enu_m, traj.ns, traj.ratio,
            run.engine, False, (*traj.notes, *tail),
        )


class ReceiverSource:
    """The receiver's own fix from the recording (metre level; for checks, never for mapping)."""

    name: ClassVar[str] = "receiver"

    def trajectory(self, opts: SourceOptions, progress: Progress | None = None) -> Trajectory:
        return trajectory_from_nav(opts.nav_solutions)


POSITION_SOURCES: dict[str, type[PositionSource]] = {
    PosFileSource.name: PosFileSource,
    RtklibSource.name: RtklibSource,
    ReceiverSource.name: ReceiverSource,
}
"""Position source name -> class."""


def get_source(name: str) -> PositionSource:
    """The position source registered under ``name``."""
    try:
        return POSITION_SOURCES[name]()
    except KeyError as err:
        raise ConfigError(
            "positions.source", f"unknown source {name!r} (known: {', '.join(POSITION_SOURCES)})"
        ) from err


# -- what made a trajectory ----------------------------------------------------------------------


ENGINE_INFO_NOTE = "engine options in "
"""How the engine names its info file (engine, version, full option set) in the notes."""


def engine_info(traj: Trajectory) -> dict[str, Any] | None:
    """The ``engine.json`` of the engine run that made the trajectory, if any."""
    info_path = next((Path(n.removeprefix(ENGINE_INFO_NOTE)) for n in traj.notes
                      if n.startswith(ENGINE_INFO_NOTE)), None)
    if info_path is None:
        return None
    try:
        info = jsonio.loads(info_path.read_bytes())
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) else None


def conditioning_of(traj: Trajectory) -> tuple[int, int, int] | None:
    """(slips found, repaired, flagged) by the phase conditioning before the engine; None when
    it did not run (an imported solution, a RINEX or RXM-RAWX rover)."""
    info = engine_info(traj)
    cond = info.get("conditioning") if info else None
    if not isinstance(cond, dict) or not cond.get("applied"):
        return None
    tot = cond.get("totals") or {}
    found = int(tot.get("receiver_slips", 0)) + int(tot.get("hidden_found", 0))
    return found, int(tot.get("repaired", 0)), int(tot.get("flagged", 0))


def engine_of(
    traj: Trajectory, rtklib_overrides: dict[str, str], positions_file: Path | None
) -> tuple[str, str, dict[str, str]]:
    """Name, version and options of the engine that made the trajectory.

    A solution our engine made carries its ``engine.json`` (engine, version, every option); an
    imported ``.pos`` states its program in its header; ``rtklib_overrides`` is kept for callers
    that imported a solution made with known options.
    """
    info = engine_info(traj)
    if info is not None:
        opts = {str(k): str(v) for k, v in dict(info.get("options") or {}).items()}
        return str(info.get("engine", traj.source)), str(info.get("version", "")), opts
    if traj.metre_level:
        return "receiver's own fix", "", {}
    head = pos_header(positions_file)
    if head.program:
        name, _, version = head.program.partition(" ")
        return name, f"{version} (from the header of {traj.source})".strip(), dict(rtklib_overrides)
    return f"imported solution file ({traj.source})", "", dict(rtklib_overrides)
