"""The solve's notes as a surveyor reads them on the terminal.

The engine writes its notes for engineers (``engine.json`` keeps them, and the report lists them
in its technical sections): "phase conditioning: receiver slips 6, hidden found 0, ...",
"acceleration noise 0.22 / 0.06 m/s^2/sqrt(s) ...", "RTKLIB .pos (xyz, GPST, calendar)". The
printout says the same in plain words, with the same figures, from ``engine.json``'s structured
sections (conditioning, dynamics, combination). Notes this module does not know are printed as
they are.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from groundstation.solve.engine.dynamics import EXCEEDED_S
from groundstation.solve.positions import engine_info
from groundstation.solve.trajectory import Trajectory

ENGINE_NOTE_PREFIXES = ("phase conditioning", "acceleration noise", "combined: ",
                        "integrity stage: epochs")
"""How the engine's notes on its conditioning, dynamics and combination begin
(``solve/engine/__init__.py``); the plain lines below stand for them on the terminal."""
POS_FORMAT_PREFIX = "RTKLIB .pos ("
"""How :func:`groundstation.solve.posfile.read_pos` names the layout of a ``.pos`` file."""

_COORDS = {"xyz": "ECEF X/Y/Z", "llh": "latitude/longitude/height", "enu": "east/north/up"}
_TIME_SYSTEMS = {"GPST": "GPS time", "UTC": "UTC", "JST": "Japan time"}
_TIME_FORMS = {"calendar": "date and time", "tow": "GPS week and seconds"}


def printed_notes(traj: Trajectory, notes: Sequence[str]) -> list[str]:
    """``notes`` for the terminal: the engine's technical notes replaced, where they stood, by
    plain lines with the same figures; every other note as it is."""
    info = engine_info(traj)
    technical = set(info.get("notes") or []) if info else set()
    plain = engine_lines(info) if info else []
    out: list[str] = []
    placed = False
    for note in notes:
        if note in technical and note.startswith(ENGINE_NOTE_PREFIXES):
            if not placed:
                out.extend(plain)
                placed = True
            continue
        out.append(pos_format_line(note) if note.startswith(POS_FORMAT_PREFIX) else note)
    return out


def engine_lines(info: Mapping[str, Any]) -> list[str]:
    """What the engine did, in plain words: carrier-phase checks, motion model, merging."""
    out: list[str] = []
    cond = info.get("conditioning")
    if isinstance(cond, Mapping):
        out.extend(_conditioning(cond))
    dyn = info.get("dynamics")
    if isinstance(dyn, Mapping):
        out.append(_dynamics(dyn))
    comb = info.get("combination")
    if isinstance(comb, Mapping):
        out.append(_combination(comb))
    integ = info.get("integrity")
    if isinstance(integ, Mapping):
        out.append(_integrity(integ))
    return out


def _integrity(ig: Mapping[str, Any]) -> str:
    arcs = ig.get("arcs") or {}
    fac = ig.get("float_sigma_factor") or {}
    grades = ", ".join(f"{k} {v}" for k, v in dict(ig.get("grades") or {}).items())
    return (f"every fix checked without trusting the engine's ratio test: epochs {grades}; "
            f"our own whole-arc phase solution fixed {arcs.get('epochs_fixed_precise', 0)} "
            f"epochs ({arcs.get('fixed_combinations', 0)} of "
            f"{arcs.get('integer_combinations', 0)} ambiguity combinations sure); float sigmas "
            f"x{fac.get('horizontal')} horizontal, x{fac.get('vertical')} vertical "
            f"(from {fac.get('from')})")


def _conditioning(cond: Mapping[str, Any]) -> list[str]:
    if not cond.get("applied"):
        return [f"carrier phase not repaired before solving: {cond.get('note') or 'not applied'}"]
    t = {k: int(v) for k, v in dict(cond.get("totals") or {}).items()}
    line = (f"carrier phase checked before solving: {t.get('receiver_slips', 0)} cycle slips "
            f"marked by the receiver, {t.get('hidden_found', 0)} more found where the phase was "
            "missing (radio gaps, blank epochs); "
            f"{t.get('repaired', 0)} phase jumps repaired, {t.get('half_resolved', 0)} "
            f"half-cycle ambiguities resolved, {t.get('flagged', 0)} breaks not bridged (the "
            "engine restarts those satellites)")
    if t.get("kept_by_doppler"):
        line += f", {t['kept_by_doppler']} gaps bridged on the Doppler alone"
    out = [line]
    per_sat = []
    for name, s in sorted(dict(cond.get("satellites") or {}).items()):
        parts = [f"{s.get(k, 0)} {what}" for k, what in
                 (("repaired", "repaired"), ("hidden_found", "found in gaps"),
                  ("flagged", "not bridged")) if s.get(k, 0)]
        if parts:
            per_sat.append(f"{name} {', '.join(parts)}")
    if per_sat:
        out.append("by satellite: " + "; ".join(per_sat))
    return out


def _dynamics(dyn: Mapping[str, Any]) -> str:
    used = dict(dyn.get("used") or {})
    setting = " / ".join(str(v) for v in used.values())
    measured = dyn.get("measured")
    if isinstance(measured, Mapping):
        user = list(dyn.get("user") or [])
        return (f"motion model set from how the rover moved: it sustained "
                f"{measured['accel_h_m_s2']:.2f} m/s^2 horizontally and "
                f"{measured['accel_v_m_s2']:.2f} m/s^2 vertically for {EXCEEDED_S:g} s (peaks "
                f"{measured['peak_h_m_s2']:.2f} / {measured['peak_v_m_s2']:.2f}) over "
                f"{measured['seconds']:.0f} s ({measured['coverage']:.0%}) of fixed positions; "
                f"engine setting {setting} horizontal / vertical"
                + (f" (yours kept for {', '.join(user)})" if user else ""))
    if dyn.get("user"):
        return f"motion model: your own engine setting {setting} horizontal / vertical"
    return (f"motion model: the engine's default setting {setting} horizontal / vertical (the "
            "rover's motion could not be measured)")


def _combination(comb: Mapping[str, Any]) -> str:
    downgraded = int(comb.get("demo5_rejected", 0)) + int(comb.get("chi2_rejected", 0))
    return (f"forward and backward solutions merged: {comb.get('both_fixed', 0)} epochs fixed "
            f"in both directions, {downgraded} fixes set to float where the two disagreed")


def pos_format_line(note: str) -> str:
    """``RTKLIB .pos (xyz, GPST, calendar)`` as "solution file in RTKLIB format (ECEF X/Y/Z,
    GPS time, date and time)"; a note it cannot read is returned as it is."""
    body = note.removeprefix(POS_FORMAT_PREFIX).removesuffix(")")
    parts = [p.strip() for p in body.split(",")]
    if len(parts) != 3:
        return note
    coords, system, form = parts
    words = (_COORDS.get(coords, coords), _TIME_SYSTEMS.get(system, system),
             _TIME_FORMS.get(form, form))
    return f"solution file in RTKLIB format ({', '.join(words)})"
