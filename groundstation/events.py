"""The catalogue of event kinds and alert names: one constant per kind, its severity and meaning.

Every :class:`~groundstation.records.Event` carries one of these kinds. The strings are the wire
format (Zenoh ``events`` topic, MCAP ``/events``, ``docs/zenoh.md``, the dashboard's JavaScript),
so they never change; code compares against the constants, never against literals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

Severity = Literal["info", "warning", "error"]


@dataclass(frozen=True, slots=True)
class Kind:
    """One entry of the catalogue."""

    name: str
    severity: Severity
    description: str


# -- the link and the source ----------------------------------------------------------------
LINK_DROPOUT: Final = "link.dropout"
LINK_DROPOUT_STARTED: Final = "link.dropout_started"
SOURCE_LOST: Final = "source.lost"
SOURCE_CONNECTED: Final = "source.connected"
SOURCE_OUTAGE: Final = "source.outage"
# -- satellites -----------------------------------------------------------------------------
SAT_SLIP: Final = "sat.slip"
SAT_HALF_CYCLE_SET: Final = "sat.half_cycle_set"
SAT_HALF_CYCLE_CLEARED: Final = "sat.half_cycle_cleared"
# -- time marks -----------------------------------------------------------------------------
MARK_MISSED: Final = "mark.missed"
MARK_DUPLICATE: Final = "mark.duplicate"
MARK_IN_DROPOUT: Final = "mark.in_dropout"
# -- alerts ---------------------------------------------------------------------------------
ALERT_RAISED: Final = "alert.raised"
ALERT_CLEARED: Final = "alert.cleared"
OPERATOR_ACK: Final = "operator.ack"
"""An operator acknowledged an alert in a view (``groundstation/<station>/ack``); not an
``alert.`` kind because the monitor ignores its own kinds coming back through the pipeline."""
# -- recording ------------------------------------------------------------------------------
RECORDER_FILE_OPENED: Final = "recorder.file_opened"
RECORDER_WRITE_FAILED: Final = "recorder.write_failed"
RECORDER_DROPPED: Final = "recorder.dropped"
RECORDER_RECOVERED: Final = "recorder.recovered"
RECORDER_VANISHED: Final = "recorder.vanished"
# -- Zenoh ----------------------------------------------------------------------------------
ZENOH_CONNECTED: Final = "zenoh.connected"
ZENOH_DISCONNECTED: Final = "zenoh.disconnected"
ZENOH_AVAILABLE: Final = "zenoh.available"
ZENOH_UNAVAILABLE: Final = "zenoh.unavailable"
# -- stations on the bus -------------------------------------------------------------------
STATION_CONFLICT: Final = "station.conflict"
STATION_CONFLICT_ENDED: Final = "station.conflict_ended"
# -- the live engine (groundstation/live/rtk.py) --------------------------------------------
RTK_FIX_LOST: Final = "rtk.fix_lost"
RTK_FIX_REGAINED: Final = "rtk.fix_regained"
# -- the pipeline's sinks -------------------------------------------------------------------
FANOUT_DROPPED: Final = "fanout.dropped"
# -- the decoder ----------------------------------------------------------------------------
DECODER_TIME_JUMP: Final = "decoder.time_jump"
BEHIND_SUFFIX: Final = ".behind"
CAUGHT_UP_SUFFIX: Final = ".caught_up"

MONITOR_PREFIXES: Final = ("alert.", "link.", "sat.", "mark.")
"""Prefixes of the kinds the monitor itself raises."""


def behind(sink: str) -> str:
    """``<sink>.behind``: the sink's queue crossed its limit (nothing is dropped)."""
    return f"{sink}{BEHIND_SUFFIX}"


def caught_up(sink: str) -> str:
    """``<sink>.caught_up``: the sink's queue drained below half its limit."""
    return f"{sink}{CAUGHT_UP_SUFFIX}"


def sink_of(kind: str, suffix: str) -> str | None:
    """The sink named by a ``<sink>.behind`` / ``<sink>.caught_up`` kind, else None."""
    return kind[: -len(suffix)] if kind.endswith(suffix) else None


CATALOGUE: Final[dict[str, Kind]] = {
    k.name: k
    for k in (
        Kind(LINK_DROPOUT, "warning", "a run of missing epochs, measured when data returned"),
        Kind(LINK_DROPOUT_STARTED, "warning", "no epoch for longer than the interval allows"),
        Kind(SOURCE_LOST, "warning", "the byte source (serial, TCP, file) went away"),
        Kind(SOURCE_CONNECTED, "info", "the byte source is connected"),
        Kind(SOURCE_OUTAGE, "warning", "the byte source came back after an outage"),
        Kind(SAT_SLIP, "info", "LLI bit 0: lost lock since the previous epoch"),
        Kind(SAT_HALF_CYCLE_SET, "info", "LLI bit 1 set: half-cycle ambiguity unresolved"),
        Kind(SAT_HALF_CYCLE_CLEARED, "info", "LLI bit 1 cleared: half cycle resolved"),
        Kind(MARK_MISSED, "warning", "the mark count jumped: marks whose records were all lost"),
        Kind(MARK_DUPLICATE, "warning", "the same falling edge reported as new again"),
        Kind(MARK_IN_DROPOUT, "warning", "a mark inside a link dropout (interpolation gap)"),
        Kind(ALERT_RAISED, "warning", "an alert (see ALERTS) is raised"),
        Kind(ALERT_CLEARED, "info", "an alert is cleared"),
        Kind(OPERATOR_ACK, "info", "an operator acknowledged an alert (data: alert, by; "
             "dropped_before: acknowledgements over the rate limit since the last)"),
        Kind(RECORDER_FILE_OPENED, "info", "the recorder opened a recording file"),
        Kind(RECORDER_WRITE_FAILED, "error", "writing the recording failed; data held in memory"),
        Kind(RECORDER_DROPPED, "error", "data the recorder could not hold was dropped"),
        Kind(RECORDER_RECOVERED, "warning", "writing the recording works again"),
        Kind(RECORDER_VANISHED, "error",
             "the recording's file or directory was deleted; a new part continues it"),
        Kind(ZENOH_CONNECTED, "info", "a Zenoh peer or router is connected"),
        Kind(ZENOH_DISCONNECTED, "warning", "no Zenoh peer or router connected"),
        Kind(ZENOH_AVAILABLE, "info", "the Zenoh session is open again"),
        Kind(ZENOH_UNAVAILABLE, "warning", "the Zenoh session cannot be opened"),
        Kind(STATION_CONFLICT, "error", "another daemon publishes as the same station"),
        Kind(STATION_CONFLICT_ENDED, "info", "no other daemon publishes as this station any more"),
        Kind(FANOUT_DROPPED, "warning", "a slow sink lost items"),
        Kind(RTK_FIX_LOST, "warning", "no fixed live position for FIX_LOST_ALERT_S while marks "
             "come in (data: since_t_gps_ns, marks): photos taken now may not get one"),
        Kind(RTK_FIX_REGAINED, "info", "the live position is fixed again (data: lost_s)"),
        Kind(DECODER_TIME_JUMP, "warning",
             "the receiver's time jumped and a second epoch confirmed it: the session's clock "
             "follows (rules/plausible)"),
    )
}
"""Every fixed kind; ``<sink>.behind`` and ``<sink>.caught_up`` are formed by :func:`behind`
and :func:`caught_up`."""

# -- alert names (``data["alert"]`` of alert.raised / alert.cleared) ------------------------
ALERT_NO_FRAMES: Final = "no_frames"
ALERT_NO_DATA: Final = "no_data"
ALERT_SOURCE_DOWN: Final = "source_down"
ALERT_DROPOUT_LONG: Final = "dropout_long"
ALERT_PPK_READY_LOW: Final = "ppk_ready_low"
ALERT_HALF_CYCLE_HIGH: Final = "half_cycle_high"
ALERT_MARKS_MISSED: Final = "marks_missed"
ALERT_DISK_LOW: Final = "disk_low"
ALERT_DISK_FULL: Final = "disk_full"
ALERT_RECORDING_FAILED: Final = "recording_failed"
ALERT_RECORDER_BEHIND: Final = "recorder_behind"
ALERT_ZENOH_DISCONNECTED: Final = "zenoh_disconnected"
ALERT_STATION_CONFLICT: Final = "station_conflict"

ALERTS: Final[dict[str, str]] = {
    ALERT_NO_FRAMES: "bytes arrive but no valid frame (baud rate, noise, NMEA only)",
    ALERT_NO_DATA: "no bytes for [monitor] no_data_s (also before the first byte)",
    ALERT_SOURCE_DOWN: "the source (serial port, TCP server) cannot be opened or is lost",
    ALERT_DROPOUT_LONG: "a link dropout longer than [monitor] dropout_alert_s",
    ALERT_PPK_READY_LOW: "too few satellites with clean continuous phase",
    ALERT_HALF_CYCLE_HIGH: "too many satellites with unresolved half cycles",
    ALERT_MARKS_MISSED: "time marks were missed",
    ALERT_DISK_LOW: "disk space below [monitor] disk_free_min_mb",
    ALERT_DISK_FULL: "the disk is full: the recording is held in memory",
    ALERT_RECORDING_FAILED: "writing the recording fails",
    ALERT_RECORDER_BEHIND: "the recorder falls behind the stream",
    ALERT_ZENOH_DISCONNECTED: "status and events reach nobody",
    ALERT_STATION_CONFLICT: "another daemon publishes as the same station",
}
"""Alert names and what each means."""
