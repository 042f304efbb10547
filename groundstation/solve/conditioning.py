"""Carrier-phase conditioning of a rover's RXM-RAW observations before the PPK engine runs.

What this module owns: finding the cycle slips the receiver could not flag, repairing the slips
whose size the other satellites determine, and resolving RXM-RAW half cycles, so that demo5
keeps each satellite's ambiguity through a loss of lock instead of starting it again.

Why: RXM-RAW carries no lock time, only each measurement's LLI. A slip's LLI travels in the
epoch after the slip; when a radio gap swallows that epoch the slip is invisible (DOMAIN.md).
And every LLI bit 0 or change of bit 1 makes demo5 reset that satellite's ambiguity
(``rtkpos.c`` ``detslp_ll``); in the field report's flight that was several satellites every
few seconds, so no fix survived.

How, for each received epoch ``e`` and each satellite seen at an earlier epoch ``p`` (its
previous appearance, at most :data:`MAX_BRIDGE_S` before) where a gap, an LLI bit 0 or a change
of bit 1 leaves room for a jump (otherwise the receiver would have flagged it):

1. per satellite, the phase change from ``p`` to ``e`` minus the change of its geometric range
   and clock (broadcast orbit, the receiver's single-point position at ``p``): what is left is
   its jump plus ``-u · Δr / λ`` (the receiver's move along the line of sight ``u``) plus a
   clock term common to all satellites;
2. ``Δr`` and the clock term fitted over the satellites seen at both epochs, weighted by their
   C/N0; the fit starts from the satellites the Doppler alone finds without a jump (phase change
   minus the Doppler's trapezoid integral, tightest tolerance that keeps 60 % of them), drops
   the worst one at a time and re-admits any that fit after all. These are between-satellite
   differences in effect: the receiver clock and the motion go, only the jumps remain;
3. the left-over ``w`` of each satellite is its jump. Within :data:`K_SIGMA` standard
   deviations of 0: continuity (a receiver LLI bit 0 there is cleared); within
   :data:`DETERMINE_CYC` of a multiple of half a cycle, with a good fit and (up to
   :data:`ROUGH_CHECK_S`) the Doppler agreeing: repaired, the jump is taken out of every later
   phase; otherwise: flagged, LLI bit 0 set, the engine starts that ambiguity again.

Half cycles (LLI bit 1): a satellite whose ambiguity continues through a repaired loss keeps the
phase it had before, already free of the half cycle, so bit 1 is cleared. A satellite that had
to start again keeps bit 1 until the receiver clears it; the jump made there (0 or half a cycle,
measured like any other) tells the half cycle of the phase since its last loss, and with the
half cycles the repairs since the lock began took up (a loss repaired while bit 1 stayed set
carries the new lock's half cycle in its jump), that of the lock's start. That is put on the
earlier part of the lock, the phase goes on from there without it, and bit 1 is cleared back
to its start: the whole lock is one resolved ambiguity. demo5 keeps the phases that
still carry bit 1 out of ambiguity resolution on any input, RINEX included (``ddidx``: a
satellite with ``slip & LLI_HALFC`` is not fixed), and resets the ambiguity when bit 1 changes
(``detslp_ll``); after conditioning, bit 1 is left only where it is still unresolved.

Only GPS phases of RXM-RAW recordings are conditioned (RXM-RAWX has lock times and its decoder
already marks every slip; SBAS has no orbit in our navigation files).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.geometry import SatGeometry
from groundstation.gnss.noise import PHASE_SIGMA_45_CYC, cno_scale
from groundstation.gnss.orbit import L1_WAVELENGTH_M
from groundstation.offline.rinex.observations import ObsSet
from groundstation.rules.phase import LLI_HALF_CYCLE, LLI_SLIP
from groundstation.solve.integrity.table import ARC_GAP_S

FloatArray = npt.NDArray[np.float64]

K_SIGMA = 4.0
"""A residual within this many of its standard deviations is noise."""
MAX_JUMP_SIGMA_CYC = 0.06
"""A jump measured less well than this is not determined (half cycles must stay apart)."""
MAX_CHI = 3.0
"""A fit whose normalised rms exceeds this determines no jump."""
MIN_REFERENCE_SATS = 5
"""Satellites without a jump needed to determine another's jump across a gap."""
MAX_BRIDGE_S = ARC_GAP_S
"""Longest span a satellite's phase is carried across: the whole-arc solution's, past which no
receiver's lock is taken to have held (:data:`groundstation.solve.integrity.table.ARC_GAP_S`,
30 s). A bridge here is a proposal: the whole-arc solution judges every gap again in
between-receiver differences, where the ionosphere and the troposphere cancel and a gap's
length does not weaken the test (each epoch's position is free either way), and cuts the arcs
at a gap it contradicts or cannot check (``integrity.steps``). Up to 2026-11-29 this was 4 s
("radio gaps are at most 3 s", the seed link's longest): a link with longer outages started
every satellite's ambiguity again at each, and its flights kept 8-100 % of their camera
positions fixed, median 61 % (benchmarks/RESULTS.md, "Long radio outages")."""
STEP_INTERVALS = 1.5
"""Epochs closer than this many nominal intervals are consecutive: no room for a slip the
receiver did not flag."""
ROUGH_SHORT_CYC = 0.25
"""Over a short span the Doppler alone tells a half-cycle jump [cycles]."""
ROUGH_PER_S_CYC = 0.1
"""... and that tolerance grows with the span (the Doppler's integral misses accelerations)."""
ROUGH_CHECK_S = 2.0
"""Up to this span the Doppler's jump must agree with the geometric one."""
ROUGH_TOLERANCES_CYC = (0.25, 0.5, 1.0, 3.0)
"""Tolerances tried, tightest first, to pick the satellites the fit starts from."""
DETERMINE_CYC = 0.15
"""A jump is a multiple of half a cycle only this close (whatever its standard deviation)."""


@dataclass(slots=True)
class SatReport:
    """What conditioning did to one satellite.

    Attributes:
        receiver_slips: LLI bit 0 the receiver set (after the phase rule).
        hidden_found: jumps the receiver did not flag (a radio gap hid its LLI).
        repaired: slips bridged: jump measured and removed, or flagged slip without a jump.
        flagged: losses we could not bridge (LLI bit 0 kept or set: the engine resets).
        half_resolved: half-cycle periods cleared (phase resolved back to the lock start).
        kept_by_doppler: gaps bridged on the Doppler alone (no receiver flag, no jump in the
            Doppler's integral) where the satellites' geometry gave no usable fit.
    """

    receiver_slips: int = 0
    hidden_found: int = 0
    repaired: int = 0
    flagged: int = 0
    half_resolved: int = 0
    kept_by_doppler: int = 0


@dataclass(slots=True)
class ConditioningReport:
    """Per satellite counts and the list of repairs (for the report and tests)."""

    satellites: dict[str, SatReport] = field(default_factory=dict)
    repairs: list[tuple[int, int, str, float, bool]] = field(default_factory=list)
    """(time GPS ns of the satellite's previous epoch, of this epoch, satellite, jump in
    cycles, whether the receiver had not flagged it) of every repaired jump."""
    flags: list[tuple[int, str]] = field(default_factory=list)
    """(epoch time GPS ns, satellite) of every flagged loss."""
    applied: bool = False
    note: str = ""
    decisions: list[tuple[int, str, int]] = field(default_factory=list)
    """(epoch time GPS ns, satellite, time of the first phase it moved) of every phase carried
    on a decision of ours: a jump repaired, a continuity taken across a loss, a gap or a change
    of the half-cycle flag (each moves that phase and the later ones: the third is the first),
    a half cycle put back (it moves the lock's phases before it: the third is the lock's
    start). The whole-arc solution tests each as a possible step (``integrity.steps``)."""

    def totals(self) -> dict[str, int]:
        keys = ("receiver_slips", "hidden_found", "repaired", "flagged", "half_resolved",
                "kept_by_doppler")
        return {k: sum(getattr(s, k) for s in self.satellites.values()) for k in keys}

    def as_dict(self) -> dict[str, object]:
        """JSON-ready: totals and per-satellite counts."""
        return {
            "applied": self.applied,
            "note": self.note,
            "totals": self.totals(),
            "satellites": {
                k: {
                    "receiver_slips": s.receiver_slips, "hidden_found": s.hidden_found,
                    "repaired": s.repaired, "flagged": s.flagged,
                    "half_resolved": s.half_resolved, "kept_by_doppler": s.kept_by_doppler,
                }
                for k, s in sorted(self.satellites.items())
            },
        }


def _jumps(
    cp: FloatArray, geo: SatGeometry, p: int, e: int, ref: npt.NDArray[np.int64],
    scale: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """Phase change from epoch ``p`` to ``e`` minus the satellites' own motion and clock, per
    satellite of ``ref`` [cycles], its standard deviation, and the lines of sight.

    What is left is the jump plus ``-u · Δr / λ`` (the receiver's move) plus a clock term
    common to all satellites. None without a receiver position.
    """
    x = geo.position(p)
    if x is None:
        return None
    rp, _ = geo.ranges(p, ref, x)
    re, u = geo.ranges(e, ref, x)
    r = (cp[e, ref] - cp[p, ref]) - (re - rp) / L1_WAVELENGTH_M
    sig = PHASE_SIGMA_45_CYC * np.hypot(scale[e, ref], scale[p, ref])
    return r, sig, u


def _fit(
    r: FloatArray, sig: FloatArray, u: FloatArray, rough: FloatArray,
    quiet: npt.NDArray[np.bool_],
) -> tuple[FloatArray, npt.NDArray[np.bool_], float]:
    """The error all satellites share, per satellite; which satellites have no jump; the
    fit's normalised rms.

    Args:
        r: jump + common error per satellite (cycles); ``sig`` its standard deviation.
        u: line of sight per satellite.
        rough: phase change minus the Doppler's integral per satellite: a jump stands out in
            it whatever the receiver did (over a short span even half a cycle), so it is left
            out before the fit starts; otherwise the line-of-sight fit can bend to take a half
            cycle in and push good satellites out.
        quiet: satellites the receiver reported nothing for (no LLI bit 0, no change of bit
            1). The fit starts from these only: when half the satellites clear their half
            cycle in the same epoch (all of them acquired together), the jumping ones must not
            become the reference.

    Returns:
        (model, clean, chi); chi is infinite when fewer than :data:`MIN_REFERENCE_SATS`
        quiet satellites agree.
    """
    n = r.size
    if int(quiet.sum()) < MIN_REFERENCE_SATS:
        return np.zeros(n), np.zeros(n, dtype=bool), np.inf
    med = float(np.median(rough[quiet]))
    for tol in ROUGH_TOLERANCES_CYC:  # the tightest start that keeps enough satellites
        clean = quiet & (np.abs(rough - med) < tol)
        if int(clean.sum()) >= max(MIN_REFERENCE_SATS, int(np.ceil(0.6 * quiet.sum()))):
            break
    first = _refine(r, sig, u, clean)
    if first[2] < MAX_CHI and int(first[1].sum()) >= int(np.ceil(0.6 * quiet.sum())):
        return first
    # The Doppler's integral misled the start (the copter accelerated through the gap: over
    # 3 s of a turn it is several cycles off for every satellite): start instead from the
    # largest set of quiet satellites one motion and one clock explain.
    start = _consensus(r, sig, u, quiet)
    if start is None:
        return first
    second = _refine(r, sig, u, start)
    if second[2] < MAX_CHI and (first[2] >= MAX_CHI or second[1].sum() > first[1].sum()):
        return second
    return first


CONSENSUS_SIZE = 5
"""Satellites per trial of the consensus start: the motion (3) and the clock (1) plus one to
check them."""
MAX_CONSENSUS_TRIALS = 2000
"""Trials at most (all subsets of 12 quiet satellites are 792)."""


def _consensus(
    r: FloatArray, sig: FloatArray, u: FloatArray, quiet: npt.NDArray[np.bool_],
) -> npt.NDArray[np.bool_] | None:
    """The satellites agreeing with the motion and clock of the best-supported subset of
    :data:`CONSENSUS_SIZE` quiet satellites (most within :data:`K_SIGMA` of it; ties: the
    smaller sum of squares), or None when there are too few quiet satellites."""
    cand = np.flatnonzero(quiet)
    if cand.size < max(CONSENSUS_SIZE, MIN_REFERENCE_SATS):
        return None
    combos = np.array(list(itertools.islice(
        itertools.combinations(cand.tolist(), CONSENSUS_SIZE), MAX_CONSENSUS_TRIALS)))
    a = np.column_stack([np.ones(r.size), u / L1_WAVELENGTH_M])
    wgt = 1.0 / sig
    aw = a[combos] * wgt[combos][..., None]  # (m, k, 4)
    rw = r[combos] * wgt[combos]
    normal = np.einsum("mki,mkj->mij", aw, aw)
    ok = np.linalg.cond(normal) < 1e12
    normal[~ok] = np.eye(4)
    coef = np.linalg.solve(normal, np.einsum("mki,mk->mi", aw, rw)[..., None])[..., 0]
    z = (r[None, :] - coef @ a.T) * wgt[None, :]  # (m, n)
    inside = (np.abs(z) < K_SIGMA) & quiet[None, :] & ok[:, None]
    count = inside.sum(axis=1)
    sse = np.where(inside, z * z, 0.0).sum(axis=1)
    best = int(np.lexsort((sse, -count))[0])
    if count[best] < MIN_REFERENCE_SATS:
        return None
    return np.asarray(inside[best], dtype=bool)


def _refine(
    r: FloatArray, sig: FloatArray, u: FloatArray, clean: npt.NDArray[np.bool_],
) -> tuple[FloatArray, npt.NDArray[np.bool_], float]:
    """The fit from a starting set ``clean``: the worst satellite dropped one at a time,
    those consistent after all re-admitted (see :func:`_fit`)."""
    n = r.size
    clean = clean.copy()
    wgt = 1.0 / sig
    for _ in range(3 * n + 3):
        k = int(clean.sum())
        if k == 0:
            return np.zeros(n), clean, np.inf
        if k >= 6:
            a = np.column_stack([np.ones(n), u / L1_WAVELENGTH_M])
            dof = k - 4
        else:
            a = np.ones((n, 1))
            dof = k - 1
        aw = a[clean] * wgt[clean, None]
        coef, *_ = np.linalg.lstsq(aw, r[clean] * wgt[clean], rcond=None)
        model = a @ coef
        z = (r - model) * wgt
        worst = int(np.argmax(np.where(clean, np.abs(z), -1.0)))
        if abs(z[worst]) < K_SIGMA or k <= 2:
            chi = float(np.sqrt(np.sum(z[clean] ** 2) / max(dof, 1))) if dof > 0 else np.inf
            back = ~clean & (np.abs(z) < K_SIGMA)
            if not back.any():
                return model, clean, chi
            clean |= back  # consistent after all: a worse satellite had bent the fit
            continue
        clean[worst] = False
    return np.zeros(n), np.zeros(n, dtype=bool), np.inf


def condition(
    obs: ObsSet, ephemerides: Sequence[BroadcastEphemeris],
    approx_ecef_m: tuple[float, float, float],
) -> tuple[ObsSet, ConditioningReport]:
    """Conditioned observations (phases repaired, LLI set or cleared) and what was done.

    Args:
        obs: the rover's observations (our RINEX writer's arrays).
        ephemerides: GPS broadcast ephemerides (for the lines of sight).
        approx_ecef_m: approximate receiver position.
    """
    rep = ConditioningReport()
    if obs.source != "RXM-RAW":
        rep.note = (f"{obs.source} gives each satellite's lock time, which marks every slip: "
                    "nothing to repair")
        return obs, rep
    rows = np.flatnonzero((obs.sys == "G") & (obs.cp_cyc != 0.0))
    if rows.size == 0:
        rep.note = "no GPS phase"
        return obs, rep
    svs = sorted(set(obs.prn[rows].tolist()))
    col = {sv: j for j, sv in enumerate(svs)}
    n_ep, n_sv = obs.t_gps_ns.size, len(svs)
    order = np.argsort(obs.t_gps_ns, kind="stable")
    rank = np.empty(n_ep, dtype=np.int64)
    rank[order] = np.arange(n_ep)
    t_ns = obs.t_gps_ns[order]
    t_s = (t_ns - t_ns[0]) / 1e9
    step_s = STEP_INTERVALS * float(np.median(np.diff(t_s))) if t_s.size > 1 else 0.0
    ep = rank[obs.epoch[rows]]
    sj = np.array([col[p] for p in obs.prn[rows].tolist()], dtype=np.int64)
    cp = np.full((n_ep, n_sv), np.nan)
    do = np.full((n_ep, n_sv), np.nan)
    scale = np.ones((n_ep, n_sv))
    lli = np.zeros((n_ep, n_sv), dtype=np.int64)
    row_of = np.full((n_ep, n_sv), -1, dtype=np.int64)
    cp[ep, sj] = obs.cp_cyc[rows]
    do[ep, sj] = obs.do_hz[rows]
    scale[ep, sj] = cno_scale(obs.cno_dbhz[rows])
    lli[ep, sj] = obs.lli[rows]
    row_of[ep, sj] = rows
    pr = np.zeros((n_ep, n_sv))
    pr[ep, sj] = obs.pr_m[rows]
    geo = SatGeometry(t_ns, svs, pr, ephemerides, approx_ecef_m)
    names = [f"G{sv:02d}" for sv in svs]
    for nm in names:
        rep.satellites[nm] = SatReport()

    corr = np.zeros(n_sv)  # running correction per satellite, applied from the current epoch on
    out_cp = cp.copy()
    out_lli = lli & ~(LLI_SLIP | LLI_HALF_CYCLE)
    last = np.full(n_sv, -1, dtype=np.int64)  # previous epoch the satellite was seen
    lock_start = np.zeros(n_sv, dtype=np.int64)  # epoch its current ambiguity began
    resolved = np.ones(n_sv, dtype=bool)  # ambiguity free of the half cycle since lock_start
    present = ~np.isnan(cp)

    for e in range(n_ep):
        sats = np.flatnonzero(present[e])
        if sats.size == 0:
            continue
        prev = last[sats]
        # (a) satellites seen for the first time or after too long: a new lock
        fresh = (prev < 0) | (t_s[e] - t_s[np.maximum(prev, 0)] > MAX_BRIDGE_S)
        for j in sats[fresh].tolist():
            if last[j] >= 0:
                rep.satellites[names[j]].flagged += 1
                rep.flags.append((int(t_ns[e]), names[j]))
            if lli[e, j] & LLI_SLIP and last[j] >= 0:
                rep.satellites[names[j]].receiver_slips += 1
            out_lli[e, j] |= LLI_SLIP
            corr[j] = 0.0
            lock_start[j] = e
            resolved[j] = not (lli[e, j] & LLI_HALF_CYCLE)
        # (b) the others, grouped by where they were seen last; only a gap, an LLI bit 0 or a
        # change of bit 1 can hide or make a jump (otherwise the receiver would have said so)
        for p in np.unique(prev[~fresh]).tolist():
            group = sats[~fresh][prev[~fresh] == p]
            dt = float(t_s[e] - t_s[p])
            event = (lli[e, group] & LLI_SLIP) | ((lli[e, group] ^ lli[p, group]) & LLI_HALF_CYCLE)
            if dt <= step_s:
                group = group[event != 0]
            if group.size == 0:
                continue
            ref = np.flatnonzero(present[e] & present[p])
            ref = ref[~np.isnan(geo.clk_m[e, ref]) & ~np.isnan(geo.clk_m[p, ref])]
            got = _jumps(cp, geo, p, e, ref, scale) if ref.size else None
            rough = (cp[e, ref] - cp[p, ref]) + 0.5 * (do[e, ref] + do[p, ref]) * dt
            if got is None:
                r, sig = np.zeros(ref.size), np.full(ref.size, np.inf)
                model, clean, chi = r, np.zeros(ref.size, dtype=bool), np.inf
            else:
                r, sig, u = got
                quiet = ((lli[e, ref] & LLI_SLIP) == 0) & (
                    ((lli[e, ref] ^ lli[p, ref]) & LLI_HALF_CYCLE) == 0)
                model, clean, chi = _fit(r, sig, u, rough, quiet)
            need = max(MIN_REFERENCE_SATS, int(np.ceil(0.5 * ref.size)))
            good = chi < MAX_CHI and int(clean.sum()) >= need
            # over a short span the Doppler must tell the same jump (a second opinion), as
            # well as it tells the satellites without one: a walker's steps or a copter's
            # jolts between epochs put the Doppler's trapezoid off for every satellite alike
            rj = rough - float(np.median(rough[clean])) if clean.any() else rough
            w_all = r - model
            spread = (1.4826 * float(np.median(np.abs((rj - w_all)[clean])))
                      if int(clean.sum()) >= MIN_REFERENCE_SATS else 0.0)
            pos = {int(s): i for i, s in enumerate(ref.tolist())}
            for j in group.tolist():
                i = pos.get(j)
                if i is None:
                    _bridge(e, p, j, np.inf, np.inf, False, lli, out_lli, corr, lock_start,
                            resolved, out_cp, rep, names[j], t_ns)
                    continue
                w = float(r[i] - model[i])
                tol = max(ROUGH_SHORT_CYC + ROUGH_PER_S_CYC * dt, K_SIGMA * spread)
                agree = dt > ROUGH_CHECK_S or abs(float(rj[i]) - w) < tol
                if (not good and dt <= ROUGH_CHECK_S and not lli[e, j] & LLI_SLIP
                        and not (lli[e, j] ^ lli[p, j]) & LLI_HALF_CYCLE
                        and abs(float(rj[i])) < tol):
                    # The geometric fit failed, but the receiver saw no loss and the Doppler
                    # sees no jump: keep the phase rather than reset every satellite at once.
                    rep.satellites[names[j]].kept_by_doppler += 1
                    rep.decisions.append((int(t_ns[e]), names[j], int(t_ns[e])))
                    continue
                _bridge(e, p, j, w, float(sig[i]), good and agree, lli, out_lli,
                        corr, lock_start, resolved, out_cp, rep, names[j], t_ns)
        out_cp[e, sats] = cp[e, sats] + corr[sats]
        # bit 1 on the output: only where the ambiguity still carries the half cycle
        for j in sats.tolist():
            if not resolved[j] and lli[e, j] & LLI_HALF_CYCLE:
                out_lli[e, j] |= LLI_HALF_CYCLE
            elif not resolved[j]:
                resolved[j] = True  # receiver cleared it with no jump measured: see _bridge
        last[sats] = e

    new_cp = obs.cp_cyc.copy()
    new_lli = obs.lli.copy()
    sel = row_of >= 0
    new_cp[row_of[sel]] = out_cp[sel]
    new_lli[row_of[sel]] = out_lli[sel]
    rep.applied = True
    return replace(obs, cp_cyc=new_cp, lli=new_lli), rep


def _bridge(
    e: int, p: int, j: int, w: float, sig: float, good: bool, lli: npt.NDArray[np.int64],
    out_lli: npt.NDArray[np.int64], corr: FloatArray, lock_start: npt.NDArray[np.int64],
    resolved: npt.NDArray[np.bool_], out_cp: FloatArray, rep: ConditioningReport, name: str,
    t_ns: npt.NDArray[np.int64],
) -> None:
    """Carry satellite ``j``'s ambiguity from epoch ``p`` into ``e`` (its jump ``w``), or start
    it again."""
    sr = rep.satellites[name]
    flagged = bool(lli[e, j] & LLI_SLIP)
    half_cleared = bool(lli[p, j] & LLI_HALF_CYCLE) and not lli[e, j] & LLI_HALF_CYCLE
    if flagged:
        sr.receiver_slips += 1
    if not (np.isfinite(w) and np.isfinite(sig)):
        # No measurement of the jump (the satellite had no geometry at one of the epochs, or
        # too few references): nothing to round, the ambiguity starts again.
        w, sig, good = np.inf, np.inf, False
    half = round(2.0 * w) / 2.0 if np.isfinite(w) else np.inf
    noise = K_SIGMA * sig
    determined = (good and sig < MAX_JUMP_SIGMA_CYC
                  and abs(w - half) < min(noise, DETERMINE_CYC))
    if determined and not resolved[j] and half_cleared and not flagged and abs(half) in (0, 0.5):
        # The half cycle resolved: the phase since the last loss was off by minus this jump
        # (0 or half a cycle). The repairs since the lock began carried the phase through
        # every loss in between with whatever half cycle each new lock had, so the output
        # so far is off by the lock's *first* half cycle: this one less the half cycles
        # those repairs took up (their sum is -corr). Put that on the earlier part, and
        # carry the phase on from here without it: the whole lock is one resolved ambiguity.
        # (With no half-odd repair since the lock began, this is the jump itself.)
        first = float((corr[j] - half) % 1.0)
        out_cp[lock_start[j]:e, j] -= first
        corr[j] -= half + first
        out_lli[lock_start[j]:e, j] &= ~LLI_HALF_CYCLE
        resolved[j] = True
        sr.half_resolved += 1
        rep.decisions.append((int(t_ns[e]), name, int(t_ns[lock_start[j]])))
        return
    if abs(w) < noise and good and sig < MAX_JUMP_SIGMA_CYC:
        if flagged:
            sr.repaired += 1
        rep.decisions.append((int(t_ns[e]), name, int(t_ns[e])))
        return
    if determined:
        if not flagged and not half_cleared:
            sr.hidden_found += 1
        corr[j] -= half
        sr.repaired += 1
        rep.repairs.append((int(t_ns[p]), int(t_ns[e]), name, half, not flagged))
        rep.decisions.append((int(t_ns[e]), name, int(t_ns[e])))
        return
    if not flagged and good and np.isfinite(w) and abs(w) >= noise:
        # A jump measured (a good fit) where the receiver said nothing: hidden by a gap. A jump
        # that could not be measured is no finding: the ambiguity starts again all the same,
        # counted as not bridged only.
        sr.hidden_found += 1
    sr.flagged += 1
    rep.flags.append((int(t_ns[e]), name))
    out_lli[e, j] |= LLI_SLIP
    corr[j] = 0.0
    lock_start[j] = e
    resolved[j] = not (lli[e, j] & LLI_HALF_CYCLE)
