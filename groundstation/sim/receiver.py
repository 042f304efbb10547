"""A simulated L1 receiver: clock, tracking, squaring loop and the raw observations it measures.

Observation model (RINEX sign conventions, as u-blox RXM-RAW reports them):

- pseudorange ``P = rho + c (dt_r - dt_s + TGD) + I + T + e_P``
- carrier phase ``L = (rho + c (dt_r - dt_s) - I + T) / lambda + N (+ 1/2 while the half-cycle
  ambiguity is unresolved) + e_L`` cycles
- Doppler ``D = -d/dt(rho + c (dt_r - dt_s)) / lambda`` Hz (positive when approaching)

``rho`` is the geometric range from the satellite at transmission time, rotated into the ECEF frame
of the reception time (Earth rotation during the signal's travel), to the antenna at the *true*
reception time ``t = t_rx - dt_r``; the satellite clock includes the relativistic correction.

Lock model: the default (:class:`SquaringModel` alone) is a gentle flight where a slip re-draws the
ambiguity. With :class:`FlightLossModel` (the ``seed`` profile, modelled on the field report's
failed flight) every satellite loses lock in flight at a given mean interval; the phase keeps its
ambiguity plus a recorded jump of whole or half cycles, the half-cycle flag follows each loss,
and with :class:`ShadowModel` low satellites on the outside of each turn are not tracked.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from groundstation.geodesy import ecef_to_llh, enu_rotation
from groundstation.gnss.atmosphere import saastamoinen_delay_m, smooth_ionosphere_delay_m
from groundstation.gnss.orbit import (
    C_M_S,
    L1_WAVELENGTH_M,
    rotate_earth,
    sat_state,
    toe_gps_ns,
)
from groundstation.gpstime import NS_PER_S, NS_PER_WEEK
from groundstation.sim.constellation import Constellation
from groundstation.sim.trajectory import Turn

FloatArray = NDArray[np.float64]
PositionFn = Callable[[FloatArray], tuple[FloatArray, FloatArray]]
"""Seconds since the simulation start (true GPS time) -> (ECEF position, ECEF velocity)."""

MAX_CHANNELS = 16


@dataclass(frozen=True, slots=True)
class SquaringModel:
    """Half-cycle and slip behaviour of the squaring carrier loop.

    Attributes:
        half_cycle_mean_s: mean time until the half-cycle ambiguity is resolved after lock,
            static and in flight (exponential, plus ``half_cycle_min_s``).
        half_cycle_min_s: shortest unresolved period (the receiver needs a preamble).
        slip_rate_per_h: cycle slips (loss of lock) per satellite and hour, static and flight.
        acquisition_s: delay from rising above the mask to the first measurement.
    """

    half_cycle_mean_s: tuple[float, float] = (2.0, 4.0)
    half_cycle_min_s: float = 0.6
    slip_rate_per_h: tuple[float, float] = (0.3, 12.0)
    acquisition_s: float = 3.0


@dataclass(frozen=True, slots=True)
class FlightLossModel:
    """Losses of lock in flight as in the field report's failed flight (none when static).

    Attributes:
        mean_interval_s: mean time between losses of lock of one satellite in flight
            (exponential; the ``seed`` profile's severity divides it).
        half_cycle_s: the half-cycle flag (LLI bit 1) lasts a uniform time in this range after
            each loss, or until the next loss.
        inverted_prob: probability that the loop relocks with inverted polarity, i.e. half a
            cycle off until the flag clears (the phase then jumps back by half a cycle).
        small_jump_prob: probability that the whole-cycle jump is within +-2 cycles (0 included:
            a loss of lock need not move the phase); otherwise within +-``max_jump_cyc``.
        max_jump_cyc: largest whole-cycle jump.
    """

    mean_interval_s: float = 20.0
    half_cycle_s: tuple[float, float] = (2.0, 10.0)
    inverted_prob: float = 0.5
    small_jump_prob: float = 0.3
    max_jump_cyc: int = 200


@dataclass(frozen=True, slots=True)
class ShadowModel:
    """Low satellites on the outside of a turn are hidden by the airframe while it banks.

    Attributes:
        duration_s: how long each turn shadows them.
        below_elevation_deg: satellites lower than this can be shadowed.
        half_width_deg: ... if their azimuth is within this of the side the copter banks away from.
    """

    duration_s: float = 10.0
    below_elevation_deg: float = 25.0
    half_width_deg: float = 90.0


@dataclass(frozen=True, slots=True)
class Blockage:
    """The sky hidden from the antenna for a while: a bridge, a tree canopy, a building the
    copter flies past. Every satellite lower than ``below_elevation_deg`` (90: all of them) is
    lost from ``start_s`` (seconds since the first epoch) for ``duration_s``; each is
    reacquired afterwards with a new ambiguity (a loss of lock, LLI bit 0).
    """

    start_s: float
    duration_s: float
    below_elevation_deg: float = 90.0


@dataclass(frozen=True, slots=True)
class ReceiverConfig:
    """One receiver's characteristics.

    Attributes:
        name: ``rover`` or ``base``.
        clock_bias_s: clock offset at the start (receiver time minus GPS time).
        clock_drift_s_s: clock drift (s/s).
        clock_walk_s_s_sqrt_s: random-walk density of the drift.
        elevation_mask_deg: satellites below are not tracked.
        code_sigma_m: pseudorange noise at 45 dBHz.
        phase_sigma_m: carrier-phase noise at 45 dBHz.
        doppler_sigma_hz: Doppler noise at 45 dBHz.
        cno_offset_db: added to the elevation-dependent C/N0 (antenna, airframe).
        flight_cno_drop_db: C/N0 lost in flight (propellers, banking, motor interference).
        squaring: the carrier-loop model.
        flight_losses: frequent in-flight losses of lock (replaces the squaring model's slips).
        shadow: airframe shadowing in turns.
        blockages: spells of a hidden sky (:class:`Blockage`).
    """

    name: str
    clock_bias_s: float = 1.5e-4
    clock_drift_s_s: float = 2.0e-8
    clock_walk_s_s_sqrt_s: float = 2.0e-11
    elevation_mask_deg: float = 7.0
    code_sigma_m: float = 0.3
    phase_sigma_m: float = 0.002
    doppler_sigma_hz: float = 0.05
    cno_offset_db: float = 0.0
    flight_cno_drop_db: float = 2.0
    squaring: SquaringModel = field(default_factory=SquaringModel)
    flight_losses: FlightLossModel | None = None
    shadow: ShadowModel | None = None
    blockages: tuple[Blockage, ...] = ()


@dataclass(frozen=True, slots=True)
class LockEvent:
    """A loss of lock (cycle slip) or a new acquisition, for the truth file.

    ``t_rx_ns`` is the epoch whose LLI carries bit 0. With a :class:`FlightLossModel`, a slip also
    records the true phase jump at that epoch (cycles, whole or half), whether the loop relocked
    half a cycle off, and where the half-cycle flag cleared with the jump it made there.
    """

    sv: int
    t_rx_ns: int
    kind: str  # "acquired" | "slip" | "reacquired" (after a shadow)
    half_cycle_s: float
    jump_cyc: float | None = None
    half_cycle_inverted: bool = False
    resolve_t_rx_ns: int | None = None
    resolve_jump_cyc: float = 0.0


@dataclass(frozen=True, slots=True)
class ShadowEvent:
    """A satellite hidden by the airframe in a turn: not tracked in ``[start, end)``."""

    sv: int
    start_t_rx_ns: int
    end_t_rx_ns: int
    turn: int


@dataclass(slots=True)
class Observations:
    """Everything a receiver measured; arrays are (epochs, satellites) unless noted.

    ``svs`` gives the column order. ``tracked`` marks the measurements reported.
    """

    name: str
    svs: tuple[int, ...]
    t_rx_ns: NDArray[np.int64]  # (epochs,) receiver time tags, GPS ns
    clock_bias_s: FloatArray  # (epochs,)
    pos_ecef_m: FloatArray  # (epochs, 3) at true reception time
    tracked: NDArray[np.bool_]
    pseudorange_m: FloatArray
    carrier_phase_cyc: FloatArray
    doppler_hz: FloatArray
    cno_dbhz: NDArray[np.int8]
    lli: NDArray[np.uint8]
    mes_qi: NDArray[np.int8]
    elevation_deg: FloatArray
    azimuth_deg: FloatArray
    events: list[LockEvent]
    shadows: list[ShadowEvent] = field(default_factory=list)


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of a 1-D mask."""
    padded = np.concatenate(([False], mask, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def observe(
    constellation: Constellation,
    config: ReceiverConfig,
    start_gps_ns: int,
    n_epochs: int,
    interval_ns: int,
    position: PositionFn,
    in_flight: Callable[[FloatArray], NDArray[np.bool_]],
    rng: np.random.Generator,
    iono_scale: float = 1.1,
    turns: Sequence[Turn] = (),
) -> Observations:
    """Simulate one receiver's raw measurements at ``n_epochs`` epochs.

    Args:
        constellation: satellites and ephemerides.
        config: the receiver.
        start_gps_ns: first epoch (receiver time tag, on the ``interval_ns`` grid).
        n_epochs: number of epochs.
        interval_ns: measurement interval (200 ms for 5 Hz).
        position: antenna ECEF position and velocity at seconds since ``start_gps_ns``.
        in_flight: whether each of those times is in flight (for the squaring model).
        rng: the random generator (the caller seeds it).
        iono_scale: true ionosphere relative to the broadcast model's amplitude (the true one
            is continuous, :func:`~groundstation.gnss.atmosphere.smooth_ionosphere_delay_m`).
        turns: the rover's turns, for the shadow model (seconds since ``start_gps_ns``).
    """
    svs = constellation.svs
    n_sv = len(svs)
    t_rx_ns = start_gps_ns + np.arange(n_epochs, dtype=np.int64) * interval_ns
    t_rel_s = (t_rx_ns - start_gps_ns) / NS_PER_S
    dt_s = interval_ns / NS_PER_S
    walk = np.cumsum(rng.normal(0.0, config.clock_walk_s_s_sqrt_s * np.sqrt(dt_s), n_epochs))
    drift = config.clock_drift_s_s + walk
    bias = config.clock_bias_s + np.concatenate(([0.0], np.cumsum(drift[:-1] * dt_s)))
    t_true_s = t_rel_s - bias
    pos, vel = position(t_true_s)
    lat, lon, h = ecef_to_llh(*(float(v) for v in pos[0]))
    rot = np.array(enu_rotation(lat, lon), dtype=np.float64)
    # Height of every epoch (the rover climbs 30 m: the troposphere must follow it).
    h_epoch = h + (pos - pos[0]) @ rot[2]
    flying = in_flight(t_true_s)
    tow_s = ((t_rx_ns % NS_PER_WEEK) / NS_PER_S).astype(np.float64)

    shape = (n_epochs, n_sv)
    pr = np.zeros(shape)
    cp = np.zeros(shape)
    dop = np.zeros(shape)
    el = np.full(shape, -90.0)
    az = np.zeros(shape)
    cno = np.zeros(shape, dtype=np.int8)
    lli = np.zeros(shape, dtype=np.uint8)
    mesqi = np.zeros(shape, dtype=np.int8)
    tracked = np.zeros(shape, dtype=bool)
    events: list[LockEvent] = []
    shadows: list[ShadowEvent] = []
    sq = config.squaring
    losses = config.flight_losses

    for j, sv in enumerate(svs):
        # Which ephemeris issue the receiver would use at each epoch (nearest toe).
        issues = constellation.ephemerides[sv]
        toes = np.array([toe_gps_ns(e) for e in issues], dtype=np.int64)
        which = np.argmin(np.abs(t_rx_ns[:, None] - toes[None, :]), axis=1)
        rho = np.zeros(n_epochs)
        rho_dot = np.zeros(n_epochs)
        clk = np.zeros(n_epochs)
        clk_dot = np.zeros(n_epochs)
        los_enu = np.zeros((n_epochs, 3))
        tgd = np.zeros(n_epochs)
        for k, eph in enumerate(issues):
            sel = which == k
            if not np.any(sel):
                continue
            # True reception time relative to toe (ns integers first, then seconds).
            dt_toe = (t_rx_ns[sel] - toes[k]) / NS_PER_S - bias[sel]
            tau = np.full(dt_toe.shape, 0.075)
            for _ in range(3):
                st = sat_state(eph, dt_toe - tau)
                sat_pos = rotate_earth(st.pos_m, tau)
                diff = sat_pos - pos[sel]
                rng_m = np.linalg.norm(diff, axis=1)
                tau = rng_m / C_M_S
            sat_vel = rotate_earth(st.vel_m_s, tau)
            u = diff / rng_m[:, None]
            rho[sel] = rng_m
            rho_dot[sel] = np.einsum("ij,ij->i", u, sat_vel - vel[sel])
            clk[sel] = st.clock_s
            clk_dot[sel] = st.clock_drift_s_s
            los_enu[sel] = u @ rot.T
            tgd[sel] = eph.tgd_s
        elev = np.degrees(np.arcsin(np.clip(los_enu[:, 2], -1.0, 1.0)))
        azim = np.degrees(np.arctan2(los_enu[:, 0], los_enu[:, 1])) % 360.0
        el[:, j] = elev
        az[:, j] = azim
        visible = elev >= config.elevation_mask_deg
        # The broadcast model's shape without its step (a real ionosphere is smooth), so
        # receivers a few hundred metres apart see nearly the same delay at the same time.
        iono = iono_scale * smooth_ionosphere_delay_m(
            constellation.iono.alpha, constellation.iono.beta, lat, lon, azim,
            np.maximum(elev, 0.0), tow_s,
        )
        trop = 1.02 * saastamoinen_delay_m(lat, h_epoch, np.maximum(elev, 1.0))
        sin_el = np.sin(np.radians(np.clip(elev, 0.0, 90.0)))
        cno_f = 30.0 + 19.0 * sin_el**0.5 + config.cno_offset_db + rng.normal(0, 0.7, n_epochs)
        cno_f -= config.flight_cno_drop_db * flying
        cno_i = np.clip(np.round(cno_f), 15, 55).astype(np.int8)
        scale = 10.0 ** ((45.0 - cno_i.astype(np.float64)) / 20.0)
        clock_term = C_M_S * (bias - clk)
        pr_j = rho + clock_term + C_M_S * tgd + iono + trop
        pr_j += rng.normal(0.0, 1.0, n_epochs) * config.code_sigma_m * scale
        ph_m = rho + clock_term - iono + trop
        ph_m += rng.normal(0.0, 1.0, n_epochs) * config.phase_sigma_m * scale
        dop_j = -(rho_dot + C_M_S * (drift - clk_dot)) / L1_WAVELENGTH_M
        dop_j += rng.normal(0.0, 1.0, n_epochs) * config.doppler_sigma_hz * scale
        cyc = ph_m / L1_WAVELENGTH_M

        shadowed = _shadowed(config.shadow, turns, t_true_s, elev, azim)
        for a, b in _runs(shadowed & visible):
            turn = _turn_at(turns, float(t_true_s[a]))
            end = int(t_rx_ns[b]) if b < n_epochs else int(t_rx_ns[-1]) + interval_ns
            shadows.append(ShadowEvent(sv, int(t_rx_ns[a]), end, turn))
        off = np.zeros(n_epochs)  # ambiguity plus any half-cycle offset, cycles
        half = np.zeros(n_epochs, dtype=bool)
        slip = np.zeros(n_epochs, dtype=bool)
        track = np.zeros(n_epochs, dtype=bool)
        acq_epochs = int(round(sq.acquisition_s / dt_s))
        hidden = shadowed | _blocked(config.blockages, t_rel_s, elev)
        for a, b in _runs(visible & ~hidden):
            # Back from a shadow the receiver reacquires at once (it still has the satellite).
            back = a > 0 and bool(hidden[a - 1])
            a = a + acq_epochs if a > 0 and not back else a
            if a >= b:
                continue
            track[a:b] = True
            if losses is None:
                # Lock segments: split the run at cycle slips (rate depends on flight state).
                rates = np.where(flying[a + 1 : b], sq.slip_rate_per_h[1], sq.slip_rate_per_h[0])
                hits = np.flatnonzero(rng.random(b - a - 1) < rates / 3600.0 * dt_s) + a + 1
            else:
                p = dt_s / losses.mean_interval_s if losses.mean_interval_s > 0 else 0.0
                hits = np.flatnonzero(flying[a + 1 : b] & (rng.random(b - a - 1) < p)) + a + 1
            bounds = [a, *(int(i) for i in hits), b]
            for s0, s1 in zip(bounds[:-1], bounds[1:], strict=True):
                if losses is None or s0 == a:
                    mean = sq.half_cycle_mean_s[1 if flying[s0] else 0]
                    hc_s = sq.half_cycle_min_s + float(rng.exponential(mean))
                    n_half = min(s1 - s0, int(np.ceil(hc_s / dt_s)))
                    # Integer ambiguity: the receiver starts the phase near the code (cycles).
                    n_int = np.round(pr_j[s0] / L1_WAVELENGTH_M - cyc[s0]) + rng.integers(-5, 6)
                    off[s0:s1] = n_int
                    off[s0 : s0 + n_half] += 0.5
                    half[s0 : s0 + n_half] = True
                    slip[s0] = True
                    kind = "acquired" if s0 == a else "slip"
                    cleared = s0 + n_half
                    events.append(LockEvent(
                        sv, int(t_rx_ns[s0]), "reacquired" if back and s0 == a else kind, hc_s,
                        half_cycle_inverted=True,
                        resolve_t_rx_ns=int(t_rx_ns[cleared]) if cleared < s1 else None,
                        resolve_jump_cyc=-0.5 if cleared < s1 else 0.0,
                    ))
                    continue
                events.append(_flight_loss(losses, rng, s0, s1, dt_s, t_rx_ns, off, half, slip,
                                           sv))
        cp_j = cyc + off
        order_ok = track
        tracked[:, j] = order_ok
        pr[:, j] = np.where(order_ok, pr_j, 0.0)
        cp[:, j] = np.where(order_ok, cp_j, 0.0)
        dop[:, j] = np.where(order_ok, dop_j, 0.0)
        cno[:, j] = np.where(order_ok, cno_i, 0)
        lli[:, j] = np.where(order_ok, slip.astype(np.uint8) | (half.astype(np.uint8) << 1), 0)
        mesqi[:, j] = np.where(order_ok, np.where(slip, 5, np.where(half, 6, 7)), 0)

    # A LEA-6T has 16 channels: keep the highest satellites when more are visible.
    over = tracked.sum(axis=1) > MAX_CHANNELS
    for i in np.flatnonzero(over):
        keep = np.argsort(-np.where(tracked[i], el[i], -999.0))[:MAX_CHANNELS]
        row = np.zeros(n_sv, dtype=bool)
        row[keep] = True
        tracked[i] &= row

    return Observations(
        name=config.name,
        svs=svs,
        t_rx_ns=t_rx_ns,
        clock_bias_s=bias,
        pos_ecef_m=pos,
        tracked=tracked,
        pseudorange_m=pr,
        carrier_phase_cyc=cp,
        doppler_hz=dop,
        cno_dbhz=cno,
        lli=lli,
        mes_qi=mesqi,
        elevation_deg=el,
        azimuth_deg=az,
        events=events,
        shadows=shadows,
    )


def _flight_loss(
    model: FlightLossModel,
    rng: np.random.Generator,
    s0: int,
    s1: int,
    dt_s: float,
    t_rx_ns: NDArray[np.int64],
    off: FloatArray,
    half: NDArray[np.bool_],
    slip: NDArray[np.bool_],
    sv: int,
) -> LockEvent:
    """A loss of lock at epoch ``s0`` of a segment ending at ``s1``: jump, half-cycle flag."""
    if rng.random() < model.small_jump_prob:
        jump = int(rng.integers(-2, 3))
    else:
        jump = int(rng.integers(1, model.max_jump_cyc + 1)) * (1 if rng.random() < 0.5 else -1)
    hc_s = float(rng.uniform(*model.half_cycle_s))
    inverted = bool(rng.random() < model.inverted_prob)
    n_half = min(s1 - s0, int(np.ceil(hc_s / dt_s - 1e-9)))
    # The ambiguity continues from the previous epoch's (a half cycle the previous lock still
    # carried is the receiver's, not the ambiguity's: drop it).
    before = float(off[s0 - 1])
    base = before - 0.5 if half[s0 - 1] and before % 1.0 == 0.5 else before
    off[s0:s1] = base + jump
    if inverted:
        off[s0 : s0 + n_half] += 0.5
    half[s0 : s0 + n_half] = True
    slip[s0] = True
    cleared = s0 + n_half
    resolve = cleared < s1
    return LockEvent(
        sv, int(t_rx_ns[s0]), "slip", n_half * dt_s,
        jump_cyc=float(off[s0] - before),
        half_cycle_inverted=inverted,
        resolve_t_rx_ns=int(t_rx_ns[cleared]) if resolve else None,
        resolve_jump_cyc=float(off[cleared] - off[cleared - 1]) if resolve else 0.0,
    )


def _shadowed(
    model: ShadowModel | None,
    turns: Sequence[Turn],
    t_s: FloatArray,
    elev: FloatArray,
    azim: FloatArray,
) -> NDArray[np.bool_]:
    """Epochs at which the airframe hides this satellite (low, outside the turn)."""
    out = np.zeros(t_s.shape, dtype=bool)
    if model is None:
        return out
    low = elev < model.below_elevation_deg
    for turn in turns:
        away = np.abs((azim - turn.away_azimuth_deg + 180.0) % 360.0 - 180.0)
        during = (t_s >= turn.t_s) & (t_s < turn.t_s + model.duration_s)
        out |= during & low & (away <= model.half_width_deg)
    return out


def _blocked(blockages: Sequence[Blockage], t_s: FloatArray, elev: FloatArray,
             ) -> NDArray[np.bool_]:
    """Epochs at which a blockage hides this satellite."""
    out = np.zeros(t_s.shape, dtype=bool)
    for b in blockages:
        out |= (t_s >= b.start_s) & (t_s < b.start_s + b.duration_s) & (
            elev < b.below_elevation_deg)
    return out


def _turn_at(turns: Sequence[Turn], t_s: float) -> int:
    """Index of the last turn that started at or before ``t_s``."""
    return max((i for i, turn in enumerate(turns) if turn.t_s <= t_s), default=-1)
