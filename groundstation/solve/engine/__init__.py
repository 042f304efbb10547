"""PPK engines: RTKLIB demo5 in a worker process (default) and Debian's ``rnx2rtkp`` (b34).

Engines are registered by name in :data:`ENGINES`. :func:`run_engine` is the one entry point:
it converts recordings to RINEX, resolves the options (engine defaults < ``--rtk-conf`` <
``--base-xyz`` < ``--rtk-opt``, each checked against the engine's own option table), runs the
engine and writes, next to the ``.pos``, ``engine.json`` with the engine's name, version and
full option set; the same goes into the ``.pos`` header. Between conversion and the solve, the
"dynamics" stage (:func:`derive_dynamics`) sets the filter's acceleration noise from a
forward-only pass when the user has not set it. A combined solution of an engine that allows it
is made of separate forward and backward runs merged here (:func:`solve`, rule in
:mod:`.combine`).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from groundstation import jsonio
from groundstation.errors import ConfigError, GroundstationError
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.solve.engine import options as eo
from groundstation.solve.engine.demo5 import Demo5Engine
from groundstation.solve.engine.protocol import Engine, EngineError, EngineJob, EngineRun, Progress
from groundstation.solve.engine.rnx2rtkp import Rnx2rtkpEngine

log = logging.getLogger("groundstation.solve")

DEFAULT_ENGINE = "demo5"


if TYPE_CHECKING:
    from groundstation.offline.rinex.convert import ObsHook as rinex_hook
    from groundstation.offline.rinex.observations import ObsSet
    from groundstation.solve.conditioning import ConditioningReport
    from groundstation.solve.integrity.assess import Arcs, EngineSolution, IntegrityResult


ENGINES: dict[str, type[Engine]] = {Demo5Engine.name: Demo5Engine,
                                    Rnx2rtkpEngine.name: Rnx2rtkpEngine}
"""Engine name -> class."""


def get_engine(name: str) -> Engine:
    """The engine registered under ``name``.

    Raises:
        ConfigError: unknown name (named ``--engine``).
    """
    try:
        return ENGINES[name]()
    except KeyError as err:
        known = ", ".join(ENGINES)
        raise ConfigError("--engine", f"unknown engine {name!r} (known: {known})") from err


def resolve_options(
    engine: Engine,
    base_ecef_m: tuple[float, float, float] | None,
    conf: Path | None = None,
    overrides: Mapping[str, str] | None = None,
) -> tuple[dict[str, str], list[str]]:
    """Engine defaults < ``conf`` < base position < ``overrides``, checked; plus notes.

    The output keys our reader needs (:data:`options.OUTPUT_OPTIONS`) are set last; a user value
    they replace is named in the notes.

    Raises:
        ConfigError: unknown key or bad value (named), unreadable conf file.
        ToolMissingError: the engine is not installed.
    """
    table = engine.option_table()
    opts = dict(engine.defaults)
    notes: list[str] = []
    user: dict[str, str] = {}
    if conf is not None:
        user.update(eo.read_conf(conf, table))
    if base_ecef_m is not None:
        user.update(eo.base_position_options(base_ecef_m))
    if overrides:
        user.update(eo.check_options(table, overrides, "--rtk-opt"))
    opts.update(user)
    for key, value in eo.OUTPUT_OPTIONS.items():
        if key in user and not _same(table, key, user[key], value):
            notes.append(f"option {key}={user[key]} replaced by {value} (our reader needs it)")
        opts[key] = value
    return eo.check_options(table, opts, f"{engine.name} option"), notes


def _same(table: eo.OptionTable, key: str, a: str, b: str) -> bool:
    """Whether two values of ``key`` mean the same (an enumeration by name or by number)."""
    spec = table.get(key)
    choices = spec.choices() if spec is not None else {}

    def norm(v: str) -> str:
        v = v.strip()
        return str(choices[v]) if v in choices else v

    return norm(a) == norm(b)


def is_rinex_obs_name(path: Path) -> bool:
    """Whether a base (or rover) file is taken as RINEX observations (by its name: ``.obs``,
    ``.rnx``, ``.YYo``, optionally ``.gz``) rather than a recording to convert."""
    return re.search(r"\.(obs|rnx|\d\do)(\.gz)?$", path.name.lower()) is not None


def _to_rinex(
    path: Path, work: Path, progress: Progress | None, hook: rinex_hook | None = None,
) -> tuple[Path, list[Path]]:
    """(obs, [nav]) for a RINEX observation file or a recording converted by our RINEX writer
    (``hook`` changes the observations before they are written)."""
    if is_rinex_obs_name(path):
        navs = [
            p for p in path.parent.glob(path.name.split(".")[0] + "*")
            if re.search(r"\.(nav|\d\d[ngpl])(\.gz)?$", p.name.lower())
        ]
        return path, sorted(navs)
    from groundstation.offline import rinex  # the RINEX writer, imported only when converting

    def prog(stage: str, frac: float) -> None:
        if progress is not None:
            progress(f"rinex {path.name}: {stage}", frac)

    # No event epochs: RTKLIB's RINEX reader (rinex.c, readrnxobs) reads the epoch after an
    # event and drops it when its spacing from the epoch before differs from the spacing
    # before that, then takes the next; after a radio gap every epoch that follows a mark can
    # go that way, one in two on a 1 Hz flight with a photo every 2 s. The engine's positions
    # at the marks are not used (the marks are interpolated from its trajectory).
    res = rinex.convert(path, work, rinex.RinexOptions(version="3.04", events=False), prog,
                        hook)
    return res.obs_path, [res.nav_path] if res.ephemerides or res.other_ephemerides else []


ACCEL_KEYS = ("stats-prnaccelh", "stats-prnaccelv")
"""The filter's acceleration process noise, horizontal / vertical (:mod:`.dynamics`)."""


def derive_dynamics(
    engine: Engine, job: EngineJob, user_keys: set[str], progress: Progress | None = None,
    fixed: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]
    | None = None,
) -> tuple[dict[str, str], dict[str, object] | None, list[str]]:
    """The "dynamics" stage: the acceleration noise from how the rover moved.

    A forward-only pass of the same engine with the same options gives the rover's fixed
    positions; :func:`dynamics.observed_dynamics` measures the accelerations there and
    :func:`dynamics.process_noise` turns them into ``stats-prnaccelh`` / ``stats-prnaccelv``.
    A value the user gave (``--rtk-conf`` or ``--rtk-opt``) always wins. Given ``fixed``
    (times, positions and which are fixed, of the integrity stage's own whole-arc solution,
    which runs before the engine), the dynamics are measured there and the forward pass is
    not run, unless those fixes cover too little of the flight. Nothing is done for an
    engine whose defaults do not set these keys (b34), for a non-kinematic mode or with the
    dynamics model off (the keys are unused then), or when the user set both.

    Returns:
        (the options to solve with, what was measured and chosen or None, notes).
    """
    from groundstation.solve.engine import dynamics as dy
    from groundstation.solve.posfile import read_pos
    from groundstation.solve.trajectory import Q_FIX

    opts = dict(job.options)
    if (
        not all(k in engine.defaults for k in ACCEL_KEYS)
        or opts.get("pos1-posmode") != "kinematic" or opts.get("pos1-dynamics") != "on"
    ):
        return opts, None, []
    if all(k in user_keys for k in ACCEL_KEYS):
        used = {k: opts[k] for k in ACCEL_KEYS}
        return opts, {"measured": None, "used": used, "user": list(ACCEL_KEYS)}, [
            "acceleration noise: the user's values (not derived)"]
    t0 = time.perf_counter()
    if fixed is not None:
        mine = dy.observed_dynamics(*fixed)
        if mine is not None and mine.coverage >= dy.MIN_COVERAGE:
            return _dynamics_options(engine, opts, user_keys, mine, None, time.perf_counter() - t0,
                                     "our whole-arc solution's fixed epochs")
    if progress is not None:
        progress("dynamics (forward pass)", 0.0)
    first = EngineJob(
        job.rover_obs, job.base_obs, job.nav, {**opts, "pos1-soltype": "forward"},
        job.work_dir / "dynamics", job.timeout_s,
    )
    first.work_dir.mkdir(parents=True, exist_ok=True)
    try:
        traj = read_pos(engine.run(first).pos_path)
    except GroundstationError as err:  # the main solve may still work: keep the constant
        log.warning("dynamics pass failed: %s", err)
        traj = None
    dyn = (dy.observed_dynamics(traj.t_gps_ns, traj.ecef_m, traj.quality == Q_FIX)
           if traj is not None else None)
    wall = time.perf_counter() - t0
    if progress is not None:
        progress("dynamics (forward pass)", 1.0)
    if traj is None or dyn is None:
        why = ("the forward pass failed" if traj is None
               else "the forward pass fixed too few epochs to measure the dynamics")
        note = (f"acceleration noise: the default {opts[ACCEL_KEYS[0]]} / {opts[ACCEL_KEYS[1]]} "
                f"m/s^2 ({why})")
        return opts, {"measured": None, "used": {k: opts[k] for k in ACCEL_KEYS}}, [note]
    return _dynamics_options(engine, opts, user_keys, dyn,
                             (int(np.sum(traj.quality == Q_FIX)), len(traj)), wall,
                             "a forward pass's fixed epochs")


def _dynamics_options(
    engine: Engine, opts: dict[str, str], user_keys: set[str], dyn: Any,
    pass_counts: tuple[int, int] | None, wall: float, where: str,
) -> tuple[dict[str, str], dict[str, object], list[str]]:
    """The options with the acceleration noise of the measured dynamics ``dyn``
    (:class:`.dynamics.Dynamics`), what was done and a note."""
    from groundstation.solve.engine import dynamics as dy

    opts = dict(opts)
    constant = (float(engine.defaults[ACCEL_KEYS[0]]), float(engine.defaults[ACCEL_KEYS[1]]))
    derived = dict(zip(ACCEL_KEYS, (f"{q:g}" for q in dy.process_noise(dyn, constant)),
                       strict=True))
    for key, value in derived.items():
        if key not in user_keys:
            opts[key] = value
    used = {k: opts[k] for k in ACCEL_KEYS}
    kept = sorted(k for k in ACCEL_KEYS if k in user_keys)
    info: dict[str, object] = {
        "measured": dyn.as_dict(), "derived": derived, "used": used, "user": kept,
        "formula": dy.FORMULA, "measured_on": where,
    }
    if pass_counts is not None:
        info.update({"pass_fixed": pass_counts[0], "pass_epochs": pass_counts[1],
                     "pass_wall_s": round(wall, 3)})
    note = (
        f"acceleration noise {used[ACCEL_KEYS[0]]} / {used[ACCEL_KEYS[1]]} m/s^2/sqrt(s) "
        f"(horizontal / vertical) from the rover's observed dynamics: "
        f"{dyn.accel_h_m_s2:.3f} / {dyn.accel_v_m_s2:.3f} m/s^2 sustained for "
        f"{dy.EXCEEDED_S:g} s (peaks {dyn.peak_h_m_s2:.2f} / {dyn.peak_v_m_s2:.2f}) over "
        f"{dyn.seconds:.0f} s ({dyn.coverage:.0%}) of {where}"
        + (f", too little to go below the constant {constant[0]:g} / {constant[1]:g}"
           if dyn.coverage < dy.MIN_COVERAGE else "")
        + ("; the user's values kept for " + ", ".join(kept) if kept else "")
    )
    return opts, info, [note]


def solve(
    engine: Engine, job: EngineJob, progress: Progress | None = None,
) -> tuple[EngineRun, dict[str, object] | None, list[str]]:
    """Run the engine; a kinematic "combined" solution of an engine that
    :attr:`~Engine.combines_in_house` is its forward and backward runs (in parallel, one worker
    each) merged by :func:`.combine.combine_files`.

    The engine's own combination is used for other modes, for output with velocities (a layout
    the merge does not write) and, with a note, when a run's output cannot be read.

    Returns:
        (the run, what the merge did or None, notes).
    """
    opts = job.options
    if not (
        engine.combines_in_house and opts.get("pos1-soltype") == "combined"
        and opts.get("pos1-posmode") == "kinematic" and opts.get("out-outvel", "off") == "off"
    ):
        return engine.run(job, progress), None, []
    from groundstation.solve.engine import combine as cb

    jobs = [
        EngineJob(job.rover_obs, job.base_obs, job.nav, {**opts, "pos1-soltype": way},
                  job.work_dir / way, job.timeout_s)
        for way in ("forward", "backward")
    ]
    for j in jobs:
        j.work_dir.mkdir(parents=True, exist_ok=True)
    # Two worker processes at once: the two directions are independent, and each is one core.
    with ThreadPoolExecutor(max_workers=2) as pool:
        fwd, bwd = pool.map(engine.run, jobs)
    out = job.work_dir / "rover.pos"
    try:
        stats = cb.combine_files(fwd.pos_path, bwd.pos_path, out)
    except ValueError as err:
        log.warning("cannot merge forward and backward (%s): the engine's own combination", err)
        return engine.run(job, progress), None, [
            f"combined by the engine itself (forward and backward could not be merged: {err})"]
    options = {**fwd.options, "pos1-soltype": "combined"}
    run = EngineRun(engine.name, fwd.version, out, job.work_dir / "engine.json", options, 0.0,
                    fwd.notes)
    note = (
        f"combined: the forward and backward runs merged by groundstation ({cb.RULE}): "
        f"{stats.both_fixed} epochs fixed in both, {stats.demo5_rejected} made float by demo5's "
        f"per-axis test and {stats.chi2_rejected} more by the full-covariance test"
    )
    return run, stats.as_dict(), [note]


def run_engine(
    engine_name: str,
    rover: Path,
    base: Path,
    base_ecef_m: tuple[float, float, float] | None,
    work_dir: Path,
    *,
    conf: Path | None = None,
    overrides: Mapping[str, str] | None = None,
    progress: Progress | None = None,
    timeout_s: float = 3600.0,
    condition: bool = True,
    dynamics: bool = True,
    integrity: bool = True,
    extra_nav: Sequence[Path] = (),
) -> EngineRun:
    """Convert rover and base to RINEX if needed, run the engine, record how.

    Navigation: what the recordings carry, RINEX navigation files beside RINEX observations
    (same first name part), and ``extra_nav``.

    With ``condition`` the rover's carrier phase is conditioned on the way to RINEX
    (:mod:`groundstation.solve.conditioning`: hidden slips found, slips repaired or flagged,
    half cycles resolved); what it did goes into ``engine.json`` and the run's notes. With
    ``dynamics`` the acceleration noise comes from the rover's observed motion
    (:func:`derive_dynamics`) unless the user set it.

    Raises:
        ConfigError: unknown engine, option key or value.
        ToolMissingError: the engine is not installed.
        EngineError: the engine failed or wrote no solution.
    """
    engine = get_engine(engine_name)
    opts, notes = resolve_options(engine, base_ecef_m, conf, overrides)
    work_dir.mkdir(parents=True, exist_ok=True)
    from groundstation.solve import conditioning

    cond_report: conditioning.ConditioningReport | None = None
    seen: dict[str, tuple[ObsSet, Sequence[BroadcastEphemeris]]] = {}

    def hook(obs: ObsSet, ephs: Sequence[BroadcastEphemeris],
             approx: tuple[float, float, float]) -> ObsSet:
        nonlocal cond_report
        out = obs
        if condition:
            out, cond_report = conditioning.condition(obs, ephs, approx)
        seen["rover"] = (out, ephs)
        return out

    def base_hook(obs: ObsSet, ephs: Sequence[BroadcastEphemeris],
                  approx: tuple[float, float, float]) -> ObsSet:
        seen["base"] = (obs, ephs)
        return obs

    rover_obs, rover_nav = _to_rinex(rover, work_dir / "rover", progress, hook)
    base_obs, base_nav = _to_rinex(base, work_dir / "base", progress, base_hook)
    nav = tuple(rover_nav + base_nav + list(extra_nav))
    if not nav:
        raise EngineError("no navigation data (ephemerides) in the rover or base recording")
    job = EngineJob(rover_obs, base_obs, nav, opts, work_dir, timeout_s)
    arcs: Arcs | None = None
    arcs_note = ""
    if integrity and base_ecef_m is not None:
        arcs, arcs_note = _arcs(seen, base_ecef_m, progress, cond_report)
    dyn_info: dict[str, object] | None = None
    if dynamics:
        user_keys = set(overrides or {})
        if conf is not None:
            user_keys |= set(eo.read_conf(conf, engine.option_table()))
        opts, dyn_info, dyn_notes = derive_dynamics(
            engine, job, user_keys, progress,
            arcs.fixed_trajectory() if arcs is not None else None)
        notes.extend(dyn_notes)
        job = EngineJob(rover_obs, base_obs, nav, opts, work_dir, timeout_s)
    t0 = time.perf_counter()
    if progress is not None:
        progress(engine.name, 0.0)
    run, comb_info, comb_notes = solve(engine, job, progress)
    notes.extend(comb_notes)
    wall = time.perf_counter() - t0
    if progress is not None:
        progress(engine.name, 1.0)
    integ: IntegrityResult | None = None
    if integrity and base_ecef_m is not None:
        integ, integ_note = _integrity(arcs, arcs_note, run.pos_path, job.work_dir)
        notes.append(integ_note)
    cond = cond_report.as_dict() if cond_report is not None else None
    if cond_report is not None:
        tot = cond_report.totals()
        notes.append(
            "phase conditioning: "
            + (", ".join(f"{k.replace('_', ' ')} {v}" for k, v in tot.items())
               if cond_report.applied else cond_report.note)
        )
        per_sat = [
            f"{name} {s.hidden_found}/{s.repaired}/{s.flagged}"
            for name, s in sorted(cond_report.satellites.items())
            if s.hidden_found or s.repaired or s.flagged
        ]
        if per_sat:
            notes.append("phase conditioning per satellite (hidden found/repaired/flagged): "
                         + ", ".join(per_sat))
    elif condition:
        notes.append("phase conditioning: not applied (rover given as RINEX)")
    info = {
        "engine": run.engine,
        "version": run.version,
        "inputs": [str(p) for p in (rover_obs, base_obs, *nav)],
        "pos": str(run.pos_path),
        "wall_s": round(wall, 3),
        "options": run.options,
        "notes": [*notes, *run.notes],
        "conditioning": cond,
        "dynamics": dyn_info,
        "combination": comb_info,
        "integrity": integ.summary if integ is not None else None,
    }
    run.info_path.write_bytes(jsonio.dumps(info, indent=1) + b"\n")
    _stamp_header(run.pos_path, run.engine, run.version, run.options)
    return EngineRun(
        run.engine, run.version, run.pos_path, run.info_path, run.options, wall,
        (*notes, *run.notes), cond, dyn_info, comb_info, integ,
    )


def engine_solution(pos: Path) -> EngineSolution | None:
    """An engine's ``.pos`` (xyz layout) as the integrity stage's columns; None when it is in
    another layout or missing."""
    from groundstation.solve.engine.combine import parse_solutions
    from groundstation.solve.integrity.assess import EngineSolution

    if not pos.is_file():
        return None
    try:
        _, sols = parse_solutions(pos.read_text(encoding="ascii", errors="replace"))
    except ValueError:
        return None
    t = np.round(sols.t_s * 1e9).astype(np.int64)
    return EngineSolution(t, sols.xyz, sols.q, sols.cov)


def _arcs(
    seen: Mapping[str, tuple[ObsSet, Sequence[BroadcastEphemeris]]],
    base_ecef_m: tuple[float, float, float], progress: Progress | None,
    cond: ConditioningReport | None = None,
) -> tuple[Arcs | None, str]:
    """The integrity stage's whole-arc solution, from the observations alone (before the
    engine); None and why when it cannot run (an input given as RINEX). ``cond``: what the
    conditioning did (the phases it carried on its own decisions, which the whole-arc solution
    tests)."""
    from groundstation.solve.integrity.assess import arcs_stage

    if "rover" not in seen or "base" not in seen:
        return None, "the rover or base was given as RINEX: no raw observations to check with"
    if progress is not None:
        progress("integrity: whole-arc solution", 0.0)
    rover_obs, rover_ephs = seen["rover"]
    base_obs, base_ephs = seen["base"]
    have = set(rover_ephs)
    ephs = list(rover_ephs) + [e for e in base_ephs if e not in have]
    arcs = arcs_stage(rover_obs, base_obs, ephs, base_ecef_m,
                      None if cond is None else cond.decisions)
    if progress is not None:
        progress("integrity: whole-arc solution", 1.0)
    return arcs, "" if arcs is not None else "no rover epochs"


def _integrity(arcs: Arcs | None, why_not: str, pos: Path, work_dir: Path,
               ) -> tuple[IntegrityResult | None, str]:
    """The graded trajectory (:mod:`groundstation.solve.integrity`) from our whole-arc
    solution and the engine's solutions, written to ``integrity.pos`` beside the engine's
    ``.pos``, and a note saying what it did (or why it could not run)."""
    from groundstation.solve.integrity.assess import grade_stage
    from groundstation.solve.integrity.pos import write_pos

    merged = engine_solution(pos)
    if merged is not None and merged.t_gps_ns.size == 0:
        return None, "integrity stage: not run (the engine positioned no epoch)"
    if arcs is None or merged is None:
        why = why_not if merged is not None else (
            "the engine's solution is not in RTKLIB's xyz layout")
        return None, f"integrity stage: not run ({why}); fixes are graded fixed-unchecked"
    fwd = engine_solution(work_dir / "forward" / "rover.pos")
    bwd = engine_solution(work_dir / "backward" / "rover.pos")
    result = grade_stage(arcs, merged, fwd, bwd)
    write_pos(work_dir / "integrity.pos", result)
    counts = result.summary["grades"]
    assert isinstance(counts, dict)
    grades = ", ".join(f"{k} {v}" for k, v in counts.items())
    return result, f"integrity stage: epochs {grades} (rule and checks in engine.json)"


def _stamp_header(pos: Path, engine: str, version: str, opts: Mapping[str, str]) -> None:
    """Put the engine and its full option set at the top of the ``.pos`` as ``%`` lines."""
    head = [f"% engine    : {engine} {version}"]
    head += [f"% option    : {k}={v}" for k, v in opts.items()]
    text = pos.read_text(encoding="ascii", errors="replace")
    pos.write_text("\n".join(head) + "\n" + text, encoding="ascii", errors="replace")


__all__ = [
    "ACCEL_KEYS",
    "DEFAULT_ENGINE",
    "ENGINES",
    "derive_dynamics",
    "get_engine",
    "resolve_options",
    "run_engine",
    "solve",
]
