"""The base station's position from a static baseline to a reference station (``locate-base``).

The user's base (a u-blox recording or RINEX) is solved as a static receiver against a reference
station's RINEX (2.x, 3.x, 4.x; Hatanaka ``.crx``/``.YYd`` and ``.gz``/``.Z`` through the
``hatanaka`` package) by the same engine as the flights, in RTKLIB's static mode, forward: its
last epoch is the estimate from every epoch. Navigation comes from the base's recording or from
RINEX navigation files beside either input.

The sigma is the engine's formal one, but never less than what an L1 static baseline of that
length is good to (:data:`STATIC_FLOOR`): the formal sigma of a long static session shrinks with
the number of epochs as if their errors were independent, while multipath, the residual
troposphere and the differential ionosphere are correlated over tens of minutes and grow with
the baseline. A solution whose last epoch is not fixed carries unresolved ambiguities (biases of
a fraction of the 19 cm L1 wavelength on each satellite): its sigma is at least
:data:`FLOAT_FLOOR_M` on every axis, and it is said.
"""

from __future__ import annotations

import math
import re
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from groundstation import jsonio
from groundstation.errors import ConfigError, InputError
from groundstation.geodesy import ecef_to_llh
from groundstation.gpstime import utc_span
from groundstation.solve import csrs
from groundstation.solve.base import BASE_FAR_REFUSED_M, check_pairing
from groundstation.solve.engine import is_rinex_obs_name

Progress = Callable[[str, float], None]

STATIC_FLOOR = ((0.005, 1e-6), (0.010, 2e-6))
"""The least sigma of a fixed L1 static baseline, (constant m, per metre of baseline),
horizontal then vertical: 5 mm + 1 ppm and 10 mm + 2 ppm, the accuracy surveying receivers
are specified to for L1 static work."""
FLOAT_FLOOR_M = 0.19
"""The least sigma, every axis, of a solution whose ambiguities are not fixed: one L1
wavelength."""
HATANAKA = re.compile(r"\.(crx|\d\dd)(\.(gz|z|bz2|zip))?$", re.IGNORECASE)
COMPRESSED = re.compile(r"\.(gz|z|bz2|zip)$", re.IGNORECASE)
RINEX_NAV = re.compile(r"(\.(nav|\d\d[ngpl])|_[a-z]n\.rnx)(\.(gz|z|bz2|zip))?$", re.IGNORECASE)
_OPTIONS = {"pos1-posmode": "static", "pos1-soltype": "forward"}
"""The engine run: static, forward (its last epoch uses every epoch)."""


@dataclass(frozen=True, slots=True)
class BaseLocation:
    """A located base: what ``locate-base`` prints and ``solve --base-position`` reads."""

    ecef_m: tuple[float, float, float]
    sigma_enu_m: tuple[float, float, float]
    formal_sd_enu_m: tuple[float, float, float]
    fixed: bool
    fixed_share: float
    epochs: int
    span_gps_ns: tuple[int, int]
    baseline_m: float
    base: str
    reference: str
    reference_ecef_m: tuple[float, float, float]
    reference_from: str
    engine: str

    @property
    def llh(self) -> tuple[float, float, float]:
        return ecef_to_llh(*self.ecef_m)

    def as_json(self) -> dict[str, object]:
        lat, lon, h = self.llh
        return {
            "kind": "groundstation base position",
            "ecef_m": [round(v, 4) for v in self.ecef_m],
            "sigma_enu_m": [round(v, 4) for v in self.sigma_enu_m],
            "llh": [round(lat, 10), round(lon, 10), round(h, 4)],
            "formal_sd_enu_m": [round(v, 4) for v in self.formal_sd_enu_m],
            "fixed": self.fixed,
            "fixed_share": round(self.fixed_share, 4),
            "epochs": self.epochs,
            "span_utc": utc_span(self.span_gps_ns),
            "baseline_m": round(self.baseline_m, 3),
            "base": self.base,
            "reference": self.reference,
            "reference_ecef_m": [round(v, 4) for v in self.reference_ecef_m],
            "reference_from": self.reference_from,
            "engine": self.engine,
        }

    def text(self) -> str:
        lat, lon, h = self.llh
        e, n, u = self.sigma_enu_m
        fe, fn, fu = self.formal_sd_enu_m
        t0, t1 = self.span_gps_ns
        state = ("fixed" if self.fixed else
                 "FLOAT (ambiguities not fixed: decimetres; a longer session or a nearer "
                 "reference station helps)")
        return "\n".join([
            (f"base position  ECEF {self.ecef_m[0]:.4f}, {self.ecef_m[1]:.4f}, "
            f"{self.ecef_m[2]:.4f} m"),
            (f"               lat {lat:.9f}, lon {lon:.9f}, h {h:.4f} m (WGS84 ellipsoidal, "
            "antenna reference point)"),
            (f"sigma          east {e:.3f} m, north {n:.3f} m, up {u:.3f} m (formal "
            f"{fe:.3f}/{fn:.3f}/{fu:.3f}; {self._floor_text()})"),
            (f"baseline       {self.baseline_m / 1000:.3f} km to {self.reference} (its position "
            f"{self.reference_from})"),
            (f"solution       {state}; {self.fixed_share:.0%} of {self.epochs} epochs fixed; "
            f"{utc_span((t0, t1))} ({(t1 - t0) / 6e10:.1f} min)"),
        ]) + "\n"

    def _floor_text(self) -> str:
        if not self.fixed:
            return f"at least {FLOAT_FLOOR_M:.2f} m unfixed"
        (hc, hp), (vc, vp) = STATIC_FLOOR
        return (f"at least {hc * 1000:.0f} mm + {hp * 1e6:.0f} ppm horizontal, "
                f"{vc * 1000:.0f} mm + {vp * 1e6:.0f} ppm vertical for an L1 static baseline")


def honest_sigma(
    formal_enu_m: tuple[float, float, float], baseline_m: float, fixed: bool,
) -> tuple[float, float, float]:
    """The sigma to state: the formal one, at least the floor for the baseline
    (module docstring)."""
    if not fixed:
        floor = (FLOAT_FLOOR_M,) * 3
    else:
        (hc, hp), (vc, vp) = STATIC_FLOOR
        h, v = hc + hp * baseline_m, vc + vp * baseline_m
        floor = (h, h, v)
    e, n, u = (max(f, fl) if math.isfinite(f) else fl
               for f, fl in zip(formal_enu_m, floor, strict=True))
    return e, n, u


def header_position(path: Path) -> tuple[float, float, float] | None:
    """``APPROX POSITION XYZ`` from a RINEX observation header (None when absent or zero)."""
    for line in _text(path).splitlines():
        label = line[60:].strip()
        if label == "APPROX POSITION XYZ":
            try:
                x, y, z = (float(v) for v in line[:60].split()[:3])
            except ValueError:
                return None
            return (x, y, z) if math.hypot(x, y, z) > 6.0e6 else None
        if label == "END OF HEADER":
            break
    return None


def _text(path: Path) -> str:
    """A RINEX file's text, decompressed (Hatanaka and/or gzip, compress, bzip2, zip)."""
    import hatanaka

    try:
        if HATANAKA.search(path.name) or COMPRESSED.search(path.name):
            data = bytes(hatanaka.decompress(path))
        else:
            data = path.read_bytes()
    except (OSError, ValueError, hatanaka.HatanakaException) as err:
        raise InputError(f"{path}: cannot read it as RINEX: {err}") from err
    return data.decode("ascii", errors="replace")


def plain_rinex(path: Path, work: Path, prefix: str) -> Path:
    """A RINEX file copied into ``work``, decompressed, under a name the engine's file rules
    recognise (observations ``.obs``, navigation ``.nav``) and that starts with ``prefix``
    (the engine looks for navigation files beside observations by their first name part)."""
    kind = ".nav" if RINEX_NAV.search(path.name) else ".obs"
    out = work / f"{prefix}_{re.sub(r'[^A-Za-z0-9]', '_', path.name)}{kind}"
    out.write_text(_text(path), encoding="ascii")
    return out


def navigation_beside(path: Path) -> list[Path]:
    """RINEX navigation files next to an observation file, of the same station and day
    (``0759092{0}.05n``, ``..._MN.rnx.gz``)."""
    station = path.name[:4].lower()
    return sorted(p for p in path.parent.iterdir()
                  if p.is_file() and p.name[:4].lower() == station and RINEX_NAV.search(p.name))


def locate_base(
    base: Path, reference: Path, reference_xyz: tuple[float, float, float] | None, *,
    engine: str = "demo5", progress: Progress | None = None,
) -> BaseLocation:
    """Solve the base against the reference station (module docstring).

    Raises:
        ConfigError: naming ``--reference-xyz`` (no position given and none in the header) or
            ``--reference`` (no time overlap with the base, or further than
            :data:`~groundstation.solve.base.BASE_FAR_REFUSED_M`).
        InputError: an unreadable input.
        groundstation.solve.engine.protocol.EngineError: the engine positioned nothing.
    """
    from groundstation.solve.engine import run_engine
    from groundstation.solve.engine.protocol import EngineError
    from groundstation.solve.posfile import read_pos

    with tempfile.TemporaryDirectory(prefix="locate-base-") as tmp:
        work = Path(tmp)
        # the reference (and a RINEX base) decompressed into the work folder once, with the
        # navigation files beside them; a recording is converted by the engine's own step
        ref_obs = plain_rinex(reference, work, "reference")
        base_obs = base
        if is_rinex_obs_name(base) or HATANAKA.search(base.name):
            base_obs = plain_rinex(base, work, "base")
        for given, plain in ((reference, ref_obs), (base, base_obs)):
            if plain.parent == work and "RINEX VERSION / TYPE" not in _text(plain)[:400]:
                raise InputError(f"{given}: not RINEX observations (no RINEX VERSION / TYPE "
                                 "header line)")
        ref_xyz, ref_from = _reference_position(reference, ref_obs, reference_xyz)
        navs = [plain_rinex(n, work, "nav") for n in navigation_beside(reference)]
        if base_obs != base:
            navs += [plain_rinex(n, work, "nav") for n in navigation_beside(base)]
        check_pairing(base_obs, ref_obs, key="--reference", words=("base", "reference"))
        run = run_engine(
            engine, base_obs, ref_obs, ref_xyz, work / "engine", overrides=_OPTIONS,
            progress=progress, dynamics=False, integrity=False, extra_nav=tuple(navs))
        try:
            traj = read_pos(run.pos_path)
        except InputError as err:
            raise EngineError(f"the {engine} engine positioned no epoch of {base.name} against "
                              f"{reference.name}: {err}") from err
    if len(traj) == 0:
        raise EngineError(f"the {engine} engine positioned no epoch of {base.name}")
    xyz = tuple(float(v) for v in traj.ecef_m[-1])
    formal = tuple(float(v) for v in traj.sd_enu_m[-1])
    baseline = float(np.linalg.norm(np.asarray(xyz) - np.asarray(ref_xyz)))
    if baseline >= BASE_FAR_REFUSED_M:
        raise ConfigError("--reference", (
            f"{reference.name} is {baseline / 1000:.0f} km from the base: an L1 baseline over "
            f"{BASE_FAR_REFUSED_M / 1000:.0f} km cannot be fixed (choose a nearer station)"))
    fixed = int(traj.quality[-1]) == 1
    x, y, z = xyz
    fe, fn, fu = formal
    return BaseLocation(
        ecef_m=(x, y, z), sigma_enu_m=honest_sigma((fe, fn, fu), baseline, fixed),
        formal_sd_enu_m=(fe, fn, fu), fixed=fixed,
        fixed_share=float(np.mean(traj.quality == 1)), epochs=len(traj),
        span_gps_ns=(int(traj.t_gps_ns[0]), int(traj.t_gps_ns[-1])), baseline_m=baseline,
        base=base.name, reference=reference.name, reference_ecef_m=ref_xyz,
        reference_from=ref_from, engine=f"{run.engine} {run.version}")


def _reference_position(
    reference: Path, plain: Path, given: tuple[float, float, float] | None,
) -> tuple[tuple[float, float, float], str]:
    """The reference station's position and where it came from: given, or its header's.

    Raises:
        ConfigError: naming ``--reference-xyz``: none given and none in the header.
    """
    if given is not None:
        return given, "given with --reference-xyz"
    head = header_position(plain)
    if head is None:
        raise ConfigError("--reference-xyz", (
            f"{reference.name} gives no position in its header (APPROX POSITION XYZ): give the "
            "reference station's coordinates, ECEF metres, from its network's page"))
    return head, ("from the APPROX POSITION XYZ of its RINEX header: check it against the "
                  "network's published coordinates, which --reference-xyz takes")


def read_base_position(path: Path) -> tuple[tuple[float, float, float],
                                              tuple[float, float, float] | None, str]:
    """A base position file: ``locate-base --out``'s JSON, or an NRCan CSRS-PPP summary
    (:mod:`.csrs`). Returns (ECEF, sigma east/north/up or None, how it was given).

    Raises:
        ConfigError: naming ``--base-position``: not such a file.
    """
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ConfigError("--base-position", f"{path}: cannot read: {err}") from err
    if path.name.lower().endswith(".sum") or csrs.looks_like_sum(data[:65536]):
        return csrs.read_sum(path, data.decode("latin-1"))
    try:
        doc = jsonio.loads(data)
    except ValueError as err:
        raise ConfigError("--base-position", (
            f"{path}: not a base position file (JSON from groundstation locate-base --out, or "
            f"a CSRS-PPP .sum): {err}")) from err
    try:
        xyz = tuple(float(v) for v in doc["ecef_m"])
        sd_raw = doc.get("sigma_enu_m")
        sd = tuple(float(v) for v in sd_raw) if sd_raw is not None else None
    except (TypeError, KeyError, ValueError, AttributeError) as err:
        raise ConfigError("--base-position", (
            f"{path}: no ecef_m [x, y, z] in it (expected groundstation locate-base --out's "
            "JSON)")) from err
    if len(xyz) != 3 or (sd is not None and len(sd) != 3) or not all(
            math.isfinite(v) for v in (*xyz, *(sd or ()))):
        raise ConfigError("--base-position", f"{path}: ecef_m and sigma_enu_m need 3 numbers")
    if not 6.3e6 < math.hypot(*xyz) < 6.4e6:
        raise ConfigError("--base-position", f"{path}: ecef_m is not on the Earth's surface")
    x, y, z = xyz
    sigma = (sd[0], sd[1], sd[2]) if sd is not None else None
    how = f"from {path.name}" + (
        f" (located against {doc.get('reference')}, baseline "
        f"{float(doc.get('baseline_m', 0)) / 1000:.2f} km)" if doc.get("reference") else "")
    return (x, y, z), sigma, how
