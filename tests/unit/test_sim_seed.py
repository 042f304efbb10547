"""The ``seed`` profile (the field report's failed flight), measured from the UBX bytes it sends.

Every statistic is taken from what the project's framer and decoder read out of the rover
stream, then compared with the profile's specification and with the truth file: losses of lock
per satellite in flight, half-cycle flags after each loss, C/N0 in flight, shadowing in turns,
radio gaps, the phase jumps themselves (time-differenced phase against Doppler), and which
slips the ground can see. RTKLIB's convbin must read the stream too.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from peers import REPO

from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.orbit import C_M_S, L1_WAVELENGTH_M, rotate_earth, sat_state, toe_gps_ns
from groundstation.records import RawEpoch, SatObs, SvInfo
from groundstation.sim.profiles import sim_config
from groundstation.sim.stream import SimResult, simulate
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import iter_frames

# One worker runs this module's tests (pytest-xdist):
# its module fixtures simulate the seed flights (~3 s each), made once.
pytestmark = pytest.mark.xdist_group("test_sim_seed")

DT_NS = 200_000_000
DT_S = 0.2


@dataclass
class Flight:
    """A simulated flight as the ground decodes it."""

    sim: SimResult
    epochs: dict[int, dict[int, SatObs]] = field(default_factory=dict)  # epoch index -> sv -> obs
    svinfo: list[SvInfo] = field(default_factory=list)

    @property
    def truth(self) -> dict[str, Any]:
        return self.sim.truth

    @property
    def n(self) -> int:
        return int(self.truth["receivers"]["rover"]["epochs"])

    @cached_property
    def trajectory(self) -> tuple[np.ndarray[Any, np.dtype[np.int64]],
                                  np.ndarray[Any, np.dtype[np.float64]]]:
        """The truth's antenna path: GPS ns and ECEF metres, as arrays."""
        traj = self.truth["trajectory"]
        xyz = np.stack([np.asarray(traj[c], dtype=np.float64) for c in ("x_m", "y_m", "z_m")], 1)
        return np.asarray(traj["t_gps_ns"], dtype=np.int64), xyz

    def index(self, t_gps_ns: int) -> int:
        return (t_gps_ns - int(self.truth["start_gps_ns"])) // DT_NS

    @property
    def takeoff(self) -> int:
        """First epoch index in flight."""
        return -(-(int(self.truth["phases"]["takeoff_gps_ns"])
                   - int(self.truth["start_gps_ns"])) // DT_NS)

    @property
    def landing(self) -> int:
        """First epoch index after landing."""
        return -(-(int(self.truth["phases"]["landing_gps_ns"])
                   - int(self.truth["start_gps_ns"])) // DT_NS)

    def in_flight(self, i: int) -> bool:
        return self.takeoff <= i < self.landing

    def losses(self) -> list[tuple[int, int]]:
        """(epoch, sv) of every LLI bit 0 where the satellite was in the previous delivered
        epoch: a loss of lock, not a (re)acquisition."""
        out = []
        prev: dict[int, SatObs] = {}
        for i in sorted(self.epochs):
            cur = self.epochs[i]
            out += [(i, sv) for sv, s in cur.items() if s.lli & 1 and sv in prev]
            prev = cur
        return out

    def gaps(self) -> list[tuple[int, int]]:
        """[first, stop) epoch indices of each run of epochs that did not arrive."""
        present = np.zeros(self.n, dtype=bool)
        present[list(self.epochs)] = True
        padded = np.concatenate(([False], ~present, [False]))
        edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
        return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _decode(sim: SimResult) -> Flight:
    flight = Flight(sim)
    decoder = Decoder()
    for frame in iter_frames(sim.rover_bytes):
        if frame.key not in ((0x02, 0x10), (0x01, 0x30)):
            continue  # only RXM-RAW and NAV-SVINFO matter here (and decoding takes time)
        rec = decoder.decode(frame)
        if isinstance(rec, RawEpoch):
            flight.epochs[flight.index(rec.t_gps_ns)] = {s.sv: s for s in rec.sats}
        elif isinstance(rec, SvInfo):
            flight.svinfo.append(rec)
    return flight


@pytest.fixture(scope="module")
def seed() -> Flight:
    # 25 min: 7.5 min static at each end, 10 min of flight (the full profile: 15 + 20 + 15).
    return _decode(simulate(sim_config("seed", duration_s=1500.0, seed=7)))


@pytest.fixture(scope="module")
def mild() -> Flight:
    return _decode(simulate(sim_config("seed", duration_s=800.0, seed=8, severity=0.5)))


@pytest.fixture(scope="module")
def harsh() -> Flight:
    return _decode(simulate(sim_config("seed", duration_s=800.0, seed=8, severity=2.0)))


def _loss_rate_per_s(f: Flight) -> float:
    """Losses per satellite-second in flight, counted in the epochs that arrived."""
    losses = sum(f.in_flight(i) for i, _ in f.losses())
    sat_epochs = sum(len(sats) for i, sats in f.epochs.items() if f.in_flight(i))
    return losses / (sat_epochs * DT_S)


def test_every_satellite_loses_lock_every_20_s_in_flight(seed: Flight) -> None:
    rate = _loss_rate_per_s(seed)
    assert 0.85 / 20 < rate < 1.15 / 20, 1 / rate  # one loss per 20 s, within 15 %
    per_sv: dict[int, int] = defaultdict(int)
    for i, sv in seed.losses():
        per_sv[sv] += seed.in_flight(i)
    flying = [sv for sv, n in per_sv.items() if n]
    assert len(flying) >= 6, "every tracked satellite loses lock, not a few"


def test_severity_scales_the_loss_rate(mild: Flight, harsh: Flight) -> None:
    low, high = _loss_rate_per_s(mild), _loss_rate_per_s(harsh)
    assert 0.5 / 20 * 0.7 < low < 0.5 / 20 * 1.3, 1 / low
    assert 2 / 20 * 0.8 < high < 2 / 20 * 1.2, 1 / high
    assert 3.0 < high / low < 5.3


def test_no_losses_while_static(seed: Flight) -> None:
    static = [(i, sv) for i, sv in seed.losses() if not seed.in_flight(i)]
    assert static == []
    slips = [e for e in seed.truth["receivers"]["rover"]["lock_events"] if e["kind"] == "slip"]
    landing = seed.truth["phases"]["landing_gps_ns"]
    takeoff = seed.truth["phases"]["takeoff_gps_ns"]
    assert slips and all(takeoff <= e["t_rx_ns"] < landing + DT_NS for e in slips)


def test_truth_says_which_slips_the_ground_sees(seed: Flight) -> None:
    slips = [e for e in seed.truth["receivers"]["rover"]["lock_events"] if e["kind"] == "slip"]
    visible = {(seed.index(e["t_rx_ns"]), e["sv"]) for e in slips if e["visible"]}
    hidden = [e for e in slips if not e["visible"]]
    # A visible slip is exactly an LLI bit 0 on the ground (unless the satellite itself was
    # missing from the epoch before: then it reads as a reacquisition, counted in neither).
    seen = set(seed.losses())
    assert seen <= visible and len(visible - seen) <= 0.02 * len(visible)
    assert hidden, "radio gaps must hide some slips"
    for e in hidden:
        assert seed.index(e["t_rx_ns"]) not in seed.epochs
    rover = seed.truth["receivers"]["rover"]
    assert rover["slips"] == len(slips) and rover["slips_hidden"] == len(hidden)


def test_half_cycle_flag_lasts_2_to_10_s_after_each_loss(seed: Flight) -> None:
    events = seed.truth["receivers"]["rover"]["lock_events"]
    hidden = {(seed.index(e["t_rx_ns"]), e["sv"]) for e in events if not e["visible"]}
    durations = []
    bounded = 0
    for i, sv in seed.losses():
        assert seed.epochs[i][sv].lli & 2, "each loss starts a half-cycle flag"
        # Follow the flag across radio gaps unless the truth says a gap hid another loss.
        j, last_flagged = i + 1, i
        while j < seed.n:
            if (j, sv) in hidden:
                break
            s = seed.epochs.get(j, {}).get(sv)
            if j in seed.epochs and (s is None or s.lli & 1):
                break  # lost or slipped again before the flag cleared
            if s is not None and not s.lli & 2:
                # The flag covered epochs i..last_flagged at least, and cleared by j.
                assert j - i >= 10 and last_flagged - i < 50, (i, sv, last_flagged, j)
                bounded += 1
                if j == last_flagged + 1:
                    durations.append((j - i) * DT_S)
                break
            if s is not None:
                last_flagged = j
            j += 1
    assert bounded > 100 and len(durations) > 60
    assert min(durations) < 3.0 and max(durations) > 9.0
    assert 5.0 < float(np.mean(durations)) < 7.0


def test_about_300_radio_gaps_in_20_min_of_flight(seed: Flight) -> None:
    gaps = seed.gaps()
    flight = [(a, b) for a, b in gaps if seed.in_flight(a)]
    static = [(a, b) for a, b in gaps if not seed.in_flight(a)]
    flight_min = (seed.landing - seed.takeoff) * DT_S / 60
    per_20_min = len(flight) / flight_min * 20
    assert 230 < per_20_min < 370, per_20_min  # Poisson: 10 min hold ~150 +- 12
    lengths = np.array([(b - a) * DT_S for a, b in flight])
    assert float(np.median(lengths)) == pytest.approx(0.4)
    assert 2.0 <= lengths.max() <= 3.0
    # On the ground only a corrupted frame now and then, never a radio outage.
    assert all(b - a == 1 for a, b in static) and len(static) < 0.1 * len(flight)


def test_cno_is_5_db_lower_in_flight(seed: Flight) -> None:
    drops = []
    minute = int(60 / DT_S)
    for edge, sign in ((seed.takeoff, 1), (seed.landing, -1)):
        ground = range(edge - minute, edge) if sign == 1 else range(edge, edge + minute)
        air = range(edge, edge + minute) if sign == 1 else range(edge - minute, edge)

        def cno(rng: range) -> dict[int, list[int]]:
            out: dict[int, list[int]] = defaultdict(list)
            for i in rng:
                for sv, s in seed.epochs.get(i, {}).items():
                    out[sv].append(s.cno_dbhz)
            return out

        g, a = cno(ground), cno(air)
        drops += [np.mean(g[sv]) - np.mean(a[sv]) for sv in g
                  if len(g[sv]) > 200 and len(a[sv]) > 200]
    assert len(drops) >= 10
    assert 4.5 < float(np.mean(drops)) < 5.5, drops


def test_low_satellites_are_shadowed_for_10_s_in_each_turn(seed: Flight) -> None:
    turns = seed.truth["turns"]
    shadows = seed.truth["receivers"]["rover"]["shadows"]
    # 10 min of flight hold 4 lines (3 turns) with jerk-limited legs (5 with trapezoidal ones).
    assert len(turns) >= 3 and shadows
    assert len({sh["turn"] for sh in shadows}) >= len(turns) // 2
    elev: dict[int, dict[int, tuple[int, int]]] = {}  # epoch index -> sv -> (elev, azim)
    for info in seed.svinfo:
        i = seed.index(seed.truth["start_gps_ns"] // 604_800_000_000_000 * 604_800_000_000_000
                       + info.tow_ns)
        elev[i] = {s.sv: (s.elev_deg, s.azim_deg) for s in info.sats}

    def last_seen(sv: int, i: int) -> tuple[int, int]:
        return next(elev[k][sv] for k in range(i, 0, -1) if sv in elev.get(k, {}))

    for sh in shadows:
        a, b = seed.index(sh["start_t_rx_ns"]), seed.index(sh["end_t_rx_ns"])
        assert (b - a) * DT_S == pytest.approx(10.0)
        assert all(sh["sv"] not in seed.epochs.get(i, {}) for i in range(a, b))
        back = seed.epochs.get(b, {}).get(sh["sv"])
        if back is not None:
            assert back.lli & 1, "back from the shadow with a new lock"
        el, az = last_seen(sh["sv"], a)
        away = turns[sh["turn"]]["away_azimuth_deg"]
        assert el < 25 and abs((az - away + 180) % 360 - 180) <= 91, (sh, el, az)
    # Nothing else disappears in flight but satellites setting below the mask.
    expected = {(seed.index(sh["start_t_rx_ns"]), sh["sv"]) for sh in shadows}
    prev: tuple[int, dict[int, SatObs]] | None = None
    for i in range(seed.takeoff, seed.landing):
        cur = seed.epochs.get(i)
        if cur is None:
            continue
        if prev is not None and prev[0] == i - 1:
            for sv in set(prev[1]) - set(cur):
                assert (i, sv) in expected or last_seen(sv, i)[0] < 9, (i, sv)
        prev = (i, cur)


def _doppler_residuals(f: Flight, i: int, sv: int) -> float | None:
    """Phase change from epoch i-1 to i minus the change Doppler predicts, in cycles."""
    a, b = f.epochs.get(i - 1, {}).get(sv), f.epochs.get(i, {}).get(sv)
    if a is None or b is None:
        return None
    predicted = -(a.doppler_hz + b.doppler_hz) / 2 * DT_S
    return b.carrier_phase_cyc - a.carrier_phase_cyc - predicted


def test_phase_jumps_in_the_data_equal_the_truth(seed: Flight) -> None:
    events = seed.truth["receivers"]["rover"]["lock_events"]
    jumps = {(seed.index(e["t_rx_ns"]), e["sv"]): e["jump_cyc"] for e in events
             if e["kind"] == "slip"}
    jumps |= {(seed.index(e["resolve_t_rx_ns"]), e["sv"]): e["resolve_jump_cyc"]
              for e in events if e["resolve_t_rx_ns"] is not None}
    checked = 0
    for (i, sv), jump in jumps.items():
        r = _doppler_residuals(seed, i, sv)
        if r is None:
            continue
        assert abs(r - jump) < 0.3, (i, sv, r, jump)
        checked += 1
    assert checked > 200
    at_loss = [e["jump_cyc"] for e in events if e["kind"] == "slip"]
    half = [j for j in at_loss if j % 1.0 == 0.5]
    whole = [j for j in at_loss if j % 1.0 == 0.0 and j != 0]
    assert len(half) > 50 and len(whole) > 50
    # Elsewhere the phase follows the Doppler: no jump the truth does not list.
    quiet = [r for i in range(seed.takeoff, seed.landing) for sv in seed.epochs.get(i, {})
             if (i, sv) not in jumps and (r := _doppler_residuals(seed, i, sv)) is not None]
    # Noise (about 0.09 cycles at the lowest C/N0 in flight) only: half a cycle stands out.
    assert len(quiet) > 10_000 and max(abs(r) for r in quiet) < 0.4
    assert float(np.std(quiet)) < 0.08


def _geometry_cyc(f: Flight, ephs: dict[int, list[BroadcastEphemeris]], sv: int, i: int
                  ) -> float:
    """(range - c * satellite clock) / wavelength at epoch ``i``, the rover where the truth's
    trajectory puts it: what the phase follows apart from the receiver clock and the ambiguity."""
    t_ns = int(f.truth["start_gps_ns"]) + i * DT_NS
    t_traj, xyz = f.trajectory
    k = int(np.searchsorted(t_traj, t_ns)) - 1
    w = (t_ns - t_traj[k]) / (t_traj[k + 1] - t_traj[k])
    rx = xyz[k] + w * (xyz[k + 1] - xyz[k])
    eph = min(ephs[sv], key=lambda e: abs(toe_gps_ns(e) - t_ns))
    dt_toe = (t_ns - toe_gps_ns(eph)) / 1e9
    tau = 0.075
    for _ in range(3):
        st = sat_state(eph, np.array([dt_toe - tau]))
        rho = float(np.linalg.norm(rotate_earth(st.pos_m, tau)[0] - rx))
        tau = rho / C_M_S
    return (rho - C_M_S * float(st.clock_s[0])) / L1_WAVELENGTH_M


def _change(f: Flight, ephs: dict[int, list[BroadcastEphemeris]], sv: int, p: int, q: int
            ) -> float:
    """Phase change of ``sv`` from epoch p to q minus the geometry's, in cycles."""
    measured = f.epochs[q][sv].carrier_phase_cyc - f.epochs[p][sv].carrier_phase_cyc
    return measured - (_geometry_cyc(f, ephs, sv, q) - _geometry_cyc(f, ephs, sv, p))


def test_slips_hidden_in_radio_gaps_are_in_the_phase(seed: Flight) -> None:
    """Across a gap, between two satellites, phase change minus geometry = the truth's jumps."""
    events = seed.truth["receivers"]["rover"]["lock_events"]
    jumps: dict[int, dict[int, float]] = defaultdict(dict)  # sv -> epoch -> jump
    for e in events:
        if e["jump_cyc"] is not None:
            jumps[e["sv"]][seed.index(e["t_rx_ns"])] = e["jump_cyc"]
        if e["resolve_t_rx_ns"] is not None:
            jumps[e["sv"]][seed.index(e["resolve_t_rx_ns"])] = e["resolve_jump_cyc"]
    ephs: dict[int, list[BroadcastEphemeris]] = defaultdict(list)
    for d in seed.truth["ephemerides"]:
        ephs[d["sv"]].append(BroadcastEphemeris(**d))

    def jumped(sv: int, p: int, q: int) -> float:
        return sum(j for i, j in jumps[sv].items() if p < i <= q)

    checked = 0
    for e in events:
        if e["kind"] != "slip" or e["visible"]:
            continue
        i, sv = seed.index(e["t_rx_ns"]), e["sv"]
        p = max(k for k in seed.epochs if k < i)
        q = min(k for k in seed.epochs if k > i)
        if sv not in seed.epochs[p] or sv not in seed.epochs[q]:
            continue
        refs = [r for r in seed.epochs[p] if r != sv and r in seed.epochs[q]
                and not any(p < k <= q for k in jumps[r])]
        if not refs:
            continue
        ref = refs[0]

        residual = _change(seed, ephs, sv, p, q) - _change(seed, ephs, ref, p, q)
        assert abs(residual - jumped(sv, p, q)) < 0.3, (i, sv, ref, residual, jumped(sv, p, q))
        checked += 1
    assert checked > 20


@pytest.mark.skipif(shutil.which("convbin") is None, reason="RTKLIB convbin not installed")
def test_convbin_reads_the_seed_flight(seed: Flight, tmp_path: Path) -> None:
    (tmp_path / "rover.ubx").write_bytes(seed.sim.rover_bytes)
    subprocess.run(["convbin", "-r", "ubx", "-v", "2.11", "-od", "-os", "-o", "rover.obs",
                    "-n", "rover.nav", "rover.ubx"], cwd=tmp_path, check=True,
                   capture_output=True, timeout=120)
    header, rest = (tmp_path / "rover.obs").read_text().split("END OF HEADER", 1)
    body = rest.splitlines()
    epochs = [ln for ln in body if len(ln) > 32 and ln[0] == " " and ln[28] == "0"
              and ln[1:3].strip().isdigit() and ln[3] == " "]
    # RTKLIB trusts the length of a damaged frame and loses the frame after it; otherwise it
    # reads every epoch our resynchronising framer reads.
    damaged = seed.truth["fault_summary"]["frames_damaged"]
    assert len(seed.epochs) - damaged <= len(epochs) <= len(seed.epochs)
    # Each value is F14.3 followed by the LLI digit: find L1's column from the header.
    types = next(ln for ln in header.splitlines() if "TYPES OF OBSERV" in ln).split()
    col = 16 * (types.index("L1") - 1)
    lli = [ln[col + 14] for ln in body if len(ln) > col + 14 and ln[col + 10] == "."]
    assert lli.count("3") > 100 and lli.count("2") > 1000


def test_cli_simulates_the_seed_profile_and_rejects_a_bad_severity(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "groundstation.cli", "simulate", "--profile", "seed",
           "--duration", "300", "--out", "r.ubx", "--truth", "t.json"]
    proc = subprocess.run([*cmd, "--severity", "2"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120, check=False, env=_env())
    assert proc.returncode == 0, proc.stderr
    assert '"profile":{"name":"seed","severity":2.0}' in (tmp_path / "t.json").read_text()
    fresh = [*cmd[:4], "--profile", "seed", "--duration", "300", "--out", "other.ubx"]
    bad = [*fresh, "--severity", "-1"]
    default_with_severity = [*cmd[:4], "--severity", "2", "--out", "other.ubx"]
    for argv in (bad, default_with_severity):
        proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=60,
                              check=False, env=_env())
        assert proc.returncode == 2, proc.stderr
        assert "severity" in proc.stderr and "Traceback" not in proc.stderr


def _env() -> dict[str, str]:
    import os

    return {**os.environ, "PYTHONPATH": str(REPO)}
