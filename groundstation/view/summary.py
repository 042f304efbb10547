"""The monitor's final status as a few lines of text, for the end-of-run summaries."""

from __future__ import annotations

from groundstation.records import Status


def status_lines(st: Status, *, injected_lost_epochs: int | None = None,
                 exposures: int | None = None, at: str = "at the end") -> list[str]:
    """Link, marks and satellites in three lines; the simulator's figures when given.

    The link and marks lines count the whole run; the satellites and alerts are the state
    ``at`` its last data (``"at the end of the recording"``): a recording whose receiver was
    carried indoors at the end ends with few satellites even when its flight was clean.
    """
    link, marks = st.link, st.marks
    sim_link = (f"; simulator injected {injected_lost_epochs}"
                if injected_lost_epochs is not None else "")
    sim_marks = f" (simulator: {exposures} exposures)" if exposures is not None else ""
    return [
        (f"  link: {link.epochs} epochs at {link.epoch_interval_s or 0:g} s, {link.dropouts} "
        f"dropouts ({link.missing_epochs} epochs missing{sim_link}), {link.damaged_frames} "
        "damaged frames"),
        (f"  marks: {marks.marks} received, {marks.missed} missed, {marks.duplicates} "
         f"duplicates, "
        f"{marks.in_dropout} inside dropouts{sim_marks}"),
        (f"  {at}: {st.tracked} satellites tracked, {st.ppk_ready} PPK-ready; alerts: "
         f"{'; '.join(st.alerts) or 'none'}"),
    ]
