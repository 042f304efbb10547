"""The record types that flow through the pipeline: frames, decoded messages, status and events.

Times are integers. ``t_host_ns`` is the host wall clock at reception (UNIX ns); GPS time is
``gps_week`` + ``tow_ns`` or ``t_gps_ns`` (ns since the GPS epoch 1980-01-06). Units are in the
field names. Every record is a frozen, slotted dataclass so it can be shared between tasks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

from groundstation.gpstime import NS_PER_WEEK

GNSS_LETTERS = {0: "G", 1: "S", 2: "E", 3: "C", 4: "I", 5: "J", 6: "R", 7: "I"}
"""RINEX system letter for each u-blox ``gnssId`` (4 is IMES, shown as I like NavIC)."""
GNSS_GLONASS = 6
UNKNOWN_GLONASS_SV = 255
"""u-blox svId of a GLONASS satellite whose slot number the receiver does not know yet: a
measurement without a satellite name ("R255"), not usable until the receiver identifies it."""
ELEVATION_RANGE_DEG = (-90, 90)
"""Elevations a receiver can report; u-blox sends -91 for a satellite whose elevation it does
not know (no orbit yet, or no slot number)."""


def identified(gnss: int, sv: int) -> bool:
    """Whether a measurement names its satellite (not a GLONASS slot still unknown)."""
    return not (gnss == GNSS_GLONASS and sv == UNKNOWN_GLONASS_SV)


def known_elevation(elev_deg: int) -> int | None:
    """A reported elevation, or None where the receiver said it does not know (-91)."""
    lo, hi = ELEVATION_RANGE_DEG
    return elev_deg if lo <= elev_deg <= hi else None


def sv_label(gnss: int, sv: int) -> str:
    """RINEX-style satellite label, e.g. ``G05``; SBAS PRNs 120-158 become ``S20``-``S58``."""
    letter = GNSS_LETTERS.get(gnss, "?")
    if letter == "S" and sv >= 100:
        sv -= 100
    return f"{letter}{sv:02d}"


T = TypeVar("T")


def positional_constructor(cls: type[T]) -> Callable[..., T]:
    """A fast constructor of a frozen, slotted dataclass: the same object as ``cls(...)``.

    It takes the fields in order, positionally or by name, with the same defaults. A frozen
    dataclass's ``__init__`` sets each field through ``object.__setattr__`` (its own
    ``__setattr__`` refuses); this one fills a plain twin class with the same slots, with
    ordinary attribute stores, then gives the object its real class (allowed: same layout). The
    result is an instance of ``cls`` like any other (equality, hash, frozenness), made about six
    times faster than by ``cls(...)`` (three times faster than setting each slot through its
    descriptor). It matters for the records made per frame and per satellite (106 000 satellite
    measurements in 5 MB of RXM-RAW).

    Raises:
        TypeError: ``cls`` is not a slotted dataclass without default factories.
    """
    fields = dataclasses.fields(cls)  # type: ignore[arg-type]
    names = tuple(f.name for f in fields)
    if getattr(cls, "__slots__", None) != names or cls.__bases__ != (object,):
        raise TypeError(f"{cls.__name__}: not a slotted dataclass with its own fields only")
    twin = type(f"_{cls.__name__}Fields", (), {"__slots__": names})
    probe: Any = twin()
    probe.__class__ = cls  # fails here, not on first use, if the layouts were incompatible
    # the generated code's own names start with _pc_, so no field name can shadow them
    if any(name.startswith("_pc_") for name in names):
        raise TypeError(f"{cls.__name__}: a field name starts with _pc_")
    ns: dict[str, Any] = {"_pc_twin": twin, "_pc_cls": cls}
    params = []
    for i, f in enumerate(fields):
        if f.default_factory is not dataclasses.MISSING:
            raise TypeError(f"{cls.__name__}.{f.name}: default factories are not supported")
        if f.default is dataclasses.MISSING:
            params.append(f.name)
        else:
            ns[f"_pc_default{i}"] = f.default
            params.append(f"{f.name}=_pc_default{i}")
    lines = [f"def make({', '.join(params)}):", "    _pc_o = _pc_twin()"]
    lines += [f"    _pc_o.{name} = {name}" for name in names]
    lines += ["    _pc_o.__class__ = _pc_cls", "    return _pc_o"]
    exec("\n".join(lines), ns)  # noqa: S102 - code built from the dataclass's own field names
    make: Callable[..., T] = ns["make"]
    make.__doc__ = f"{cls.__name__}(...), built as its slots' twin."
    make.__qualname__ = make.__name__ = f"make_{cls.__name__}"
    return make


@dataclass(frozen=True, slots=True)
class Frame:
    """One UBX frame with a valid checksum, exactly as it was received.

    Attributes:
        cls: message class byte.
        id: message id byte.
        payload: the payload bytes (without header and checksum).
        raw: the whole frame, sync word to checksum.
        t_host_ns: host time of the chunk that completed the frame.
        offset: byte offset of the sync word in the stream since the framer started.
    """

    cls: int
    id: int
    payload: bytes
    raw: bytes
    t_host_ns: int
    offset: int = 0

    @property
    def key(self) -> tuple[int, int]:
        return (self.cls, self.id)


@dataclass(frozen=True, slots=True)
class SatObs:
    """One satellite's measurement in a raw epoch.

    ``lli`` follows RINEX: bit 0 lost lock since the previous epoch (cycle slip possible),
    bit 1 half-cycle ambiguity unresolved; ``slip``, ``half_cycle_unresolved`` and (RXM-RAWX)
    ``cp_valid`` are its bits and the phase validity under the phase rule
    (:mod:`groundstation.rules.phase`), the same the RINEX files get.
    """

    gnss: int
    sv: int
    carrier_phase_cyc: float
    pseudorange_m: float
    doppler_hz: float
    cno_dbhz: int
    mes_qi: int | None
    lli: int
    half_cycle_unresolved: bool
    slip: bool
    sig_id: int = 0
    freq_id: int = 0
    locktime_ms: int | None = None
    trk_stat: int | None = None
    pr_valid: bool = True
    cp_valid: bool = True
    half_cycle_subtracted: bool = False
    pr_stdev_idx: int | None = None
    cp_stdev_idx: int | None = None
    do_stdev_idx: int | None = None

    @property
    def label(self) -> str:
        return sv_label(self.gnss, self.sv)


@dataclass(frozen=True, slots=True)
class RawEpoch:
    """Raw measurements of one receiver epoch (RXM-RAW or RXM-RAWX)."""

    gps_week: int
    tow_ns: int
    sats: tuple[SatObs, ...]
    source: Literal["RXM-RAW", "RXM-RAWX"]
    t_host_ns: int = 0
    leap_s: int | None = None
    clock_reset: bool = False

    @property
    def t_gps_ns(self) -> int:
        return self.gps_week * NS_PER_WEEK + self.tow_ns


@dataclass(frozen=True, slots=True)
class TimeMark:
    """A TIM-TM2 record: the camera's hot-shoe edges, time-tagged by the receiver.

    Edge times are converted to GPS time (ns since the GPS epoch) whatever the time base; an
    edge the receiver has not seen yet (week 0) is ``None``. ``flags`` keeps every bit as sent.
    """

    channel: int
    count: int
    rising_t_gps_ns: int | None
    falling_t_gps_ns: int | None
    new_rising: bool
    new_falling: bool
    time_base: int
    valid: bool
    acc_ns: int
    t_host_ns: int
    flags: int = 0
    mode_running: bool = False
    run: bool = False
    utc_valid: bool = False
    leap_s_applied: int = 0

    @property
    def time_base_name(self) -> str:
        return {0: "receiver", 1: "GPS", 2: "UTC"}.get(self.time_base, f"unknown({self.time_base})")


@dataclass(frozen=True, slots=True)
class Subframe:
    """One navigation-data subframe as the receiver forwarded it.

    ``words`` are the receiver's 32-bit words: RXM-SFRB (u-blox 6) carries 24 data bits per word
    with parity stripped; RXM-SFRBX carries the 30-bit GPS words with parity in the low 6 bits.
    """

    gnss: int
    sv: int
    words: tuple[int, ...]
    source: Literal["RXM-SFRB", "RXM-SFRBX"]
    channel: int = 0
    sig_id: int = 0
    freq_id: int = 0
    t_host_ns: int = 0

    def data_words(self) -> tuple[int, ...]:
        """The 24 data bits of each word (GPS L1 C/A layout), parity removed."""
        if self.source == "RXM-SFRBX":
            return tuple((w >> 6) & 0xFFFFFF for w in self.words)
        return tuple(w & 0xFFFFFF for w in self.words)


@dataclass(frozen=True, slots=True)
class Ephemeris:
    """A GPS broadcast ephemeris as delivered by AID-EPH: subframes 1-3, words 3-10.

    The words are 24 data bits each (parity stripped). ``how`` is the hand-over word; 0 means
    the receiver had no ephemeris for the satellite.
    """

    sv: int
    how: int
    sf1: tuple[int, ...]
    sf2: tuple[int, ...]
    sf3: tuple[int, ...]
    t_host_ns: int = 0

    @property
    def valid(self) -> bool:
        return self.how != 0 and len(self.sf1) == 8


@dataclass(frozen=True, slots=True)
class NavSolution:
    """The receiver's own fix (metre level): NAV-SOL, NAV-PVT or NAV-POSLLH."""

    source: str
    tow_ns: int
    gps_week: int | None
    fix_type: int
    fix_ok: bool
    num_sv: int | None
    ecef_m: tuple[float, float, float] | None
    lat_deg: float | None
    lon_deg: float | None
    height_m: float | None
    h_acc_m: float | None
    v_acc_m: float | None
    p_acc_m: float | None
    t_host_ns: int = 0


@dataclass(frozen=True, slots=True)
class SvInfoSat:
    gnss: int
    sv: int
    cno_dbhz: int
    elev_deg: int
    azim_deg: int
    used: bool
    quality: int
    healthy: bool

    @property
    def label(self) -> str:
        return sv_label(self.gnss, self.sv)


@dataclass(frozen=True, slots=True)
class SvInfo:
    """Per-satellite tracking state from NAV-SVINFO or NAV-SAT."""

    source: str
    tow_ns: int
    sats: tuple[SvInfoSat, ...]
    t_host_ns: int = 0


@dataclass(frozen=True, slots=True)
class UndecodedFrame:
    """A frame with a valid checksum that was not decoded; its bytes are kept.

    Either its payload does not fit its message's layout, or (``implausible``) its time cannot
    belong to the session (:mod:`groundstation.rules.plausible`): a frame that passed its
    checksum by chance.
    """

    frame: Frame
    error: str
    implausible: bool = False


Record = RawEpoch | TimeMark | Subframe | Ephemeris | NavSolution | SvInfo | UndecodedFrame | Frame
"""What the decoder hands downstream: a decoded record, or the frame itself."""


@dataclass(frozen=True, slots=True)
class Event:
    """Something that happened, for the operator and the record: outages, dropouts, alerts.

    ``kind`` is a dotted name (``source.outage``, ``link.dropout``, ``recorder.behind`` ...);
    ``data`` holds plain JSON values only.
    """

    kind: str
    t_host_ns: int
    message: str
    severity: Literal["info", "warning", "error"] = "info"
    data: dict[str, Any] = dataclasses.field(default_factory=dict)


STATUS_SCHEMA_VERSION = 1
"""Version of the status/event/mark JSON payloads (MCAP and Zenoh); bump on breaking change."""


@dataclass(frozen=True, slots=True)
class Dropout:
    """A run of missing epochs: the first and last missing epoch times and how many."""

    start_t_gps_ns: int
    end_t_gps_ns: int
    missing_epochs: int
    duration_s: float
    ongoing: bool = False


@dataclass(frozen=True, slots=True)
class LinkStatus:
    """The radio link as the monitor sees it."""

    epoch_interval_s: float | None
    epochs: int
    first_epoch_t_gps_ns: int | None
    last_epoch_t_gps_ns: int | None
    last_byte_age_s: float | None
    bytes_per_s: float
    frames_per_s: float
    bytes_in: int
    frames: int
    damaged_frames: int
    garbage_bytes: int
    completeness_10s: float | None
    completeness_60s: float | None
    completeness_session: float | None
    dropouts: int
    missing_epochs: int
    current_dropout: Dropout | None
    recent_dropouts: tuple[Dropout, ...]
    source_connected: bool | None
    source_outages: int
    implausible_frames: int = 0
    """Frames with a valid checksum whose time cannot belong to the session (rules/plausible):
    recorded, not decoded."""


@dataclass(frozen=True, slots=True)
class SatStatus:
    """One satellite's tracking state."""

    sv: str
    cno_dbhz: int
    elev_deg: int | None
    azim_deg: int | None
    lock_s: float
    clean_phase_s: float
    half_cycle_unresolved: bool
    slips: int
    last_slip_age_s: float | None
    mes_qi: int | None
    used: bool | None
    state: Literal["clean", "half_cycle", "slipped", "code_only"]


@dataclass(frozen=True, slots=True)
class MarkStatus:
    """Camera time marks so far."""

    marks: int
    last_count: int | None
    last_falling_t_gps_ns: int | None
    last_pulse_width_ms: float | None
    missed: int
    duplicates: int
    in_dropout: int
    multi_in_epoch: int
    rate_per_min: float
    last_acc_ns: int | None
    lost_on_link: int = 0
    """Of ``missed``: lost on the radio link (count jumped across a link loss)."""
    not_reported: int = 0
    """Of ``missed``: not reported by the receiver (count jumped, link intact)."""


@dataclass(frozen=True, slots=True)
class Status:
    """The 1 Hz status snapshot (MCAP ``/groundstation/status``, Zenoh ``.../status``)."""

    schema: int
    station: str
    t_host_ns: int
    session_id: str
    link: LinkStatus
    sats: tuple[SatStatus, ...]
    ppk_ready: int
    tracked: int
    half_cycle_fraction: float
    marks: MarkStatus
    alerts: tuple[str, ...]
    recording: dict[str, Any] = dataclasses.field(default_factory=dict)
    ppk_ready_min: int | None = None
    """The monitor's ``ppk_ready_min``: PPK-ready satellites needed (None: not recorded)."""
    ppk_clean_phase_s: float | None = None
    """The monitor's ``clean_phase_s``: clean continuous phase a satellite needs to count as
    PPK-ready, so a view can say what its number means (None: not recorded)."""
    below_mask: int = 0
    """Tracked satellites below the monitor's ``elevation_mask_deg``: never PPK-ready, so a view
    can say why ``ppk_ready`` is lower than ``tracked`` with every row clean."""
    elevation_mask_deg: float | None = None
    """The monitor's ``elevation_mask_deg`` (None: not recorded)."""
    unidentified: int = 0
    """Measurements of the latest epoch without a satellite number (GLONASS slots the
    receiver has not identified yet): not in ``sats``, not tracked, not usable."""


@dataclass(frozen=True, slots=True)
class RawChunk:
    """Bytes exactly as the source delivered them, with the host receive time."""

    data: bytes
    t_host_ns: int


@dataclass(frozen=True, slots=True)
class PipelineStatus:
    """The daemon's own counters, published every ``status_interval_s`` (MCAP
    ``/groundstation/pipeline``); the monitor folds them into its :class:`Status`."""

    t_host_ns: int
    source: str
    source_connected: bool | None
    bytes_in: int
    chunks: int
    frames: int
    garbage_bytes: int
    bad_checksum: int
    records: int
    undecodable: int
    queued: dict[str, int]
    dropped: dict[str, int]
    nmea_sentences: int = 0
    implausible: int = 0
    """Frames whose time cannot belong to the session (in ``undecodable`` too)."""


@dataclass(frozen=True, slots=True)
class DamagedData:
    """Bytes that are no frame (nor NMEA) came between two frames: the link garbled or dropped
    some (the monitor names marks lost there: :func:`groundstation.rules.marks.lost_cause`)."""

    t_host_ns: int


@dataclass(frozen=True, slots=True)
class LiveSolution:
    """One rover epoch's live carrier-phase position (:mod:`groundstation.live.rtk`)."""

    t_gps_ns: int
    quality: str
    """``fix``, ``float``, ``dgps``, ``single`` or ``none``."""
    ratio: float
    sats: int
    age_s: float | None
    ecef_m: tuple[float, float, float] | None
    sd_enu_m: tuple[float, float, float] | None
    why: str = ""
    """Why there is no position (quality ``none``), why an integer solution is not called
    fixed (quality ``float``: its sigma), or that the filter restarted (the sky was lost)."""
    rx_host_ns: int = 0
    """When the rover epoch's frame was received (host UNIX ns; 0: not known here), so that a
    reader can tell how late the position comes."""

    def message(self) -> dict[str, Any]:
        """The ``groundstation/<rover>/rtk`` message body (docs/zenoh.md)."""
        return {"t_gps_ns": self.t_gps_ns, "quality": self.quality,
                "ratio": round(self.ratio, 2), "sats": self.sats,
                "age_s": None if self.age_s is None else round(self.age_s, 3),
                "ecef_m": None if self.ecef_m is None else [round(v, 4) for v in self.ecef_m],
                "sd_enu_m": (None if self.sd_enu_m is None else
                             [round(v, 4) for v in self.sd_enu_m]),
                **({"why": self.why} if self.why else {}),
                **({"rx_host_ns": self.rx_host_ns} if self.rx_host_ns else {})}


Item = (RawChunk | RawEpoch | TimeMark | Subframe | Ephemeris | NavSolution | SvInfo | Event
        | Status | PipelineStatus | DamagedData | LiveSolution)
"""What travels through the live pipeline's fanout: the received bytes, the decoded records, and
what the stages say about themselves (events, status snapshots, the pipeline's counters)."""
