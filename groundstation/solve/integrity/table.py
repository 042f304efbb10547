"""Between-receiver GPS L1 phase and code of a rover against its base, ready for residuals.

What this module owns: one table of the rover's epochs x GPS satellites holding the rover's
carrier phase minus the base's (the base epoch nearest in time, its geometry taken out at the
base's own known position), the matching code, a noise figure per measurement and an **arc**
per measurement: a stretch over which both receivers kept lock, so that the between-receiver
ambiguity is one constant. :meth:`PhaseTable.residuals` takes out the rover's geometry at any
trajectory; what is left of a right trajectory is one constant per arc plus one per epoch (the
two receivers' clocks), plus noise.

It is computed from our own observations, orbits and models, not by the PPK engine: it is the
ground truth the integrity stage holds the engine's positions against.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation.gnss.atmosphere import saastamoinen_delay_m
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.geometry import SatGeometry, elevation_deg
from groundstation.gnss.noise import CODE_SIGMA_45_M, PHASE_SIGMA_45_CYC, cno_scale
from groundstation.gnss.orbit import L1_WAVELENGTH_M
from groundstation.offline.rinex.observations import ObsSet
from groundstation.rules.phase import LLI_HALF_CYCLE, LLI_SLIP

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

MAX_BASE_AGE_S = 30.0
"""A rover epoch is differenced with a base epoch at most this far in time (RTKLIB's maxage)."""
ARC_GAP_S = 30.0
"""A satellite missing from a receiver's epochs for longer than this starts a new arc even
without a loss-of-lock flag (no receiver reports carrier lock it has not been reporting)."""
ELEVATION_MASK_DEG = 15.0
"""Measurements below this elevation are not used (the engine's own mask)."""


@dataclass(frozen=True, slots=True)
class _Grid:
    """One receiver's GPS L1 observations as epochs x satellites (NaN: none)."""

    t_ns: IntArray
    phase: FloatArray
    code: FloatArray
    cno: FloatArray
    lli: IntArray


def _grid(obs: ObsSet, svs: Sequence[int]) -> _Grid:
    col = {sv: j for j, sv in enumerate(svs)}
    order = np.argsort(obs.t_gps_ns, kind="stable")
    rank = np.empty(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size)
    n_ep, n_sv = obs.t_gps_ns.size, len(svs)
    rows = np.flatnonzero((obs.sys == "G") & (obs.code == "1C")
                          & np.isin(obs.prn, np.asarray(svs, dtype=np.int64)))
    ep = rank[obs.epoch[rows]]
    sj = np.array([col[int(p)] for p in obs.prn[rows].tolist()], dtype=np.int64)
    phase = np.full((n_ep, n_sv), np.nan)
    code = np.full((n_ep, n_sv), np.nan)
    cno = np.full((n_ep, n_sv), np.nan)
    lli = np.zeros((n_ep, n_sv), dtype=np.int64)
    cp, pr = obs.cp_cyc[rows], obs.pr_m[rows]
    phase[ep, sj] = np.where(cp != 0.0, cp, np.nan)
    code[ep, sj] = np.where(pr != 0.0, pr, np.nan)
    cno[ep, sj] = obs.cno_dbhz[rows]
    lli[ep, sj] = obs.lli[rows]
    return _Grid(obs.t_gps_ns[order], phase, code, cno, lli)


def _arc_counter(t_ns: IntArray, phase: FloatArray, lli: IntArray) -> IntArray:
    """Per (epoch, satellite) of one receiver: how many times lock started again before it
    (a loss-of-lock flag, a first appearance, or an absence longer than :data:`ARC_GAP_S`)."""
    n_ep, n_sv = phase.shape
    out = np.zeros((n_ep, n_sv), dtype=np.int64)
    t_s = (t_ns - t_ns[0]) / 1e9 if t_ns.size else np.zeros(0)
    for j in range(n_sv):
        rows = np.flatnonzero(~np.isnan(phase[:, j]))
        if rows.size == 0:
            continue
        start = np.zeros(rows.size, dtype=bool)
        start[0] = True
        start[1:] = (np.diff(t_s[rows]) > ARC_GAP_S) | ((lli[rows[1:], j] & LLI_SLIP) != 0)
        out[rows, j] = np.cumsum(start)
    return out


@dataclass(frozen=True, slots=True)
class PhaseTable:
    """The rover's between-receiver phase per epoch and GPS satellite (see the module doc).

    Attributes:
        t_ns: rover epoch times (GPS ns, increasing).
        svs: GPS satellite numbers of the columns.
        sd_cyc: rover phase minus base phase minus the base's geometry [cycles]; NaN where a
            measurement is missing, flagged half-cycle, below the mask or without an orbit.
        sd_code_m: the same for the pseudoranges [m].
        sigma_cyc: the phase difference's noise [cycles].
        sigma_code_m: the code difference's noise [m].
        arc: arc number per measurement (-1 where ``sd_cyc`` is NaN).
        n_arcs: number of arcs.
        arc_sv: the satellite column of each arc.
        base_age_s: rover minus base epoch time per rover epoch (NaN: no base epoch near).
        geo: the rover's satellite geometry (for :meth:`residuals`).
        lattice_cyc: the spacing of the values an arc's constant can take relative to another's:
            1 cycle, or half a cycle when either receiver sends RXM-RAW (a squaring loop's
            half-cycle ambiguity is resolved by the receiver or the conditioning, and a wrong
            resolution leaves a whole arc half a cycle off).
        arc_whole: on a half-cycle table, the arcs two of which differ by whole cycles: the
            receivers resolve a squaring loop's half cycle from the navigation data, and
            where a phase rests on a decision of ours, that decision passed a test that would
            have seen it half a cycle wrong (``integrity.steps.unverified``); a piece split
            off an arc is not one. None: every arc on ``lattice_cyc``.
        decided: (n_ep, n_sv) the rover phases the conditioning carried on a decision of its
            own (a repair, a continuity across a loss or a gap, a half cycle put back).
        put_back: (n_ep, n_sv) those where it put a half cycle back on the lock's phases
            before them (a wrong one moved the phases before the step, not after).
    """

    t_ns: IntArray
    svs: tuple[int, ...]
    sd_cyc: FloatArray
    sd_code_m: FloatArray
    sigma_cyc: FloatArray
    sigma_code_m: FloatArray
    arc: IntArray
    n_arcs: int
    arc_sv: IntArray
    base_age_s: FloatArray
    geo: SatGeometry
    lattice_cyc: float = 1.0
    arc_whole: BoolArray | None = None
    decided: BoolArray | None = None
    put_back: BoolArray | None = None

    @property
    def n_epochs(self) -> int:
        return int(self.t_ns.size)

    def geometry(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The rover's range minus satellite clock plus troposphere [m] and lines of sight at
        positions ``x`` (n_ep, 3)."""
        rho, los = self.geo.ranges_all(x)
        return rho + _troposphere_m(x, los), los

    def residuals(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Phase residuals [cycles] of trajectory ``x`` (n_ep, 3) and the lines of sight:
        arc constant + epoch constant + noise where ``x`` is right."""
        rng, los = self.geometry(x)
        return self.sd_cyc - rng / L1_WAVELENGTH_M, los

    def code_residuals(self, x: FloatArray) -> FloatArray:
        """Code residuals [m] of trajectory ``x``: epoch constant + noise where it is right."""
        rng, _ = self.geometry(x)
        return self.sd_code_m - rng


def _troposphere_m(x: FloatArray, los: FloatArray) -> FloatArray:
    """Saastamoinen delay [m] per (epoch, satellite) for receiver positions ``x`` (n, 3) or (3,)."""
    xx = np.asarray(x, dtype=np.float64)
    el = elevation_deg(los, xx)
    p = np.hypot(xx[..., 0], xx[..., 1])
    lat = np.degrees(np.arctan2(xx[..., 2], p * (1 - 6.69437999014e-3)))
    r = np.linalg.norm(xx, axis=-1)
    # Height above the ellipsoid, to a few metres (plenty for a delay of metres per km).
    a, b = 6378137.0, 6356752.314245
    rl = np.radians(lat)
    r_ell = np.sqrt(((a * a * np.cos(rl)) ** 2 + (b * b * np.sin(rl)) ** 2)
                    / ((a * np.cos(rl)) ** 2 + (b * np.sin(rl)) ** 2))
    h = r - r_ell
    if np.ndim(lat) == 0:
        return saastamoinen_delay_m(float(lat), np.full(el.shape, h), np.maximum(el, 1.0))
    lat0 = float(np.nanmean(lat)) if np.isfinite(lat).any() else 0.0
    hh = np.broadcast_to(np.asarray(h)[:, None], el.shape)
    return saastamoinen_delay_m(lat0, hh, np.maximum(np.nan_to_num(el, nan=90.0), 1.0))


def build_table(
    rover: ObsSet, base: ObsSet, ephemerides: Sequence[BroadcastEphemeris],
    base_ecef_m: tuple[float, float, float], approx_ecef_m: FloatArray | None = None,
    decisions: Sequence[tuple[int, str, int]] | None = None,
) -> PhaseTable:
    """The table of a rover (conditioned observations) against its base.

    Args:
        rover, base: observations (our RINEX writer's arrays).
        ephemerides: GPS broadcast ephemerides.
        base_ecef_m: the base antenna's known position.
        approx_ecef_m: the rover's approximate position per rover epoch (n_ep, 3), for the
            elevation mask; default the base's (a baseline of kilometres changes an elevation
            by hundredths of a degree).
        decisions: (GPS ns, satellite name, first phase moved) of every rover phase the
            conditioning carried on a decision of its own (:attr:`~groundstation.solve.
            conditioning.ConditioningReport.decisions`): marked in :attr:`PhaseTable.decided`,
            tested as possible steps. Given on a half-cycle table, an arc is on the whole-cycle
            lattice (:attr:`PhaseTable.arc_whole`) unless a decision it rests on falls outside
            its own phases; the whole-arc solution takes that away too from an arc where a
            decision fails its test (``integrity.steps.unverified``).
    """
    svs = sorted(set(rover.prn[(rover.sys == "G")].tolist())
                 & set(base.prn[(base.sys == "G")].tolist()))
    r = _grid(rover, svs)
    b = _grid(base, svs)
    n_ep, n_sv = r.phase.shape
    # the base epoch nearest each rover epoch
    if b.t_ns.size:
        k = np.clip(np.searchsorted(b.t_ns, r.t_ns), 1, max(b.t_ns.size - 1, 1))
        k0 = np.maximum(k - 1, 0)
        pick = np.where(np.abs(b.t_ns[k0] - r.t_ns) <= np.abs(b.t_ns[np.minimum(k, b.t_ns.size
                                                                              - 1)] - r.t_ns),
                        k0, np.minimum(k, b.t_ns.size - 1))
        age = (r.t_ns - b.t_ns[pick]) / 1e9
    else:
        pick = np.zeros(n_ep, dtype=np.int64)
        age = np.full(n_ep, np.nan)
    near = np.abs(age) <= MAX_BASE_AGE_S
    base_geo = SatGeometry(b.t_ns, svs, b.code, ephemerides)
    brng, blos = base_geo.ranges_all(np.asarray(base_ecef_m, dtype=np.float64))
    brng = brng + _troposphere_m(np.asarray(base_ecef_m, dtype=np.float64), blos)
    bel = elevation_deg(blos, np.asarray(base_ecef_m, dtype=np.float64))
    rover_geo = SatGeometry(r.t_ns, svs, r.code, ephemerides)
    approx = (np.broadcast_to(np.asarray(base_ecef_m, dtype=np.float64), (n_ep, 3))
              if approx_ecef_m is None else approx_ecef_m)
    _, rlos = rover_geo.ranges_all(approx)
    rel = elevation_deg(rlos, approx)

    bph, bcode, bcno = b.phase[pick], b.code[pick], b.cno[pick]
    blli = b.lli[pick]
    sd = r.phase - bph + brng[pick] / L1_WAVELENGTH_M
    sdc = r.code - bcode + brng[pick]
    usable = (
        near[:, None] & ~np.isnan(sd) & ~np.isnan(rover_geo.clk_m)
        & ((r.lli & LLI_HALF_CYCLE) == 0) & ((blli & LLI_HALF_CYCLE) == 0)
        & (np.nan_to_num(rel, nan=-90.0) >= ELEVATION_MASK_DEG)
        & (np.nan_to_num(bel[pick], nan=-90.0) >= ELEVATION_MASK_DEG)
    )
    sd = np.where(usable, sd, np.nan)
    sdc = np.where(usable & ~np.isnan(sdc), sdc, np.nan)
    scale = np.hypot(cno_scale(r.cno), cno_scale(bcno))
    # arcs: (satellite, rover lock, base lock) triples
    rc = _arc_counter(r.t_ns, r.phase, r.lli)
    bc = _arc_counter(b.t_ns, b.phase, b.lli)[pick]
    sv_idx = np.broadcast_to(np.arange(n_sv)[None, :], (n_ep, n_sv))
    key = np.stack([sv_idx[usable], rc[usable], bc[usable]], axis=1)
    arc = np.full((n_ep, n_sv), -1, dtype=np.int64)
    if key.size:
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        arc[usable] = inv.reshape(-1)
        arc_sv = uniq[:, 0].astype(np.int64)
    else:
        arc_sv = np.zeros(0, dtype=np.int64)
    lattice = 0.5 if "RXM-RAW" in (rover.source, base.source) else 1.0
    decided = np.zeros((n_ep, n_sv), dtype=bool)
    put_back = np.zeros((n_ep, n_sv), dtype=bool)
    backs: list[tuple[int, int, int]] = []  # (first row moved, row, column) of put-backs
    col = {f"G{sv:02d}": j for j, sv in enumerate(svs)}
    for t, name, t_first in decisions or ():
        e = int(np.searchsorted(r.t_ns, t))
        if name not in col or e >= n_ep or int(r.t_ns[e]) != int(t):
            continue
        decided[e, col[name]] = True
        if t_first < t:
            put_back[e, col[name]] = True
            backs.append((int(np.searchsorted(r.t_ns, t_first)), e, col[name]))
    whole = None
    if lattice < 1.0 and decisions is not None:
        whole = np.ones(int(arc_sv.size), dtype=bool)
        # An arc rests on every decision made in its rover lock before its last phase: one
        # before its first phase in the table, or at a phase the table does not take, moved
        # it untested.
        for a in range(int(arc_sv.size)):
            j = int(arc_sv[a])
            rows = np.flatnonzero(arc[:, j] == a)
            lock = np.flatnonzero((rc[:, j] == uniq[a, 1]) & ~np.isnan(r.phase[:, j]))
            lock = lock[lock <= rows[-1]]
            if np.any(decided[np.setdiff1d(lock, rows), j]):
                whole[a] = False
        # ... and on every half cycle put back on its phases: tested only where the put-back
        # falls on one of its own phases (the step there)
        for first, e, j in backs:
            moved = arc[first:e, j]
            for a in np.unique(moved[moved >= 0]).tolist():
                if arc[e, j] != a:
                    whole[a] = False
    return PhaseTable(
        t_ns=r.t_ns, svs=tuple(svs), sd_cyc=sd, sd_code_m=sdc,
        sigma_cyc=PHASE_SIGMA_45_CYC * scale, sigma_code_m=CODE_SIGMA_45_M * scale,
        arc=arc, n_arcs=int(arc_sv.size), arc_sv=arc_sv,
        base_age_s=np.where(near, age, np.nan), geo=rover_geo,
        lattice_cyc=lattice, arc_whole=whole, decided=decided, put_back=put_back,
    )
