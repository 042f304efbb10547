"""Phase conditioning on a simulated seed flight (the field report's failed flight), against truth.

The simulator's truth records every slip: when, by how much (whole and half cycles), and whether
its LLI reached the ground or was swallowed by a radio gap. The flight goes through our RINEX
writer with the conditioning as its observation hook, exactly as the solver runs it; then
through demo5.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.offline import rinex
from groundstation.offline.rinex.observations import ObsSet
from groundstation.sim.faults import FaultConfig
from groundstation.sim.profiles import sim_config
from groundstation.sim.stream import SimResult, simulate
from groundstation.solve import conditioning, engine
from groundstation.solve.posfile import read_pos
from groundstation.solve.trajectory import Q_FIX

# One worker runs this module's tests (pytest-xdist):
# its module fixture simulates the seed flight (~6 s), made once.
pytestmark = pytest.mark.xdist_group("test_conditioning")

FLIGHT_S = 1200.0  # 6 min static, 8 min flight, 6 min static: short seed flights vary a lot
SEED = 1


@dataclass
class Conditioned:
    sim: SimResult
    work: Path
    before: list[ObsSet] = field(default_factory=list)
    report: list[conditioning.ConditioningReport] = field(default_factory=list)
    after: list[ObsSet] = field(default_factory=list)

    @property
    def truth(self) -> dict[str, Any]:
        return self.sim.truth


def _conditioned(sim: SimResult, work: Path) -> Conditioned:
    """The flight through our RINEX writer with the conditioning as its observation hook, as
    the solver runs it: the observations before and the report."""
    (work / "rover.ubx").write_bytes(sim.rover_bytes)
    (work / "base.ubx").write_bytes(sim.base_bytes)
    out = Conditioned(sim, work)

    def hook(obs: ObsSet, ephs: list[BroadcastEphemeris] | Any,
             approx: tuple[float, float, float]) -> ObsSet:
        out.before.append(obs)
        new, rep = conditioning.condition(obs, ephs, approx)
        out.report.append(rep)
        out.after.append(new)
        return new

    rinex.convert(work / "rover.ubx", work / "rinex", obs_hook=hook)
    return out


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Conditioned:
    sim = simulate(sim_config("seed", duration_s=FLIGHT_S, seed=SEED, severity=1.0))
    return _conditioned(sim, tmp_path_factory.mktemp("cond"))


def _true_jumps(truth: dict[str, Any]) -> dict[int, list[tuple[int, float]]]:
    """Per satellite: (epoch time, phase jump there in cycles) of every loss and resolution."""
    jumps: dict[int, list[tuple[int, float]]] = defaultdict(list)
    for e in truth["receivers"]["rover"]["lock_events"]:
        if e["jump_cyc"] is not None:
            jumps[e["sv"]].append((int(e["t_rx_ns"]), float(e["jump_cyc"])))
        if e["resolve_t_rx_ns"] is not None:
            jumps[e["sv"]].append((int(e["resolve_t_rx_ns"]), float(e["resolve_jump_cyc"])))
    return jumps


def _assert_every_repair_is_the_true_jump(c: Conditioned) -> None:
    jumps = _true_jumps(c.truth)
    for t_prev, t, sat, jump, _hidden in c.report[0].repairs:
        true = sum(j for tj, j in jumps[int(sat[1:])] if t_prev < tj <= t)
        assert jump == true, (t, sat, jump, true)


def test_every_repair_takes_out_the_true_jump(flight: Conditioned) -> None:
    rep = flight.report[0]
    assert rep.applied and rep.repairs
    _assert_every_repair_is_the_true_jump(flight)


def _inverted(truth: dict[str, Any]) -> dict[int, list[tuple[int, int]]]:
    """Per satellite: the spans [start, end) GPS ns in which the simulated receiver's phase
    carries a wrong half cycle (its loop locked with inverted polarity and has not yet resolved
    it; a new loss ends the span, the new lock's own polarity taking over)."""
    by_sv: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for e in truth["receivers"]["rover"]["lock_events"]:
        by_sv[e["sv"]].append(e)
    spans: dict[int, list[tuple[int, int]]] = defaultdict(list)
    for sv, evs in by_sv.items():
        evs.sort(key=lambda e: e["t_rx_ns"])
        for k, e in enumerate(evs):
            if not e["half_cycle_inverted"]:
                continue
            end = e["resolve_t_rx_ns"]
            nxt = evs[k + 1]["t_rx_ns"] if k + 1 < len(evs) else None
            if end is None or (nxt is not None and nxt < end):
                end = nxt if nxt is not None else 2**62
            spans[sv].append((int(e["t_rx_ns"]), int(end)))
    return spans


def test_every_resolved_phase_is_on_the_whole_cycle_lattice(flight: Conditioned) -> None:
    # A squaring loop may lock half a cycle off; the receiver flags that (LLI bit 1) until it
    # has read the navigation data's polarity, then jumps back. Where the conditioning clears
    # bit 1, the phase it leaves must be the true one plus whole cycles: the engine and the
    # whole-arc solution fix it on the whole-cycle lattice. Until 2026-11-29 a lock whose flag
    # stayed set through further repaired losses was shifted by the last lock's half cycle,
    # not its first's (severity 2, seed 1311: 16 arcs half a cycle off the others).
    before, after = flight.before[0], flight.after[0]
    inv = _inverted(flight.truth)
    g = np.flatnonzero((after.sys == "G") & (after.cp_cyc != 0.0)
                       & ((after.lli & 2) == 0))
    t = after.t_gps_ns[after.epoch[g]]
    moved = after.cp_cyc[g] - before.cp_cyc[g]  # what the conditioning added, cycles
    half = np.array([any(lo <= tt < hi for lo, hi in inv.get(int(sv), ()))
                     for tt, sv in zip(t.tolist(), after.prn[g].tolist(), strict=True)])
    off = (moved + 0.5 * half) % 1.0
    wrong = np.minimum(off, 1.0 - off) > 1e-3
    assert g.size > 10_000 and half.any()
    assert not wrong.any(), (
        f"{int(wrong.sum())} of {g.size} phases half a cycle off, e.g. "
        f"{sorted({f'G{int(s):02d}' for s in after.prn[g][wrong]})}")


def test_slips_hidden_in_radio_gaps_are_found_and_mostly_repaired(flight: Conditioned) -> None:
    rep = flight.report[0]
    obs = flight.before[0]
    times = np.sort(obs.t_gps_ns)
    seen: dict[int, set[int]] = defaultdict(set)  # satellite -> epochs (ns) with its phase
    for t, sv, cp in zip(obs.t_gps_ns[obs.epoch].tolist(), obs.prn.tolist(),
                         obs.cp_cyc.tolist(), strict=True):
        if cp != 0.0:
            seen[sv].add(t)
    repaired = {(t, s) for _, t, s, _, _ in rep.repairs}
    flagged = set(rep.flags)
    jumps = _true_jumps(flight.truth)
    hidden = [e for e in flight.truth["receivers"]["rover"]["lock_events"]
              if e["kind"] == "slip" and not e["visible"]]
    assert len(hidden) > 10, "the flight must hide slips in radio gaps"
    n_fixed = n_flagged = n_checked = n_none = 0
    for e in hidden:
        k = int(np.searchsorted(times, e["t_rx_ns"]))
        if k >= times.size or int(times[k]) not in seen[e["sv"]]:
            continue  # the satellite did not come back after the gap
        n_checked += 1
        key = (int(times[k]), f"G{e['sv']:02d}")
        n_fixed += key in repaired
        n_flagged += key in flagged
        if key not in repaired and key not in flagged:
            prev = max(t for t in seen[e["sv"]] if t < times[k])
            # a loss of lock that left the phase where it was: continuity is right
            assert sum(j for tj, j in jumps[e["sv"]] if prev < tj <= times[k]) == 0.0, e
            n_none += 1
    # Nothing is missed: each hidden slip is either repaired (by its true jump, see above), or
    # the satellite starts again, or the phase did not move. Most are repaired.
    assert n_fixed + n_flagged + n_none == n_checked
    assert n_fixed >= 0.6 * n_checked, (n_fixed, n_flagged, n_checked)
    tot = rep.totals()
    assert tot["hidden_found"] >= n_fixed and tot["repaired"] > tot["flagged"] / 2


@pytest.mark.slow
def test_demo5_fixes_the_seed_flight_once_conditioned(flight: Conditioned) -> None:
    truth = flight.truth
    base = tuple(float(v) for v in truth["base"]["ecef_m"])
    run = engine.run_engine("demo5", flight.work / "rover.ubx", flight.work / "base.ubx",
                            (base[0], base[1], base[2]), flight.work / "demo5")
    assert run.conditioning is not None and run.conditioning["applied"]
    assert any(n.startswith("phase conditioning:") for n in run.notes)
    info = run.info_path.read_text()
    assert '"conditioning"' in info and '"hidden_found"' in info
    # Every epoch reaches the engine: its RINEX has no event epochs (RTKLIB's reader drops the
    # epoch after an event whose spacing differs from the one before: 27 of this flight's
    # 5 698 epochs, after radio gaps), and each run has a solution at every epoch.
    rover_obs = next((flight.work / "demo5" / "rover").glob("*.obs"))
    _, epochs = rinex.read_obs3(rover_obs)
    assert all(ep.flag == 0 for ep in epochs)
    for direction in ("forward", "backward"):
        run_traj = read_pos(run.pos_path.parent / direction / "rover.pos")
        assert run_traj.t_gps_ns.size == len(epochs), direction
    traj = read_pos(run.pos_path)
    tr = truth["trajectory"]
    t0 = int(tr["t_gps_ns"][0])
    tt = (np.asarray(tr["t_gps_ns"], dtype=np.int64) - t0) / 1e9
    q = (traj.t_gps_ns - t0) / 1e9
    ref = np.stack([np.interp(q, tt, np.asarray(tr[c])) for c in ("x_m", "y_m", "z_m")], axis=1)
    err = np.linalg.norm(traj.ecef_m - ref, axis=1)
    ph = truth["phases"]
    in_flight = (traj.t_gps_ns >= ph["takeoff_gps_ns"]) & (traj.t_gps_ns < ph["landing_gps_ns"])
    fixed = traj.quality == Q_FIX
    assert in_flight.sum() > 1500
    assert np.mean(fixed[in_flight]) >= 0.90
    # No wrong fix: every fixed epoch within 10 cm of the truth (the simulator's ionosphere is
    # continuous and its legs jerk-limited; with a step in either, fixes came out 10-23 cm off).
    assert float(np.max(err[fixed])) <= 0.10, f"{np.sum(err[fixed] > 0.10)} fixes > 10 cm"


LONG_OUTAGES = FaultConfig(flight_dropout_per_min=4.0, dropout_median_s=5.0,
                           dropout_max_s=10.0, dropout_spacing_s=3.0)
"""The copter behind a tree line: outages of seconds, up to 10 s (longer than
benchmarks/faults/long-outages.toml's, so that a short flight has many)."""


@pytest.fixture(scope="module")
def long_outages(tmp_path_factory: pytest.TempPathFactory) -> Conditioned:
    sim = simulate(sim_config("seed", duration_s=FLIGHT_S, seed=SEED, severity=1.0,
                              faults=LONG_OUTAGES))
    return _conditioned(sim, tmp_path_factory.mktemp("cond-long"))


def test_phase_is_carried_across_outages_longer_than_the_seed_links(
        long_outages: Conditioned) -> None:
    # Until 2026-11-29 no phase was carried across more than 4 s (the seed link's outages are
    # at most 3 s): every satellite started again after each longer outage, and such flights
    # kept 8-100 % of their camera positions fixed (median 61 %).
    obs, rep = long_outages.before[0], long_outages.report[0]
    sats: dict[int, set[str]] = defaultdict(set)  # epoch -> satellites with a phase
    for t, sv, cp in zip(obs.t_gps_ns[obs.epoch].tolist(), obs.prn.tolist(),
                         obs.cp_cyc.tolist(), strict=True):
        if cp != 0.0:
            sats[t].add(f"G{sv:02d}")
    times = sorted(sats)
    flagged = set(rep.flags)
    across = carried = 0
    for before, after in zip(times[:-1], times[1:], strict=True):
        if (after - before) / 1e9 > 4.0:
            both = sats[before] & sats[after]
            across += len(both)
            carried += sum((after, s) not in flagged for s in both)
    # measured: 29 of 106 satellites carried across (the others' jumps not determined: the
    # Doppler's integral misses the copter's accelerations over seconds); before, none
    assert across >= 20 and carried >= 0.2 * across, (carried, across)
    # ... and rightly: every repair takes out the true jump, across long outages too
    _assert_every_repair_is_the_true_jump(long_outages)
