"""Named simulation profiles: today's gentle ``default`` flight and the field report's ``seed``.

The ``seed`` profile is the flight the original project failed on (docs/simulator.md): 30 % of the
span static at each end (15 min of a 50 min recording), in between a lever-arm calibration pass at
15 m, lawnmower lines at 30 m and a second calibration pass; every
satellite losing lock in flight on average every 20 s (divided by ``severity``) with whole- and
half-cycle jumps and 2-10 s of half-cycle flags, C/N0 5 dB lower in flight, low satellites
shadowed for 10 s in each turn, and about 300 radio gaps per 20 min of flight
(:meth:`~groundstation.sim.faults.FaultConfig.seed`).
"""

from __future__ import annotations

import math
from dataclasses import replace

from groundstation.errors import ConfigError
from groundstation.sim.faults import FaultConfig
from groundstation.sim.receiver import FlightLossModel, ShadowModel
from groundstation.sim.stream import SimConfig
from groundstation.sim.trajectory import TrajectoryConfig

PROFILES = ("default", "seed")
DEFAULT_DURATION_S = {"default": 600.0, "seed": 3000.0}
"""Span when none is given: the default's 10 min, the seed's 15 + 20 + 15 min."""
DEFAULT_FAULTS = {"default": "none", "seed": "seed"}
"""The ``--faults`` spec a profile implies when none is given."""
SEED_STATIC_FRACTION = 0.3
SEED_LOSS_INTERVAL_S = 20.0
MAX_SEVERITY = 50.0
"""At 50 a satellite loses lock every 0.4 s on average: two epochs at 5 Hz."""

SEED_TRAJECTORY = TrajectoryConfig(
    height_m=30.0,
    speed_m_s=2.0,
    line_length_m=100.0,
    line_spacing_m=20.0,
    n_lines=60,  # for_duration trims this to what the flight time holds
    exposure_spacing_m=2.0,  # a photo a second at 2 m/s
    calibration_height_m=15.0,
)


def sim_config(
    profile: str = "default",
    *,
    duration_s: float | None = None,
    seed: int = 1,
    severity: float = 1.0,
    faults: FaultConfig | None = None,
    with_base: bool = True,
) -> SimConfig:
    """The :class:`SimConfig` of a named profile.

    Args:
        profile: ``default`` or ``seed``.
        duration_s: total span (static ends included); ``None`` takes the profile's.
        seed: random seed.
        severity: the seed profile's loss-of-lock rate relative to the field flight's
            (1 = every 20 s per satellite, 0.5 half as often, 2 twice; 0 none).
        faults: link and mark faults; ``None`` takes the profile's (:data:`DEFAULT_FAULTS`).
        with_base: also simulate the base receiver.

    Raises:
        ConfigError: unknown profile (key ``profile``), a severity out of range or given to the
            default profile (key ``severity``).
    """
    if profile not in PROFILES:
        raise ConfigError("profile", f"unknown profile {profile!r} (one of {', '.join(PROFILES)})")
    if not (math.isfinite(severity) and 0.0 <= severity <= MAX_SEVERITY):
        raise ConfigError("severity", f"must be between 0 and {MAX_SEVERITY:g}, not {severity:g}")
    if profile == "default" and severity != 1.0:
        raise ConfigError("severity", "only the seed profile has a severity")
    span = DEFAULT_DURATION_S[profile] if duration_s is None else duration_s
    link = FaultConfig.load(DEFAULT_FAULTS[profile]) if faults is None else faults
    if profile == "default":
        return SimConfig(duration_s=span, seed=seed, faults=link, with_base=with_base)
    base = SimConfig()
    interval = SEED_LOSS_INTERVAL_S / severity if severity > 0 else math.inf
    rover = replace(
        base.rover,
        flight_cno_drop_db=5.0,
        flight_losses=FlightLossModel(mean_interval_s=interval),
        shadow=ShadowModel(),
    )
    trajectory = TrajectoryConfig.for_duration(span, SEED_TRAJECTORY, SEED_STATIC_FRACTION)
    return SimConfig(duration_s=None, trajectory=trajectory, seed=seed, faults=link,
                     with_base=with_base, rover=rover, profile=profile, severity=severity)
