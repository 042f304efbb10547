"""The base station: its position in the forms surveyors give it, and whether a base recording
can be this flight's base at all.

Position forms (:func:`base_position`): ECEF (``--base-xyz``), latitude/longitude/ellipsoidal
height (``--base-llh``), either one as the ground mark with the antenna height measured
vertically from the mark to the antenna reference point (``--base-antenna-height``). The result
is the antenna reference point in ECEF metres, the one form the engine takes.

Pairing (:func:`check_pairing`), made before the engine runs (a refusal after minutes of engine
work names the same problem too late):

- the base must observe while the rover flies: a base of another day has no epoch in the
  flight's span;
- the base must be another receiver: two receivers never report the same pseudorange to the
  millimetre (their clocks differ by microseconds, i.e. hundreds of metres, and their
  multipath and noise by decimetres), so equal pseudoranges at shared epochs mean the flight's
  own recording (or a copy of it) was given as its base;
- the base must be near: an L1-only baseline of :data:`BASE_FAR_REFUSED_M` or more gives no
  carrier-phase solution worth the name (the differential ionosphere there is decimetres, several
  times half an L1 wavelength, so ambiguities cannot be fixed, and a float solution is no better
  than code differences).

Given coordinates are checked against the mean of the base receiver's own fixes
(:func:`check_base`): :data:`BASE_DOUBTFUL_M` away is said as doubtful, :data:`BASE_REFUSED_M`
refused before any work.
"""

from __future__ import annotations

import datetime as dt
import gzip
import math
import re
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from groundstation.errors import ConfigError, GroundstationError, InputError
from groundstation.geodesy import ecef_to_llh, enu_rotation, enu_to_ecef, llh_to_ecef
from groundstation.gpstime import gps_calendar_ns, utc_span
from groundstation.offline.rinex.convert import observations_of, read_frames
from groundstation.records import NavSolution
from groundstation.rules.plausible import span_text
from groundstation.solve.antex import antenna_name, l1_offset
from groundstation.solve.engine import is_rinex_obs_name
from groundstation.solve.flight import read_flight
from groundstation.solve.posfile import pos_header
from groundstation.solve.trajectory import Trajectory
from groundstation.storage.reading import detect_format

BASE_FAR_REFUSED_M = 100_000.0
"""A base this far from the flight is refused (module docstring: an L1 baseline that long)."""
SAME_PR_M = 0.001
"""Pseudoranges this close are the same measurement (RINEX keeps 1 mm; two receivers differ by
their clocks, hundreds of metres)."""
SAME_SHARE = 0.9
"""The share of shared (epoch, satellite) pseudoranges that must be equal to call the base the
flight's own recording (a copy damaged in places still qualifies)."""


@dataclass(frozen=True, slots=True)
class ObservationTimes:
    """When a recording observed, and its L1 pseudoranges by (epoch, satellite), for pairing."""

    t_gps_ns: npt.NDArray[np.int64]
    """Epoch times, GPS ns, ascending."""
    pseudoranges: dict[tuple[int, str], float]
    """L1 C/A pseudorange (m) by (epoch GPS ns, ``G05``); empty when the format has none read."""

    @property
    def span(self) -> tuple[int, int] | None:
        if self.t_gps_ns.size == 0:
            return None
        return int(self.t_gps_ns[0]), int(self.t_gps_ns[-1])


BASE_OPTIONS = {"xyz": "--base-xyz", "llh": "--base-llh", "en": "--base-en",
                "crs": "--base-crs", "antenna": "--base-antenna-height",
                "type": "--base-antenna", "antex": "--antex"}
"""The command line's names of the base position's forms."""
BASE_KEYS = {"xyz": "base_xyz", "llh": "base_llh", "en": "base_en", "crs": "base_crs",
             "antenna": "base_antenna_height_m", "type": "base_antenna", "antex": "antex"}
"""The solver configuration's names of the same."""


def base_position(
    xyz: tuple[float, float, float] | None,
    llh: tuple[float, float, float] | None,
    antenna_height_m: float | None = None,
    names: dict[str, str] = BASE_OPTIONS,
    en: tuple[float, float, float] | None = None,
    crs: int | str | None = None,
    antenna: str | None = None,
    antex_file: Path | None = None,
) -> tuple[tuple[float, float, float] | None, str]:
    """The base antenna reference point, ECEF metres, from the form given (None if none), and
    how it was given (for the report).

    Args:
        xyz: ECEF metres (``--base-xyz``).
        llh: latitude and longitude in degrees, ellipsoidal height in metres (``--base-llh``).
        en: easting, northing and height in the projected CRS ``crs`` (``--base-en``,
            ``--base-crs``): an EPSG code, or horizontal+vertical (``2157+5731``, Irish Grid
            + Malin Head heights) for a height above the geoid, converted by PROJ with the
            vertical CRS's geoid grid (refused when the grid is not installed).
        antenna_height_m: when given, ``xyz``/``llh`` is the ground mark and the antenna reference
            point is this far above it along the ellipsoid normal (a vertical tape measure).
        antenna, antex_file: the base antenna's type and an ANTEX file with its calibration:
            the position returned is then the L1 phase centre (:mod:`.antex`).
        names: what the forms are called where they were given (:data:`BASE_OPTIONS`,
            :data:`BASE_KEYS`), for the messages.

    Raises:
        ConfigError: both forms given, a latitude or longitude out of range, an antenna height
            that is not a plausible tripod (negative or over 100 m), or one without a position.
    """
    given = [names[k] for k, v in (("xyz", xyz), ("llh", llh), ("en", en)) if v is not None]
    if len(given) > 1:
        raise ConfigError(given[1], f"give the base as one of {names['xyz']}, {names['llh']} "
                          f"or {names['en']}, not {' and '.join(given)}")
    if (en is None) != (crs is None):
        raise ConfigError(names["en"] if en is None else names["crs"], (
            f"{names['en']} E,N,H and {names['crs']} CODE go together (the CRS the easting, "
            "northing and height are in)"))
    if en is not None and crs is not None:
        llh, crs_how = _from_crs(en, crs, names)
    if llh is not None:
        lat, lon, h = llh
        if not -90.0 <= lat <= 90.0 or not -180.0 <= lon <= 360.0:
            raise ConfigError(names["llh"], (
                f"latitude {lat:g} or longitude {lon:g} out of range: expected LAT,LON,H in "
                "degrees and metres (latitude first)"))
        if abs(h) > 10_000.0:
            raise ConfigError(names["llh"], f"height {h:g} m: expected ellipsoidal metres")
        xyz = llh_to_ecef(lat, lon, h)
    if en is not None:
        how = (f"given with {names['en']} {en[0]:.4f},{en[1]:.4f},{en[2]:.4f} in EPSG:{crs} "
               f"({crs_how}): WGS84 {lat:.9f},{lon:.9f},{h:.4f}")
    elif llh is not None:
        how = f"given with {names['llh']} {lat:.9f},{lon:.9f},{h:.4f}"
    else:
        how = f"given with {names['xyz']}"
    if antenna_height_m is not None:
        if xyz is None:
            raise ConfigError(names["antenna"],
                              f"needs the mark's position ({names['xyz']} or {names['llh']})")
        if not 0.0 <= antenna_height_m <= 100.0:
            raise ConfigError(names["antenna"], (
                f"{antenna_height_m:g} m: expected the vertical height from the ground mark up "
                "to the antenna reference point, metres (0 to 100)"))
        xyz = enu_to_ecef((0.0, 0.0, antenna_height_m), xyz)
        how = (f"{how} for the ground mark, antenna reference point {antenna_height_m:.4f} m "
               f"above it ({names['antenna']})")
    return _phase_centre(xyz, how, antenna, antex_file, names)


PCO_APPLIED = "L1 phase-centre offset of"
"""Words of a base position's description when the antenna's offset was applied; without
them the report says the position given was taken as the phase centre."""


def _phase_centre(
    xyz: tuple[float, float, float] | None, how: str, antenna: str | None,
    antex_file: Path | None, names: dict[str, str],
) -> tuple[tuple[float, float, float] | None, str]:
    """The antenna's L1 phase centre: the reference point plus the ANTEX offset."""
    if antenna is None and antex_file is None:
        return xyz, how
    if xyz is None:
        raise ConfigError(names["antex"] if antex_file else names["type"],
                          "goes with the base's position (the antenna reference point)")
    if antex_file is None:
        raise ConfigError(names["type"], f"goes with {names['antex']} FILE (the ANTEX file "
                          "with that antenna's phase-centre offsets)")
    if antenna is None:
        raise ConfigError(names["antex"], f"needs the base antenna's type: {names['type']} "
                          "TYPE (as the ANTEX file spells it, radome after a space)")
    east, north, up = l1_offset(antex_file, antenna, names["antex"], names["type"])
    kind, radome = antenna_name(antenna)
    return enu_to_ecef((east, north, up), xyz), (
        f"{how}; + the {PCO_APPLIED} {kind} {radome} in {antex_file.name}: north/east/up "
        f"{north * 1e3:.1f}/{east * 1e3:.1f}/{up * 1e3:.1f} mm (its variations with elevation "
        "not applied: millimetres)")


def _from_crs(en: tuple[float, float, float], crs: int | str, names: dict[str, str],
              ) -> tuple[tuple[float, float, float], str]:
    """WGS84 latitude, longitude and ellipsoidal height of a point given in a projected CRS,
    and what its height was (for the report)."""
    from groundstation.solve.outputs import Projector

    try:
        proj = Projector(crs)
        if not proj.projected:
            raise ConfigError("--epsg", (
                f"EPSG:{crs} ({proj.name}) is not a projected CRS: give easting and northing "
                f"in one, or latitude and longitude with {names['llh']}"))
        llh = proj.to_wgs84(*en)
    except ConfigError as err:  # named as the base's option
        msg = err.message.split("; or give --geoid")[0]
        if msg != err.message:
            msg += "; or give an ellipsoidal height with the projected CRS alone"
        raise ConfigError(names["crs"], msg) from err
    return llh, f"{proj.name}; heights: {proj.height_datum}"


def observation_times(path: Path) -> ObservationTimes:
    """The epochs (and L1 pseudoranges) of a base or rover: a u-blox recording or RINEX
    observations (2.x: times only; 3.x: C1C too; ``.gz`` too).

    Raises:
        InputError: unreadable.
    """
    if is_rinex_obs_name(path):
        return _rinex_times(path)
    data, index = read_frames(path)
    _block, obs, _rejected, _times = observations_of(data, index)
    t = obs.t_gps_ns[obs.epoch]
    l1 = (obs.code == "1C") & (obs.pr_m != 0.0)
    prs = {(int(ti), f"{s}{p:02d}"): float(pr) for ti, s, p, pr in zip(
        t[l1].tolist(), obs.sys[l1].tolist(), obs.prn[l1].tolist(), obs.pr_m[l1].tolist(),
        strict=True)}
    return ObservationTimes(np.unique(obs.t_gps_ns).astype(np.int64), prs)


_RINEX2_EPOCH = re.compile(
    r"^ ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d\.\d{7})  ([0-6])")
_RINEX3_EPOCH = re.compile(
    r"^> (\d{4}) (\d\d) (\d\d) (\d\d) (\d\d) ([ \d]\d\.\d{7})  ([0-6])")


def _rinex_times(path: Path) -> ObservationTimes:
    times: list[int] = []
    prs: dict[tuple[int, str], float] = {}
    c1c: dict[str, int] = {}
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    try:
        with opener(path, "rt", encoding="ascii", errors="replace") as f:
            sys_letter, have = "", 0
            for line in f:
                if line[60:].startswith("SYS / # / OBS TYPES"):
                    if line[0] != " ":
                        sys_letter = line[0]
                        c1c[sys_letter] = -1
                        have = 0
                    for k, t in enumerate(line[7:60].split()):
                        if t == "C1C" and sys_letter:
                            c1c[sys_letter] = have + k
                    have = have + len(line[7:60].split())
                if line[60:].startswith("END OF HEADER"):
                    break
            t_now = -1
            for line in f:
                m = _RINEX3_EPOCH.match(line) or _RINEX2_EPOCH.match(line)
                if m is not None:
                    y = int(m.group(1))
                    y = y + (2000 if y < 80 else 1900) if y < 100 else y
                    whole, _, frac = m.group(6).strip().partition(".")
                    mo, d, hh, mi = (int(m.group(i)) for i in (2, 3, 4, 5))
                    when = dt.datetime(y, mo, d, hh, mi, int(whole), tzinfo=dt.UTC)
                    t_now = gps_calendar_ns(when) + int((frac + "000000000")[:9])
                    if m.group(7) in ("0", "1"):
                        times.append(t_now)
                    continue
                j = c1c.get(line[:1], -1)
                if t_now >= 0 and j >= 0 and len(line) >= 3 + 16 * j + 14:
                    field = line[3 + 16 * j: 3 + 16 * j + 14].strip()
                    if field:
                        prs[(t_now, line[:3].replace(" ", "0"))] = float(field)
    except (OSError, EOFError, zlib.error, ValueError) as err:
        raise InputError(f"{path}: cannot read its observation epochs: {err}") from err
    return ObservationTimes(np.unique(np.asarray(times, dtype=np.int64)), prs)


def check_pairing(flight: Path, base: Path, *, key: str = "--base",
                  words: tuple[str, str] = ("flight", "base")) -> str:
    """Refuse a base recording that cannot be this flight's base; else say how they overlap.

    Args:
        flight, base: the rover's and the base's observations.
        key: the option that named the base, for the refusal.
        words: what the two are called in the messages (``locate-base``: the user's base and
            the reference station).

    Returns:
        How much of the flight the base covers (for the base check's text).

    Raises:
        ConfigError: naming ``key``: no epoch of the base falls in the flight's span (both
            spans said), or the base's pseudoranges are the flight's own.
    """
    rover_word, base_word = words
    rover, ref = observation_times(flight), observation_times(base)
    rs, bs = rover.span, ref.span
    if rs is None or bs is None:
        return "" if rs is None else f"the {base_word} {base.name} has no observation epoch"
    if bs[1] < rs[0] or bs[0] > rs[1]:
        gap_ns = rs[0] - bs[1] if bs[1] < rs[0] else bs[0] - rs[1]
        apart = span_text(gap_ns, signed=False)
        raise ConfigError(key, (
            f"{base.name} does not overlap the {rover_word} in time: {rover_word} "
            f"{utc_span(rs)}, {base_word} {utc_span(bs)} ({apart} apart): give the "
            f"{base_word} logged during this {rover_word}"))
    shared = [k for k in rover.pseudoranges if k in ref.pseudoranges]
    if shared:
        same = sum(abs(rover.pseudoranges[k] - ref.pseudoranges[k]) < SAME_PR_M for k in shared)
        if same >= SAME_SHARE * len(shared):
            raise ConfigError(key, (
                f"{base.name} is the {rover_word}'s own recording: its pseudoranges equal the "
                f"{rover_word}'s "
                f"at {same} of {len(shared)} shared satellite epochs (two receivers never agree "
                f"to the millimetre): give the {base_word} station's recording"))
    t = rover.t_gps_ns
    inside = int(np.count_nonzero((t >= bs[0]) & (t <= bs[1])))
    share = inside / t.size
    return "" if share >= 0.999 else (
        f"the {base_word} covers {share:.0%} of the {rover_word}'s epochs ({base_word} "
        f"{utc_span(bs)})")


def check_distance(
    base_ecef_m: tuple[float, float, float],
    flight_fixes_ecef_m: Iterable[tuple[float, float, float]],
) -> float | None:
    """The distance (m) from the base to the middle of the flight's own fixes; None without
    fixes.

    Raises:
        ConfigError: naming ``--base`` when the base is :data:`BASE_FAR_REFUSED_M` or more
            from the flight (its coordinates having been checked against its own fixes).
    """
    fixes = np.asarray(list(flight_fixes_ecef_m), dtype=np.float64)
    if fixes.size == 0:
        return None
    mid = np.median(fixes.reshape(-1, 3), axis=0)
    d = float(np.linalg.norm(mid - np.asarray(base_ecef_m)))
    if d >= BASE_FAR_REFUSED_M:
        lat, lon, h = ecef_to_llh(*base_ecef_m)
        raise ConfigError("--base", (
            f"the base ({lat:.5f}, {lon:.5f}, {h:.0f} m) is {d / 1000:.0f} km from the flight "
            f"(where its receiver's own fixes put it): an L1-only baseline over "
            f"{BASE_FAR_REFUSED_M / 1000:.0f} km cannot be fixed (is it this flight's base?)"))
    return d


OWN_FIX_FLOOR_ENU_M = (2.0, 2.0, 5.0)
"""The least sigma (east, north, up) of a base position averaged from its own stand-alone
fixes. Their scatter shows noise and multipath, not the errors every fix of the session shares:
the broadcast orbits and clocks (about 1 m) and the ionosphere the broadcast model leaves (it
removes about half of a daytime zenith delay of 2-10 m, mostly seen in height). Averaging does
not remove those, so the mean is not better than metres whatever the number of fixes."""


def base_from_own_fixes(
    fixes_ecef_m: Iterable[tuple[float, float, float]],
) -> tuple[tuple[float, float, float], tuple[float, float, float], int]:
    """A base position when none is given: the mean of the base receiver's own fixes, its
    sigma (east, north, up: the fixes' scatter, at least :data:`OWN_FIX_FLOOR_ENU_M`) and the
    number of fixes.

    Raises:
        ConfigError: naming ``--base-xyz``: the base recording has no fix to average.
    """
    fixes = np.asarray(list(fixes_ecef_m), dtype=np.float64).reshape(-1, 3)
    if fixes.shape[0] < 2:
        raise ConfigError("--base-xyz", (
            "the base's coordinates are needed (--base-xyz X,Y,Z or --base-llh LAT,LON,H): its "
            "recording has no receiver fixes to average instead"))
    mean = fixes.mean(axis=0)
    lat, lon, _h = ecef_to_llh(*mean)
    rot = np.asarray(enu_rotation(lat, lon))
    enu = (fixes - mean) @ rot.T
    sd = np.maximum(enu.std(axis=0, ddof=1), OWN_FIX_FLOOR_ENU_M)
    return ((float(mean[0]), float(mean[1]), float(mean[2])),
            (float(sd[0]), float(sd[1]), float(sd[2])), int(fixes.shape[0]))


# -- given coordinates against the base receiver's own fixes ------------------------------------


BASE_DOUBTFUL_M = 30.0
"""The given base coordinates are doubtful when this far from the base receiver's own fixes
(a stand-alone fix is good to a few metres; a wrong base shifts every camera position)."""
BASE_REFUSED_M = 500.0
"""Given base coordinates this far from the base receiver's own fixes are refused before any
work: the mean of a base's stand-alone fixes is good to a few metres (10 m in a bad hour), and
mixing up the height reference (geoid instead of ellipsoid, <= 107 m anywhere) stays far below
it; what lies beyond is another site's or day's coordinates or a typo, and the engine then
positions nothing (5 km: no solution rows) or a result shifted by the same distance. Between
:data:`BASE_DOUBTFUL_M` and this, the solve runs and warns."""


@dataclass(frozen=True, slots=True)
class OwnFixes:
    """The mean of a base receiver's own fixes (None without any) and how many there are."""

    mean_ecef_m: tuple[float, float, float] | None
    count: int


def fix_positions(nav: Iterable[NavSolution]) -> list[tuple[float, float, float]]:
    """The ECEF positions of a receiver's own valid fixes (those with a position)."""
    return [n.ecef_m for n in nav if n.fix_ok and n.ecef_m]


def own_fixes(base: Path) -> OwnFixes | None:
    """The base receiver's own fixes in a u-blox base recording, averaged (None: RINEX or not
    a recording).

    Raises:
        GroundstationError: the recording cannot be read.
    """
    if detect_recording(base) is None:
        return None
    return _mean_of(fix_positions(read_flight(base).nav))


def _mean_of(fixes_ecef_m: Sequence[tuple[float, float, float]]) -> OwnFixes:
    fixes = np.asarray(fixes_ecef_m, dtype=np.float64).reshape(-1, 3)
    if not fixes.size:
        return OwnFixes(None, 0)
    x, y, z = (float(v) for v in fixes.mean(axis=0))
    return OwnFixes((x, y, z), len(fixes))


def check_base(
    base: Path | None,
    base_ecef_m: tuple[float, float, float] | None,
    traj: Trajectory | None,
    positions_file: Path | None,
    how: str = "given with --base-xyz",
    own: OwnFixes | None = None,
) -> tuple[str, bool]:
    """How the base coordinates were checked: (text, doubtful); ``how`` says how they were
    given.

    Given coordinates are compared with the mean of the base receiver's own fixes in a u-blox
    base recording (``own``: as read before, by :func:`own_fixes`; before the engine runs:
    ``traj`` is not needed then); an imported solution's reference position is taken from its
    header.

    Raises:
        ConfigError: naming ``--base-xyz``: far from the base receiver's fixes
            (:func:`compare_base`).
    """
    if base_ecef_m is None:
        if traj is not None and traj.metre_level:
            return "no base (receiver's own fix)", False
        ref = pos_header(positions_file).ref_ecef_m
        if ref is not None:
            return ("reference position from the header of the imported solution; not checked "
                    "against a base recording"), False
        return "unknown (the imported solution does not state its base)", True
    if own is None and base is not None:
        try:
            own = own_fixes(base)
        except GroundstationError as err:
            return f"{how}; not checked ({err})", True
    if base is None or own is None:
        return f"{how}; not checked (no u-blox base recording)", False
    return compare_base(own, base_ecef_m, how)


def detect_recording(path: Path) -> str | None:
    """The recording format of a base file (``mcap``, ``gzip``, ``raw``); None for RINEX."""
    if path.suffix.lower() in (".obs", ".rnx") or re.search(r"\.\d\d[oO]$", path.name):
        return None
    try:
        return detect_format(path)
    except GroundstationError:
        return None


def compare_base(
    base_fixes_ecef_m: Sequence[tuple[float, float, float]] | OwnFixes,
    base_ecef_m: tuple[float, float, float],
    how_given: str,
    fixes_are: str = "the base receiver's own {n} fixes",
) -> tuple[str, bool]:
    """How the base coordinates compare with the base receiver's own fixes: (text, doubtful).
    ``fixes_are`` names the fixes (``{n}``: how many) where they are not the receiver's (the
    live engine's single-point fixes from the base's pseudoranges).

    Raises:
        ConfigError: naming ``--base-xyz``: more than :data:`BASE_REFUSED_M` away.
    """
    if not isinstance(base_fixes_ecef_m, OwnFixes):
        base_fixes_ecef_m = _mean_of(base_fixes_ecef_m)
    count = base_fixes_ecef_m.count
    if base_fixes_ecef_m.mean_ecef_m is None:
        return f"{how_given}; not checked (the base recording has no receiver fix)", False
    mean = np.array(base_fixes_ecef_m.mean_ecef_m)
    d = float(np.linalg.norm(mean - np.asarray(base_ecef_m)))
    given = re.search(r"given with (\S+)", how_given)
    key = given.group(1) if given else "--base-xyz"  # the option (or key) the user gave
    if d > BASE_REFUSED_M:
        hint = {"en": " Easting and northing swapped, or another zone's CRS?",
                "llh": " Latitude and longitude swapped?"}.get(key.rsplit("-", 1)[-1]
                                                              .removeprefix("base_"), "")
        raise ConfigError(key, (
            f"{d / 1000:.2f} km from where {fixes_are.format(n=count)} "
            f"put the base ({mean[0]:.1f},{mean[1]:.1f},{mean[2]:.1f}; stand-alone fixes "
            f"are good to a few metres): not this base's coordinates (another day's or "
            f"site's?).{hint}"))
    text = (f"{how_given}; {d:.1f} m from the mean of "
            f"{fixes_are.format(n=count)} (stand-alone, metre level)")
    lat, lon, h_m = ecef_to_llh(*(float(v) for v in mean))
    e, n, u = np.asarray(enu_rotation(lat, lon)) @ (np.asarray(base_ecef_m) - mean)
    if d > BASE_DOUBTFUL_M:
        # where the fixes put it, to hold against the surveyor's own notes of the point
        text += (f"; they put the base at {lat:.6f}, {lon:.6f}, {h_m:.1f} m (WGS84 latitude, "
                 f"longitude, ellipsoidal height)")
    if d > BASE_DOUBTFUL_M and abs(u) > 10.0 and math.hypot(e, n) < 10.0:
        text += (f"; {u:+.1f} m of the difference in height: a height above the geoid given "
                 "as an ellipsoidal one? (a compound CRS such as --base-crs 32629+5773 takes a "
                 "height above the geoid)")
    return text, d > BASE_DOUBTFUL_M
