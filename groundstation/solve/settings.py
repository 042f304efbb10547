"""The resolved options of one solve (:class:`SolveSettings`): what ``groundstation solve``,
the solver service and a re-base (:mod:`.record`) hand to :func:`.pipeline.solve`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from groundstation.errors import ConfigError
from groundstation.solve import interpolate as mi
from groundstation.solve.engine import DEFAULT_ENGINE


@dataclass(frozen=True, slots=True)
class SolveSettings:
    """Resolved options of one solve (see ``groundstation solve --help``)."""

    flight: Path
    out_dir: Path
    positions: Path | None = None
    base: Path | None = None
    base_ecef_m: tuple[float, float, float] | None = None
    base_given: str = "given with --base-xyz"
    base_sd_enu_m: tuple[float, float, float] | None = None
    """The base position's own sigma (east, north, up), None when taken as exact."""
    flight_copies: tuple[Path, ...] = ()
    """More recordings of the same receiver (an on-board log): merged with ``flight``."""
    merged_from: str = ""
    """What the merge of several recordings took from each (for the notes)."""
    base_estimated: bool = False
    """No base position was given: it is the mean of the base receiver's own fixes."""
    base_antenna_height_m: float | None = None
    base_antenna: str | None = None
    antex: Path | None = None
    """How the base antenna stood over the coordinates given (the height from the mark, its
    type and the ANTEX file of its offset): already in ``base_ecef_m``; kept for a re-base,
    which takes them again for the new coordinates (:mod:`.record`)."""
    base_fix_mean_m: tuple[float, float, float] | None = None
    base_fix_count: int = -1
    """The mean of the base receiver's own fixes (None: it has none) and how many (-1: not
    read yet, or no u-blox base recording): what the base position is checked against, kept
    for a re-base."""
    source: str | None = None
    photos: Path | None = None
    lever_arm_m: tuple[float, float, float] | None = None
    eo: Path | None = None
    epsg: int | str | None = None
    geoid: Path | None = None
    interp: str = mi.DEFAULT_METHOD
    edge: mi.Edge = "falling"
    shutter_delay_ms: float = 0.0
    max_gap_s: float = mi.DEFAULT_MAX_GAP_S
    exif_copies: bool = False
    kappa_offset_deg: float = 0.0
    engine: str = DEFAULT_ENGINE
    rtk_conf: Path | None = None
    rtk_options: tuple[tuple[str, str], ...] = ()
    recordings: tuple[Path, ...] = ()
    """The recordings as given when ``flight`` is their merge (a temporary file): what the
    run's record names (:mod:`.record`)."""
    report_pdf: bool = True
    """Print ``report.pdf`` from ``report.html`` with Chromium (``--no-pdf``: the HTML only;
    the print costs 1-8 s, most of a short solve's time after the engine)."""
    rebase: Path | None = None
    """A finished result re-based to this base position: its trajectory is taken, shifted by
    the base's move, instead of running the engine again (:mod:`.record`)."""
    previous_bases: tuple[tuple[tuple[float, float, float], str], ...] = ()
    """Re-based: the base positions the result had before, oldest first, each with how it
    was given."""

    def source_name(self) -> str:
        """The position source: explicit, else ``pos`` with --positions, ``rtklib`` with --base."""
        if self.source:
            return self.source
        if self.positions is not None:
            return "pos"
        if self.base is not None:
            return "rtklib"
        raise ConfigError(
            "--positions", "give --positions FILE.pos or --base BASE --base-xyz X,Y,Z"
        )
