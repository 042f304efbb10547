"""The simulator's entry point: configuration in, UBX byte streams and the truth out.

``simulate(SimConfig(...))`` returns a :class:`SimResult` with the rover's (possibly damaged) byte
stream as timed chunks, the base's clean stream, the truth dictionary, and the clean messages.
:func:`groundstation.pacing.paced` replays the timed chunks in real time (or faster).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from groundstation import gpstime, jsonio
from groundstation.geodesy import ecef_to_llh
from groundstation.gnss.lnav_encode import subframe_for
from groundstation.gpstime import NS_PER_S, NS_PER_WEEK
from groundstation.sim import messages as ubx
from groundstation.sim.constellation import Constellation, make_constellation
from groundstation.sim.faults import (
    DEFAULT_BAUD,
    FaultConfig,
    FaultLog,
    apply_link_faults,
    apply_mark_faults,
)
from groundstation.sim.messages import TimedMessage
from groundstation.sim.receiver import Observations, ReceiverConfig, observe
from groundstation.sim.trajectory import DEFAULT_BASE_ENU_M, Trajectory, TrajectoryConfig

DEFAULT_START_GPS_NS = gpstime.datetime_to_gps_ns(dt.datetime(2025, 6, 2, 8, 0, tzinfo=dt.UTC))
"""A Monday morning: far from a week rollover, and recent enough for RTKLIB's 10-bit week."""
TRUTH_SCHEMA = "groundstation.sim.truth/1"
OUTPUT_LATENCY_NS = 40_000_000
MARK_PULSE_NS = 14_160_000


@dataclass(frozen=True, slots=True)
class SimConfig:
    """Everything that determines a simulation (with ``seed``, the output is reproducible).

    Attributes:
        duration_s: total span; the trajectory is fitted to it. ``None`` keeps ``trajectory``.
        trajectory: explicit flight plan (used as is when ``duration_s`` is ``None``).
        start_gps_ns: first epoch (rounded down to the measurement grid).
        seed: random seed for the constellation, noise, squaring events and faults.
        faults: link and mark faults applied to the rover stream.
        with_base: also simulate the static base receiver.
        base_enu_m: base antenna relative to the take-off point.
        rate_hz: measurement rate (RXM-RAW).
        truth_rate_hz: trajectory sampling in the truth.
        baud: UART speed that spaces the bytes in time.
        rover: rover receiver; ``base``: base receiver.
        n_satellites: constellation size.
        profile: name of the profile that made this configuration (for the truth).
        severity: the profile's severity (for the truth).
    """

    duration_s: float | None = 600.0
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    start_gps_ns: int = DEFAULT_START_GPS_NS
    seed: int = 1
    faults: FaultConfig = field(default_factory=FaultConfig.none)
    with_base: bool = True
    base_enu_m: tuple[float, float, float] = DEFAULT_BASE_ENU_M
    rate_hz: int = 5
    truth_rate_hz: int = 50
    baud: int = DEFAULT_BAUD
    rover: ReceiverConfig = field(
        default_factory=lambda: ReceiverConfig("rover", clock_bias_s=2.1e-4,
                                               clock_drift_s_s=3.0e-8, cno_offset_db=-1.0)
    )
    base: ReceiverConfig = field(
        default_factory=lambda: ReceiverConfig("base", clock_bias_s=-3.4e-4,
                                               clock_drift_s_s=-1.2e-8)
    )
    n_satellites: int = 31
    profile: str = "default"
    severity: float = 1.0


@dataclass(slots=True)
class SimResult:
    """What a simulation produced.

    Attributes:
        rover_chunks: ``(t_gps_ns, bytes)`` as the ground receives them (faults applied).
        base_chunks: the base receiver's clean stream.
        truth: the truth dictionary (JSON-ready).
        rover_messages: the rover's clean messages before link faults.
        base_messages: the base's messages.
        fault_log: what the link faults did.
        constellation, rover_obs, base_obs: the simulation internals, for tests.
    """

    rover_chunks: list[tuple[int, bytes]]
    base_chunks: list[tuple[int, bytes]]
    truth: dict[str, Any]
    rover_messages: list[TimedMessage]
    base_messages: list[TimedMessage]
    fault_log: FaultLog
    constellation: Constellation
    rover_obs: Observations
    base_obs: Observations | None

    @property
    def rover_bytes(self) -> bytes:
        return b"".join(c for _, c in self.rover_chunks)

    @property
    def base_bytes(self) -> bytes:
        return b"".join(c for _, c in self.base_chunks)

    def write_truth(self, path: str | Path) -> None:
        Path(path).write_bytes(jsonio.dumps(self.truth))


@dataclass(frozen=True, slots=True)
class MarkTruth:
    """One camera exposure: true edge times, the receiver's count, the antenna position."""

    index: int
    count: int
    line: int
    falling_t_gps_ns: int
    rising_t_gps_ns: int
    ecef_m: tuple[float, float, float]


def _week_tow_ms(t_ns: int) -> tuple[int, int]:
    week, tow_ns = divmod(t_ns, NS_PER_WEEK)
    return week, tow_ns // 1_000_000


def _messages(
    obs: Observations,
    constellation: Constellation,
    vel_ecef: np.ndarray[Any, np.dtype[np.float64]],
    marks: list[tuple[int, int, bytes]],
    rng: np.random.Generator,
    baud: int,
) -> list[TimedMessage]:
    uart = ubx.Uart(baud, obs.name)
    interval = int(obs.t_rx_ns[1] - obs.t_rx_ns[0]) if len(obs.t_rx_ns) > 1 else NS_PER_S // 5
    epochs_per_sf = int(6 * NS_PER_S // interval)
    mark_i = 0
    svs = obs.svs
    for i, t in enumerate(obs.t_rx_ns.tolist()):
        week, tow_ms = _week_tow_ms(t)
        cols = np.flatnonzero(obs.tracked[i])
        ready = t + OUTPUT_LATENCY_NS
        rows = [
            (
                float(obs.carrier_phase_cyc[i, j]),
                float(obs.pseudorange_m[i, j]),
                float(obs.doppler_hz[i, j]),
                svs[j],
                int(obs.mes_qi[i, j]),
                int(obs.cno_dbhz[i, j]),
                int(obs.lli[i, j]),
            )
            for j in cols
        ]
        uart.send(ready, "RXM-RAW", ubx.rxm_raw(tow_ms, week, rows), tow_ms)
        while mark_i < len(marks) and marks[mark_i][0] <= t:
            _, count, raw = marks[mark_i]
            uart.send(ready, "TIM-TM2", raw, count)
            mark_i += 1
        if tow_ms % 1000 == 0:
            pos = obs.pos_ecef_m[i] + rng.normal(0.0, 1.2, 3)
            vel = vel_ecef[i] + rng.normal(0.0, 0.05, 3)
            ecef_cm = (round(pos[0] * 100), round(pos[1] * 100), round(pos[2] * 100))
            vel_cm = (round(vel[0] * 100), round(vel[1] * 100), round(vel[2] * 100))
            uart.send(ready, "NAV-SOL", ubx.nav_sol(tow_ms, week, ecef_cm, vel_cm, 280, 40, 160,
                                                    len(cols)), tow_ms)
            sv_rows = []
            for ch, j in enumerate(cols):
                lli = int(obs.lli[i, j])
                quality = 7 if not lli & 2 else 5
                sv_rows.append((ch, svs[j], 0x0D, quality, int(obs.cno_dbhz[i, j]),
                                int(round(obs.elevation_deg[i, j])),
                                int(round(obs.azimuth_deg[i, j])) % 360,
                                int(rng.normal(0, 40))))
            uart.send(ready, "NAV-SVINFO", ubx.nav_svinfo(tow_ms, sv_rows), tow_ms)
        # A subframe completes every 6 s; it is output with the epoch after the boundary.
        if tow_ms % 6000 == int(interval // 1_000_000) and i > epochs_per_sf:
            boundary = t - interval
            start_tow_s = (boundary // NS_PER_S) % 604_800 - 6
            tx_week = (boundary - 6 * NS_PER_S) // NS_PER_WEEK
            first = i - 1 - epochs_per_sf
            for ch, j in enumerate(cols):
                if not obs.tracked[first : i, j].all():
                    continue
                eph = constellation.ephemeris_at(svs[j], boundary)
                words = subframe_for(eph, constellation.iono, tx_week, int(start_tow_s))
                uart.send(ready, "RXM-SFRB", ubx.rxm_sfrb(ch, svs[j], words), svs[j])
    return uart.out


def _marks(
    trajectory: Trajectory,
    start_gps_ns: int,
    interval_ns: int,
    rng: np.random.Generator,
) -> tuple[list[MarkTruth], list[tuple[int, int, bytes]]]:
    """Exposure truth and the TIM-TM2 messages, each keyed by the epoch it is output with."""
    truth: list[MarkTruth] = []
    out: list[tuple[int, int, bytes]] = []
    prev_rising: int | None = None
    for k, exp in enumerate(trajectory.exposures()):
        f = start_gps_ns + round(exp.t_s * NS_PER_S)
        r = f + MARK_PULSE_NS + int(rng.normal(0, 200_000))
        pos, _ = trajectory.ecef(np.array([exp.t_s]))
        count = k + 1
        truth.append(MarkTruth(k, count, exp.line, f, r,
                               (float(pos[0, 0]), float(pos[0, 1]), float(pos[0, 2]))))
        f_meas = f + int(rng.normal(0, 15))
        r_meas = r + int(rng.normal(0, 15))

        def epoch_after(t: int) -> int:
            return start_gps_ns + -(-(t - start_gps_ns) // interval_ns) * interval_ns

        ef, er = epoch_after(f), epoch_after(r)
        if ef == er:
            out.append((ef, count, ubx.tim_tm2(count, r_meas, f_meas, True, True)))
        else:
            out.append((ef, count, ubx.tim_tm2(count - 1, prev_rising, f_meas, False, True)))
            out.append((er, count, ubx.tim_tm2(count, r_meas, f_meas, True, False)))
        prev_rising = r_meas
    out.sort(key=lambda m: m[0])
    return truth, out


def simulate(config: SimConfig) -> SimResult:
    """Run the simulation: constellation, receivers, messages, faults and truth."""
    seeds = np.random.SeedSequence(config.seed).spawn(6)
    rngs = [np.random.default_rng(s) for s in seeds]
    traj_cfg = (
        TrajectoryConfig.for_duration(config.duration_s, config.trajectory)
        if config.duration_s is not None
        else config.trajectory
    )
    trajectory = Trajectory(traj_cfg)
    interval_ns = NS_PER_S // config.rate_hz
    start = (config.start_gps_ns // interval_ns) * interval_ns
    n_epochs = int(trajectory.duration_s * config.rate_hz) + 1
    end = start + (n_epochs - 1) * interval_ns
    constellation = make_constellation(config.seed, start, end, config.n_satellites)

    def rover_pos(t_s: np.ndarray[Any, np.dtype[np.float64]]) -> tuple[Any, Any]:
        return trajectory.ecef(t_s)

    def flying(t_s: np.ndarray[Any, np.dtype[np.float64]]) -> Any:
        return (t_s >= trajectory.takeoff_s) & (t_s < trajectory.landing_s)

    rover_obs = observe(constellation, config.rover, start, n_epochs, interval_ns, rover_pos,
                        flying, rngs[0], turns=trajectory.turns())
    mark_truth, mark_msgs = _marks(trajectory, start, interval_ns, rngs[1])
    _, rover_vel = trajectory.ecef((rover_obs.t_rx_ns - start) / NS_PER_S)
    rover_msgs = _messages(rover_obs, constellation, rover_vel, mark_msgs, rngs[2], config.baud)

    base_obs = None
    base_msgs: list[TimedMessage] = []
    base_ecef = trajectory.enu_to_ecef(config.base_enu_m)
    if config.with_base:
        base_arr = np.asarray(base_ecef, dtype=np.float64)

        def base_pos(t_s: np.ndarray[Any, np.dtype[np.float64]]) -> tuple[Any, Any]:
            shape = np.shape(t_s) + (3,)
            return np.broadcast_to(base_arr, shape).copy(), np.zeros(shape)

        def static(t_s: np.ndarray[Any, np.dtype[np.float64]]) -> Any:
            return np.zeros(np.shape(t_s), dtype=bool)

        base_obs = observe(constellation, config.base, start, n_epochs, interval_ns, base_pos,
                           static, rngs[3])
        base_msgs = _messages(base_obs, constellation, np.zeros((n_epochs, 3)), [], rngs[4],
                              config.baud)

    sent, mark_faults = apply_mark_faults(rover_msgs, config.faults, rngs[5])
    flight_ns = (start + round(trajectory.takeoff_s * NS_PER_S),
                 start + round(trajectory.landing_s * NS_PER_S))
    rover_chunks, fault_log = apply_link_faults(sent, config.faults, rngs[5], config.baud,
                                                flight_ns=flight_ns)
    fault_log.faults = sorted(
        mark_faults + fault_log.faults,
        key=lambda f: f.get("t_gps_ns", f.get("start_gps_ns", 0)),
    )
    base_chunks = [(m.t_gps_ns, m.raw) for m in base_msgs]

    truth = _truth(config, traj_cfg, trajectory, start, end, constellation, mark_truth,
                   base_ecef if config.with_base else None, rover_obs, base_obs, fault_log,
                   sent)
    return SimResult(rover_chunks, base_chunks, truth, rover_msgs, base_msgs, fault_log,
                     constellation, rover_obs, base_obs)


def _truth(
    config: SimConfig,
    traj_cfg: TrajectoryConfig,
    trajectory: Trajectory,
    start: int,
    end: int,
    constellation: Constellation,
    marks: list[MarkTruth],
    base_ecef: tuple[float, float, float] | None,
    rover_obs: Observations,
    base_obs: Observations | None,
    fault_log: FaultLog,
    sent: list[TimedMessage],
) -> dict[str, Any]:
    step_ns = NS_PER_S // config.truth_rate_hz
    t_ns = np.arange(start - NS_PER_S, end + NS_PER_S + 1, step_ns, dtype=np.int64)
    pos, vel = trajectory.ecef((t_ns - start) / NS_PER_S)
    sent_counts = sorted({m.tag for m in sent if m.name == "TIM-TM2"})
    missed = sorted(f["count"] for f in fault_log.faults if f["kind"] == "missed_mark")
    duplicated = sorted(f["count"] for f in fault_log.faults if f["kind"] == "duplicate_mark")

    def receiver(obs: Observations, lost_tow_ms: set[int]) -> dict[str, Any]:
        # A slip is visible on the ground only if the epoch whose LLI carries it arrived
        # (RXM-RAW has no lock time to tell later).
        events = [
            {**asdict(e), "visible": (e.t_rx_ns % NS_PER_WEEK) // 1_000_000 not in lost_tow_ms}
            for e in obs.events
        ]
        slips = [e for e in events if e["kind"] == "slip"]
        return {
            "epochs": int(len(obs.t_rx_ns)),
            "first_tow_ms": int((obs.t_rx_ns[0] % NS_PER_WEEK) // 1_000_000),
            "clock_bias_s_first": float(obs.clock_bias_s[0]),
            "clock_bias_s_last": float(obs.clock_bias_s[-1]),
            "lock_events": events,
            "slips": len(slips),
            "slips_hidden": sum(not e["visible"] for e in slips),
            "shadows": [asdict(sh) for sh in obs.shadows],
            "half_cycle_epochs": int(((obs.lli & 2) > 0).sum()),
            "slip_epochs": int(((obs.lli & 1) > 0).sum()),
        }

    return {
        "schema": TRUTH_SCHEMA,
        "seed": config.seed,
        "profile": {"name": config.profile, "severity": config.severity},
        "start_gps_ns": int(start),
        "end_gps_ns": int(end),
        "rate_hz": config.rate_hz,
        "site_llh": list(traj_cfg.site_llh),
        "trajectory_config": asdict(traj_cfg),
        "phases": {
            "takeoff_gps_ns": start + round(trajectory.takeoff_s * NS_PER_S),
            "landing_gps_ns": start + round(trajectory.landing_s * NS_PER_S),
        },
        "turns": [{"t_gps_ns": start + round(turn.t_s * NS_PER_S),
                   "away_azimuth_deg": turn.away_azimuth_deg} for turn in trajectory.turns()],
        "base": None if base_ecef is None else {
            "ecef_m": list(base_ecef),
            "llh": list(ecef_to_llh(*base_ecef)),
        },
        "trajectory": {
            "rate_hz": config.truth_rate_hz,
            "t_gps_ns": t_ns.tolist(),
            "x_m": pos[:, 0].round(4).tolist(),
            "y_m": pos[:, 1].round(4).tolist(),
            "z_m": pos[:, 2].round(4).tolist(),
            "speed_m_s": np.linalg.norm(vel, axis=1).round(3).tolist(),
        },
        "exposures": [
            # "number": the receiver's mark number, as the exports' mark_count and mark_NNNN
            # name it ("count" is the raw TIM-TM2 count of its rising-edge record, one more)
            {**asdict(m), "number": m.count - 1, "ecef_m": list(m.ecef_m),
             "sent": m.count in sent_counts,
             "missed": m.count in missed, "duplicated": m.count in duplicated}
            for m in marks
        ],
        "receivers": {
            "rover": receiver(rover_obs, set(fault_log.epochs_lost_tow_ms)),
            **({"base": receiver(base_obs, set())} if base_obs is not None else {}),
        },
        "faults_config": asdict(config.faults),
        "faults": fault_log.faults,
        "fault_summary": {k: v for k, v in fault_log.to_json().items() if k != "faults"},
        "iono": asdict(constellation.iono),
        "ephemerides": [asdict(e) for e in constellation.all_ephemerides()],
    }

