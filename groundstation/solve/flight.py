"""What the solver takes from a flight recording, read once: the time marks, the receiver's
fixes, the measurement epochs and damage that explain lost marks, and, for the report, the
rover's satellites and the link dropouts and source outages a ground-station session recorded.

:func:`read_flight` is the one reader (``.ubx``, ``.ubx.gz``, ``.mcap``, a session's later parts
too); everything downstream, the report included, takes its :class:`FlightRecords`.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from groundstation import gpstime
from groundstation.errors import InputError
from groundstation.offline.rinex.observations import obs_from_raw, obs_from_rawx
from groundstation.records import Frame, NavSolution, TimeMark
from groundstation.rules.epochs import find_gaps, nominal_interval_ns
from groundstation.rules.marks import Mark, lost_by_cause, lost_cause
from groundstation.solve.arrays import read_npz, write_npz
from groundstation.storage.reading import Recording
from groundstation.ubx import fastraw
from groundstation.ubx.decode import (
    NAV_POSLLH,
    NAV_PVT,
    NAV_SOL,
    RXM_RAW,
    RXM_RAWX,
    TIM_TM2,
    Decoder,
)
from groundstation.ubx.framer import BetweenFrames, UbxFramer

if TYPE_CHECKING:
    from groundstation.storage.mcapio import McapMessage

Progress = Callable[[str, float], None]
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

_WANTED = {TIM_TM2, NAV_SOL, NAV_PVT, NAV_POSLLH}
_EPOCHS = {RXM_RAW, RXM_RAWX}
EVENT_TOPIC = "/groundstation/event"
NAV_TOPIC = "/gnss/nav"


@dataclass(frozen=True, slots=True)
class Span:
    """A time interval (GPS ns); ``end`` equals ``start`` for an interval still open."""

    start_gps_ns: int
    end_gps_ns: int


@dataclass(frozen=True, slots=True)
class SatelliteObs:
    """Raw measurements of the rover, one row per satellite and epoch (first band only).

    Attributes:
        sat: satellite names (``G05``, ``R12`` ...).
        t_gps_ns: epoch time of each row.
        cno_dbhz: carrier-to-noise density.
        slip: loss of lock / cycle slip flagged at this epoch (RINEX LLI bit 0).
        half: half-cycle ambiguity unresolved (LLI bit 1).
        repaired: slips repaired by the conditioning (None when none ran).
    """

    sat: tuple[str, ...]
    t_gps_ns: IntArray
    cno_dbhz: FloatArray
    slip: BoolArray
    half: BoolArray
    repaired: BoolArray | None = None


@dataclass(frozen=True, slots=True)
class FlightObservations:
    """The recording's own account of the flight beyond marks and fixes (what the report shows).

    Attributes:
        satellites: the rover's raw measurements (RXM-RAWX, else RXM-RAW), first band, as RINEX
            sees them; None when the recording has none.
        radio_gaps: link dropouts the ground station recorded.
        source_outages: outages of the receiver connection, on GPS time (the least-delayed
            offset between the host clock and the receiver's fixes, as the dashboard does).
        station_events: the recording is a station session (MCAP) that records them; a plain
            UBX file cannot tell.
    """

    satellites: SatelliteObs | None = None
    radio_gaps: tuple[Span, ...] = ()
    source_outages: tuple[Span, ...] = ()
    station_events: bool = False


@dataclass(frozen=True, slots=True)
class FlightRecords:
    """What the solver needs from a recording."""

    timemarks: tuple[TimeMark, ...]
    nav: tuple[NavSolution, ...]
    frames: int
    damaged: int
    epoch_t_gps_ns: tuple[int, ...] = ()
    """The received measurement epochs (plausible ones), in stream order."""
    damage_t_gps_ns: tuple[int, ...] = ()
    """For every stretch of bytes between frames that is not NMEA (damaged data), the time of
    the last epoch before it."""
    observed: FlightObservations | None = None
    """Satellites and station events, when asked for (:func:`read_flight`)."""

    def holes(self) -> tuple[list[tuple[int, int]], int | None]:
        """The holes in the received epochs (last before, first after) and the interval."""
        t = sorted(set(self.epoch_t_gps_ns))
        iv = nominal_interval_ns(t)
        return [(g.after_t_gps_ns, g.before_t_gps_ns) for g in find_gaps(t, iv)], iv

    def lost_by_cause(self, marks: Sequence[Mark], known_t_ns: Sequence[int] = (),
                      ) -> dict[str, list[int]]:
        """The count jumps of the marks by cause (:func:`groundstation.rules.marks.lost_cause`;
        ``known_t_ns``: the photos without a mark, timed by the camera clock)."""
        holes, iv = self.holes()
        damage = [(t, t) for t in self.damage_t_gps_ns]
        return lost_by_cause(marks, holes, damage, iv, sorted(known_t_ns))

    def cause_at(self, t_gps_ns: int) -> str:
        """Why a pulse at this time never arrived (:func:`groundstation.rules.marks.lost_cause`)."""
        holes, iv = self.holes()
        return lost_cause(t_gps_ns, holes, [(t, t) for t in self.damage_t_gps_ns], iv)


_NONE = np.iinfo(np.int64).min
"""Stands for None in a saved time mark's integer columns."""
_TIMEMARK_FIELDS = tuple(f.name for f in fields(TimeMark))


def save_npz(rec: FlightRecords, path: Path) -> None:
    """Write what a re-base takes from the flight (:func:`load_npz`): the time marks, the
    epochs and damage that explain lost marks, and the observations the report shows. The
    receiver's fixes are not kept. Plain arrays, no pickled objects."""
    cols = np.array([[_NONE if (v := getattr(tm, k)) is None else int(v)
                      for k in _TIMEMARK_FIELDS] for tm in rec.timemarks],
                    dtype=np.int64).reshape(-1, len(_TIMEMARK_FIELDS))
    arrays: dict[str, Any] = {
        "timemarks": cols, "timemark_fields": np.array(_TIMEMARK_FIELDS),
        "counts": np.array([rec.frames, rec.damaged], dtype=np.int64),
        "epoch_t_gps_ns": np.array(rec.epoch_t_gps_ns, dtype=np.int64),
        "damage_t_gps_ns": np.array(rec.damage_t_gps_ns, dtype=np.int64),
    }
    obs = rec.observed
    if obs is not None:
        arrays["radio_gaps"] = _spans_array(obs.radio_gaps)
        arrays["source_outages"] = _spans_array(obs.source_outages)
        arrays["station_events"] = np.array(obs.station_events)
        sats = obs.satellites
        if sats is not None:
            arrays.update(sat=np.array(sats.sat, dtype=np.str_), sat_t_gps_ns=sats.t_gps_ns,
                          sat_cno_dbhz=sats.cno_dbhz, sat_slip=sats.slip, sat_half=sats.half)
            if sats.repaired is not None:
                arrays["sat_repaired"] = sats.repaired
    write_npz(path, arrays)


def load_npz(path: Path) -> FlightRecords:
    """The flight's records :func:`save_npz` wrote (without the receiver's fixes).

    Raises:
        InputError: unreadable, or not what :func:`save_npz` writes.
    """
    a = read_npz(path, "flight records")
    try:
        names = tuple(str(v) for v in a["timemark_fields"])
        if names != _TIMEMARK_FIELDS:
            raise ValueError(f"time-mark fields {names}")
        flags = {f.name: f.type == "bool" for f in fields(TimeMark)}
        rows: list[dict[str, Any]] = [
            {k: (None if v == _NONE else bool(v) if flags[k] else v)
             for k, v in zip(names, row, strict=True)}
            for row in a["timemarks"].reshape(-1, len(names)).tolist()]
        tms = tuple(TimeMark(**r) for r in rows)
        frames, damaged = (int(v) for v in a["counts"])
        observed = None
        if "station_events" in a:
            sats = None
            if "sat" in a:
                sats = SatelliteObs(
                    sat=tuple(str(s) for s in a["sat"]), t_gps_ns=a["sat_t_gps_ns"],
                    cno_dbhz=a["sat_cno_dbhz"], slip=a["sat_slip"], half=a["sat_half"],
                    repaired=a.get("sat_repaired"))
            observed = FlightObservations(sats, _spans(a["radio_gaps"]),
                                          _spans(a["source_outages"]),
                                          bool(a["station_events"]))
        return FlightRecords(tms, (), frames, damaged,
                             tuple(int(t) for t in a["epoch_t_gps_ns"]),
                             tuple(int(t) for t in a["damage_t_gps_ns"]), observed)
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"{path}: not flight records this program wrote ({err!r})") from err


def _spans_array(spans: Sequence[Span]) -> IntArray:
    return np.array([(s.start_gps_ns, s.end_gps_ns) for s in spans],
                    dtype=np.int64).reshape(-1, 2)


def _spans(a: IntArray) -> tuple[Span, ...]:
    return tuple(Span(int(s), int(e)) for s, e in a.reshape(-1, 2).tolist())


def read_flight(path: Path, progress: Progress | None = None, *,
                observations: bool = False) -> FlightRecords:
    """TIM-TM2 and receiver fixes from a recording (``.ubx``, ``.ubx.gz``, ``.mcap``; a
    session's later parts too); with ``observations``, in the same pass, the rover's satellites
    and the station's events (:class:`FlightObservations`)."""
    framer = UbxFramer()
    decoder = Decoder()
    tms: list[TimeMark] = []
    nav: list[NavSolution] = []
    epochs: list[int] = []
    damage: list[int] = []
    raw_epochs: list[bytes] = []
    between = BetweenFrames()

    def take(fr: Frame) -> None:
        if between.damaged_before(fr):
            damage.append(epochs[-1] if epochs else -1)
        if fr.key in _EPOCHS:  # the session's clock the marks are judged by (issue 27)
            if observations:
                raw_epochs.append(fr.raw)
            t = decoder.judge_epoch(fr)
            if t is not None:
                epochs.append(t)
        if fr.key not in _WANTED:
            return
        rec = decoder.decode(fr)
        if isinstance(rec, TimeMark):
            tms.append(rec)
        elif isinstance(rec, NavSolution):
            nav.append(rec)

    recording = Recording(path)
    station = _StationLog()
    also = station.handlers() if observations else None
    for chunk, t_host in recording.chunks(also=also):
        between.feed(chunk)
        for fr in framer.feed(chunk, t_host):
            take(fr)
        if progress is not None:
            progress("read flight", recording.progress)
    for fr in framer.flush():
        take(fr)
    st = framer.stats
    observed = None
    if observations:
        gaps, outages = station.spans()
        observed = FlightObservations(_satellites(raw_epochs), gaps, outages,
                                      recording.format == "mcap")
    return FlightRecords(tuple(tms), tuple(nav), st.frames, st.bad_checksum + st.truncated,
                         tuple(epochs), tuple(damage), observed)


def _satellites(raw_epochs: list[bytes]) -> SatelliteObs | None:
    """The rover's raw measurements (RXM-RAWX, else RXM-RAW), first band, as RINEX sees them,
    from the recording's measurement frames in stream order."""
    data = b"".join(raw_epochs)
    index = fastraw.index_frames(data)
    obs = obs_from_rawx(fastraw.decode_rawx(data, index))
    if obs.epoch.size == 0:
        obs = obs_from_raw(fastraw.decode_raw(data, index))
    if obs.epoch.size == 0:
        return None
    first = np.char.startswith(obs.code.astype(str), "1")
    sat = np.char.add(obs.sys.astype(str), np.char.zfill(obs.prn.astype(str), 2))[first]
    return SatelliteObs(
        sat=tuple(sat.tolist()),
        t_gps_ns=obs.t_gps_ns[obs.epoch[first]],
        cno_dbhz=obs.cno_dbhz[first],
        slip=(obs.lli[first] & 1) != 0,
        half=(obs.lli[first] & 2) != 0,
    )


class _StationLog:
    """Radio dropouts and source outages of a ground-station session, gathered from its event
    and fix messages while the recording is read (MCAP only)."""

    def __init__(self) -> None:
        self.gaps: list[Span] = []
        self.host_outages: list[tuple[int, int]] = []
        self.offsets: list[int] = []

    def handlers(self) -> dict[str, Callable[[McapMessage], None]]:
        return {EVENT_TOPIC: self._event, NAV_TOPIC: self._nav}

    def _nav(self, m: McapMessage) -> None:
        try:
            d = json.loads(m.data)
        except ValueError:
            return
        th, wk, tow = d.get("t_host_ns"), d.get("gps_week"), d.get("tow_ns")
        if isinstance(th, int) and isinstance(wk, int) and isinstance(tow, int):
            self.offsets.append(th - gpstime.gps_ns(wk, tow))

    def _event(self, m: McapMessage) -> None:
        try:
            d = json.loads(m.data)
        except ValueError:
            return
        data = d.get("data") or {}
        if d.get("kind") == "link.dropout":
            a, b = data.get("start_t_gps_ns"), data.get("end_t_gps_ns")
            if isinstance(a, int) and isinstance(b, int):
                self.gaps.append(Span(a, b))
        elif d.get("kind") == "source.outage":
            a, b = data.get("start_ns"), data.get("end_ns")
            if isinstance(a, int) and isinstance(b, int):
                self.host_outages.append((a, b))

    def spans(self) -> tuple[tuple[Span, ...], tuple[Span, ...]]:
        """(dropouts, outages): outages carry host times, put on GPS time with the
        least-delayed offset between host clock and the receiver's fixes."""
        outages: tuple[Span, ...] = ()
        if self.offsets and self.host_outages:
            off = min(self.offsets)
            outages = tuple(Span(a - off, b - off) for a, b in self.host_outages)
        return tuple(self.gaps), outages
