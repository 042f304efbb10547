"""The monitor's status in words: the end-of-run summary lines, the PPK-ready label every view
(summary, watch, dashboard) gives its number with, and when a view calls a session finished."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from groundstation import gpstime
from groundstation.config import MonitorSettings
from groundstation.records import Status


def ppk_thresholds(ready_min: object, clean_phase_s: object) -> tuple[int, float]:
    """The PPK-ready thresholds a status carries (the daemon's ``[monitor]`` ``ppk_ready_min``
    and ``clean_phase_s``); the monitor's defaults for a status recorded without them."""
    default = MonitorSettings()
    n = (ready_min if isinstance(ready_min, int) and not isinstance(ready_min, bool)
         else default.ppk_ready_min)
    clean = (float(clean_phase_s)
             if isinstance(clean_phase_s, (int, float)) and not isinstance(clean_phase_s, bool)
             else default.clean_phase_s)
    return n, clean


def session_finished(status: Mapping[str, Any] | None,
                     session: Mapping[str, Any] | None) -> bool:
    """The daemon said the session its status is about has finished: the views read
    "finished" (not live, not stale) and show the alerts as those standing at its end."""
    sess = session or {}
    return sess.get("state") == "finished" and sess.get("session_id") in (
        None, (status or {}).get("session_id"))


def ppk_label(clean_phase_s: float) -> str:
    """What the PPK-ready number counts, in the same words in every view."""
    return f"PPK-ready (clean phase >= {clean_phase_s:g} s)"


def _count(value: object) -> int:
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 else 0


def below_mask_text(below_mask: object, elevation_mask_deg: object) -> str:
    """Why PPK-ready is short of the tracked count with every satellite clean, in the same
    words in every view: "2 below the 15° elevation mask" ("" when none is)."""
    n = _count(below_mask)
    if not n:
        return ""
    mask = (f"{float(elevation_mask_deg):g}°" if isinstance(elevation_mask_deg, (int, float))
            and not isinstance(elevation_mask_deg, bool) else "")
    return f"{n} below the {mask} elevation mask".replace("the  ", "the ")


def unidentified_text(unidentified: object) -> str:
    """GLONASS measurements the receiver has not given a satellite number yet (u-blox svId
    255): said apart, never a satellite ("" when there are none)."""
    n = _count(unidentified)
    if not n:
        return ""
    return (f"{n} GLONASS measurement{'s' if n > 1 else ''} without a satellite number "
            "(not counted)")


def tracked_text(status: Mapping[str, Any]) -> str:
    """"10 tracked (2 below the 15° elevation mask)": the tracked count with what keeps some
    of them from counting as PPK-ready, from a status as JSON."""
    below = below_mask_text(status.get("below_mask"), status.get("elevation_mask_deg"))
    n = status.get("tracked")
    return f"{n if isinstance(n, int) else 0} tracked" + (f" ({below})" if below else "")


def status_lines(st: Status, *, injected_lost_epochs: int | None = None,
                 exposures: int | None = None, at: str = "at the end",
                 cleared: Sequence[str] = ()) -> list[str]:
    """Link, marks and satellites in three lines; the simulator's figures when given.

    The link and marks lines count the whole run; the satellites and alerts are the state
    ``at`` its last data (``"at the end of the recording"``): a recording whose receiver was
    carried indoors at the end ends with few satellites even when its flight was clean.
    ``cleared``: the alerts raised during the run and cleared before its end (as they were
    raised), named after those standing, so that "alerts: none" never hides a problem the run
    had (a station clash that ended when the other daemon stopped).
    """
    link, marks = st.link, st.marks
    sim_link = (f"; simulator injected {injected_lost_epochs}"
                if injected_lost_epochs is not None else "")
    sim_marks = f" (simulator: {exposures} exposures)" if exposures is not None else ""
    need, clean_s = ppk_thresholds(st.ppk_ready_min, st.ppk_clean_phase_s)
    notes = "; ".join(t for t in (below_mask_text(st.below_mask, st.elevation_mask_deg),
                                  unidentified_text(st.unidentified)) if t)
    notes = f" ({notes})" if notes else ""
    earlier = (f" (raised during the run, cleared since: {'; '.join(cleared)})"
               if cleared else "")
    return [
        (f"  link: {link.epochs} epochs at {link.epoch_interval_s or 0:g} s, {link.dropouts} "
        f"dropouts ({link.missing_epochs} epochs missing{sim_link}), {link.damaged_frames} "
        "damaged frames"),
        (f"  marks: {marks.marks} received, {marks.missed} missed"
         + (f" ({marks.lost_on_link} lost on the radio link, {marks.not_reported} not reported "
            "by the receiver)" if marks.missed else "")
         + f", {marks.duplicates} duplicates, "
        f"{marks.in_dropout} inside dropouts{sim_marks}"),
        (f"  {at}: {st.tracked} satellites tracked{notes}, {st.ppk_ready} "
         f"{ppk_label(clean_s)}, {need} needed; alerts: "
         f"{'; '.join(st.alerts) or 'none'}{earlier}"),
    ]


def go_no_go_text(doc: Mapping[str, Any]) -> str:
    """``go_no_go`` in words: "all 59 marks fixed and checked" or the stretches to fly again."""
    n, fixed = int(doc.get("marks") or 0), int(doc.get("fixed") or 0)
    if n == 0:
        return "no marks positioned"
    if fixed == n:
        return f"all {n} marks fixed and checked"
    parts = [f"{gpstime.gps_as_datetime(s['start_t_gps_ns']):%H:%M:%S}-"
             f"{gpstime.gps_as_datetime(s['end_t_gps_ns']):%H:%M:%S} GPS ({s['marks']})"
             for s in doc.get("stretches") or []]
    return (f"{n - fixed} of {n} marks not fixed: fly again over " + ", ".join(parts[:5])
            + (f" and {len(parts) - 5} more stretches" if len(parts) > 5 else ""))
