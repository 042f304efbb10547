"""The engine seam: what an engine is given (:class:`EngineJob`), what it gives back
(:class:`EngineRun`), the :class:`Engine` protocol every registered engine meets, and its errors.

The engines (:mod:`.demo5`, :mod:`.rnx2rtkp`) and the registry in the package import these;
this module imports none of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Protocol

from groundstation.errors import GroundstationError
from groundstation.solve.engine import options as eo

if TYPE_CHECKING:
    from groundstation.solve.integrity.assess import IntegrityResult

Progress = Callable[[str, float], None]


class ToolMissingError(GroundstationError):
    """The chosen engine is not installed (no ``rnx2rtkp`` on PATH, no ``pyrtklib5``)."""


class EngineError(GroundstationError):
    """A positioning engine ran but failed or produced nothing."""


@dataclass(frozen=True, slots=True)
class EngineJob:
    """RINEX inputs and resolved options of one engine run."""

    rover_obs: Path
    base_obs: Path
    nav: tuple[Path, ...]
    options: dict[str, str]
    work_dir: Path
    timeout_s: float = 3600.0


@dataclass(frozen=True, slots=True)
class EngineRun:
    """What an engine produced: the solution and how it was made."""

    engine: str
    version: str
    pos_path: Path
    info_path: Path
    options: dict[str, str]
    wall_s: float
    notes: tuple[str, ...] = field(default_factory=tuple)
    conditioning: dict[str, object] | None = None
    """What the phase conditioning did to the rover (None when it did not run)."""
    dynamics: dict[str, object] | None = None
    """The rover's measured dynamics and the acceleration noise chosen (None: not derived)."""
    combination: dict[str, object] | None = None
    """How forward and backward were combined here (None: the engine's own solution type)."""
    integrity: IntegrityResult | None = None
    """The graded trajectory of the integrity stage (None: it could not run)."""


class Engine(Protocol):
    """A PPK engine: an option table and a way to run on RINEX files."""

    name: ClassVar[str]
    defaults: ClassVar[dict[str, str]]
    combines_in_house: ClassVar[bool]
    """Whether a "combined" solution is made of this engine's forward and backward runs by
    :func:`solve` (with :mod:`.combine`'s stricter fix check) rather than by the engine."""

    def option_table(self) -> eo.OptionTable:
        """The engine's own ``sysopts[]`` (raises ToolMissingError when not installed)."""
        ...

    def version(self) -> str:
        """Engine version text for outputs."""
        ...

    def run(self, job: EngineJob, progress: Progress | None = None) -> EngineRun:
        """Solve; returns the ``.pos`` (its header and engine.json still to be completed)."""
        ...
