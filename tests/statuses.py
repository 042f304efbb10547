"""Statuses as the daemon's monitor makes them, from epochs and NAV-SVINFO the tests choose
(the views' tests draw what a real monitor says, not a hand-written status)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from groundstation.config import MonitorSettings
from groundstation.gpstime import NS_PER_S, NS_PER_WEEK
from groundstation.live.monitor import Monitor
from groundstation.records import Event, RawEpoch, SatObs, Status, SvInfo, SvInfoSat

GPS, GLONASS = 0, 6
HOST0 = 1_700_000_000 * NS_PER_S
T0 = 2300 * NS_PER_WEEK + 100 * NS_PER_S


def obs(gnss: int, sv: int, cno: int = 45) -> SatObs:
    """A measurement with clean, valid phase."""
    return SatObs(gnss, sv, 1e8 + sv, 2e7, 100.0, cno, 7, 0, False, False)


def svinfo(t_host_ns: int, elevations: Sequence[tuple[int, int, int]]) -> SvInfo:
    """NAV-SVINFO for ``(gnss, sv, elevation)``; u-blox says -91 for an unknown elevation."""
    return SvInfo("NAV-SVINFO", 0, tuple(
        SvInfoSat(g, s, 45, el, 0 if el == -91 else (37 * s) % 360, True, 7, True)
        for g, s, el in elevations), t_host_ns)


def monitor_status(sats: Sequence[SatObs], elevations: Sequence[tuple[int, int, int]], *,
                   seconds: int = 40, t0_gps_ns: int = T0, host0_ns: int = HOST0,
                   events: Sequence[Event] = (), station: str = "st") -> Status:
    """A monitor fed 1 Hz epochs of ``sats`` (each 80 ms after its GPS time on the host clock
    from ``host0_ns``) with NAV-SVINFO ``elevations`` for ``seconds`` (longer than
    clean_phase_s), then ``events``; its status one second after."""
    m = Monitor(station, MonitorSettings(elevation_mask_deg=15.0, clean_phase_s=30.0))
    for k in range(seconds):
        host = host0_ns + k * NS_PER_S + 80_000_000
        m.on_bytes(600, host)
        m.observe(svinfo(host, elevations), host)
        week, tow = divmod(t0_gps_ns + k * NS_PER_S, NS_PER_WEEK)
        m.observe(RawEpoch(week, tow, tuple(sats), "RXM-RAWX"), host)
        m.tick(host + 10_000_000)
    host = host0_ns + seconds * NS_PER_S
    for ev in events:
        m.observe(ev, host)
    return m.status(host + NS_PER_S)


def drawn_status(t_host_ns: int, marks: tuple[int, int] = (0, 0),
                 alerts: Sequence[str] = ()) -> bytes:
    """A status message as the daemon publishes it, with everything ``watch`` and the dashboard
    draw (``marks``: received, missed), for tests that put it on the bus between poison."""
    from groundstation.bus import encode

    sats = [{"sv": "G05", "cno_dbhz": 44, "elev_deg": 40, "azim_deg": 120, "state": "clean",
             "lock_s": 10.0, "clean_phase_s": 9.0, "slips": 0,
             "half_cycle_unresolved": False}]
    return encode("status", {
        "station": "p", "t_host_ns": t_host_ns, "session_id": "p_20250602T080000Z",
        "link": {"epoch_interval_s": 0.2, "epochs": 10, "first_epoch_t_gps_ns": 10**18,
                 "last_epoch_t_gps_ns": 10**18 + 2 * 10**9, "recent_dropouts": [],
                 "current_dropout": None, "source_connected": True, "bytes_in": 1000,
                 "completeness_60s": 1.0, "completeness_session": 1.0, "bytes_per_s": 100.0,
                 "dropouts": 0, "missing_epochs": 0, "damaged_frames": 0,
                 "last_byte_age_s": 0.1},
        "sats": sats, "ppk_ready": 6, "tracked": 8, "half_cycle_fraction": 0.1,
        "marks": {"marks": marks[0], "missed": marks[1], "in_dropout": 0,
                  "last_falling_t_gps_ns": None, "last_count": None, "rate_per_min": 0.0,
                  "last_pulse_width_ms": None},
        "alerts": list(alerts), "recording": {"file": None},
    })


def run_watch(endpoint: str, seconds: int, out: Path) -> subprocess.CompletedProcess[str]:
    """``groundstation watch`` of station ``p`` over ``endpoint`` for ``seconds``, 160 columns
    wide, what it printed also kept in ``out`` (the test's record of the screen)."""
    from peers import REPO

    watch = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "watch", "--station", "p", "--connect",
         endpoint, "--duration", str(seconds)],
        cwd=REPO, capture_output=True, text=True, timeout=60,
        env={"COLUMNS": "160", "PATH": "/usr/bin:/bin", "PYTHONPATH": str(REPO)},
    )
    out.write_text(watch.stdout + watch.stderr)
    return watch
