"""The monitor's satellites: C/N0, elevation, lock time, slips, half cycles, clean phase, PPK-ready.

A measurement without a satellite number (a GLONASS satellite whose slot the receiver does not
know yet, u-blox svId 255) is counted apart (:attr:`Satellites.unidentified`), never listed or
counted as a tracked satellite; an elevation the receiver does not know (-91) is ``None``.

Slips and half cycles are the phase rule's (:mod:`groundstation.rules.phase`): the decoder gives
each measurement the same LLI the RINEX file gets, and
:func:`~groundstation.rules.phase.phase_events` turns a signal's LLI sequence into events.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from groundstation import events as kinds
from groundstation.config import MonitorSettings
from groundstation.gpstime import NS_PER_S
from groundstation.records import (
    Event,
    RawEpoch,
    SatStatus,
    SvInfo,
    identified,
    known_elevation,
)
from groundstation.rules.phase import SIGNAL_LOST_AFTER_EPOCHS, phase_events

SLIPPED_FOR_S = 30.0
"""A satellite shows as ``slipped`` this long after its last slip."""


@dataclass(slots=True)
class _Sat:
    sv: str
    first_seen_ns: int
    last_seen_ns: int
    lock_since_ns: int
    clean_since_ns: int | None
    cno: int = 0
    mes_qi: int | None = None
    half: bool = False
    slips: int = 0
    last_slip_ns: int | None = None
    has_phase: bool = True
    absent: int = 0  # consecutive received epochs without this satellite


class Counts(NamedTuple):
    """The satellites' figures a status carries."""

    ready: int
    """PPK-ready: clean phase long enough, at or above the elevation mask."""
    tracked: int
    """Satellites tracked with one signal each (no SBAS, no unidentified measurement)."""
    half: int
    """Tracked satellites with an unresolved half cycle."""
    below_mask: int
    """Tracked satellites whose known elevation is below the mask (never PPK-ready)."""


class Satellites:
    """Per-signal tracking state, fed with the epochs the link accepted."""

    def __init__(self, th: MonitorSettings) -> None:
        self.th = th
        self.sats: dict[str, _Sat] = {}
        self._svinfo: dict[str, tuple[int | None, int | None, bool]] = {}
        self.unidentified = 0
        """Measurements in the latest epoch without a satellite number (GLONASS slot unknown)."""

    def on_svinfo(self, item: SvInfo) -> None:
        for s in item.sats:
            if not identified(s.gnss, s.sv):
                continue
            el = known_elevation(s.elev_deg)
            # an unknown elevation comes with azimuth 0: no direction either
            self._svinfo[s.label] = (el, s.azim_deg if el is not None else None, s.used)

    def on_epoch(self, ep: RawEpoch, now_ns: int, events: list[Event]) -> None:
        # A satellite counts as lost only when it is missing from epochs that did arrive: a link
        # dropout says nothing about the receiver's tracking (RTKLIB keeps ambiguities across
        # an outage of up to 5 epochs, and the receiver flags a slip when lock really broke).
        t = ep.t_gps_ns
        seen = set()
        self.unidentified = 0
        for s in ep.sats:
            if not identified(s.gnss, s.sv):
                self.unidentified += 1
                continue
            label = s.label if s.sig_id == 0 else f"{s.label}/{s.sig_id}"
            seen.add(label)
            sat = self.sats.get(label)
            has_phase = s.cp_valid and s.carrier_phase_cyc != 0.0 and (
                s.mes_qi is None or s.mes_qi >= 5
            )
            new = sat is None or sat.absent > SIGNAL_LOST_AFTER_EPOCHS
            if sat is None or new:
                sat = _Sat(label, t, t, t, t if has_phase else None)
                self.sats[label] = sat
            sat.absent = 0
            # The phase rule's LLI (rules/phase.py, the same as in the RINEX files) decides.
            ph = phase_events(s.lli, sat.half, new)
            sat.half = s.half_cycle_unresolved
            if ph.slip:
                sat.slips += 1
                sat.last_slip_ns = t
                sat.lock_since_ns = t
                sat.clean_since_ns = t if has_phase and not s.half_cycle_unresolved else None
                events.append(Event(
                    kinds.SAT_SLIP, now_ns, f"{label}: cycle slip", "info",
                    {"sv": label, "t_gps_ns": t, "slips": sat.slips},
                ))
            if ph.half_cycle_set or ph.half_cycle_cleared:
                kind = kinds.SAT_HALF_CYCLE_SET if sat.half else kinds.SAT_HALF_CYCLE_CLEARED
                what = "half-cycle ambiguity unresolved" if sat.half else "half cycle resolved"
                events.append(Event(kind, now_ns, f"{label}: {what}", "info",
                                    {"sv": label, "t_gps_ns": t}))
            if not has_phase or s.half_cycle_unresolved:
                sat.clean_since_ns = None
            elif sat.clean_since_ns is None:
                sat.clean_since_ns = t
            sat.has_phase = has_phase
            sat.last_seen_ns = t
            sat.cno = s.cno_dbhz
            sat.mes_qi = s.mes_qi
        for label, sat in list(self.sats.items()):
            if label not in seen:
                sat.absent += 1
                if sat.absent > SIGNAL_LOST_AFTER_EPOCHS:
                    del self.sats[label]

    def counts(self, t_last_ns: int | None) -> Counts:
        """PPK-ready, tracked, half-cycle unresolved and below the mask, over the current
        satellites."""
        if t_last_ns is None:
            return Counts(0, 0, 0, 0)
        ready = tracked = half = below = 0
        need = int(self.th.clean_phase_s * NS_PER_S)
        for label, sat in self.sats.items():
            if "/" in label or label[0] == "S":
                continue  # one signal per satellite; SBAS gives no usable phase
            tracked += 1
            half += sat.half
            el = self._svinfo.get(label, (None, None, None))[0]
            above = el is None or el >= self.th.elevation_mask_deg
            below += not above
            if above and sat.clean_since_ns is not None and t_last_ns - sat.clean_since_ns >= need:
                ready += 1
        return Counts(ready, tracked, half, below)

    def statuses(self, t_last_ns: int) -> tuple[SatStatus, ...]:
        out = []
        for label, s in sorted(self.sats.items()):
            el, az, used = self._svinfo.get(label.split("/")[0], (None, None, None))
            slip_age = (t_last_ns - s.last_slip_ns) / 1e9 if s.last_slip_ns is not None else None
            if not s.has_phase:
                state = "code_only"
            elif s.half:
                state = "half_cycle"
            elif slip_age is not None and slip_age < SLIPPED_FOR_S:
                state = "slipped"
            else:
                state = "clean"
            out.append(SatStatus(
                sv=label, cno_dbhz=s.cno, elev_deg=el, azim_deg=az,
                lock_s=(t_last_ns - s.lock_since_ns) / 1e9,
                clean_phase_s=(t_last_ns - s.clean_since_ns) / 1e9
                if s.clean_since_ns is not None else 0.0,
                half_cycle_unresolved=s.half, slips=s.slips, last_slip_age_s=slip_age,
                mes_qi=s.mes_qi, used=used, state=state,  # type: ignore[arg-type]
            ))
        return tuple(out)
