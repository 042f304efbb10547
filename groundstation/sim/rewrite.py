"""A real recording through the simulator's radio link, as it was or as a LEA-6T would have sent it.

``groundstation simulate --from-recording`` and the benchmarks use it to see what a radio link
would have cost a real flight. Two forms (:data:`FORMS`):

- ``lea6t``: what a u-blox 6 LEA-6T configured as ``config/profiles/lea6t-5hz.toml`` would have
  sent of the same sky. A u-blox 8/9 recording is rewritten:

  - RXM-RAWX -> RXM-RAW (02 10): GPS L1 C/A only (no GLONASS, Galileo, BeiDou, SBAS, QZSS, no
    second band), measurements without a valid pseudorange dropped, every epoch kept (an
    epoch without GPS becomes an empty RXM-RAW) at the recording's rate and time
    (``iTOW`` = ``rcvTow`` in whole ms; a ``rcvTow`` off the millisecond is moved onto it
    along the Doppler). A phase the u-blox 8 marks unusable (:func:`~groundstation.rules.phase.
    rawx_cp_valid`) is written blank (0) with ``mesQI`` 4 and LLI 3, as a u-blox 6 flags a
    measurement without carrier lock. RXM-RAW has no lock time: the LLI of a usable phase
    carries what the lock time said (:class:`LeaLli`, the rule and why).
  - RXM-SFRBX GPS L1 C/A subframes -> RXM-SFRB (02 11): the ten words parity-checked and
    stripped to their 24 data bits (:func:`~groundstation.offline.ephemeris.
    ublox_sfrbx_data_words`), as a u-blox 6 outputs them; a subframe failing parity is not
    sent (a u-blox 6 does not output it), other systems' navigation data is dropped.
  - TIM-TM2, NAV-SOL, NAV-POSLLH unchanged. NAV-SVINFO of a newer chip: its GPS channels only,
    chip generation u-blox 6. NAV-PVT (u-blox 7 on) becomes NAV-POSLLH when the recording has
    no NAV-POSLLH of its own (the receiver's fix, which the solver checks the base against).
  - Everything else is not sent: NAV-SVIN, NAV-SAT, NAV-CLOCK, RXM-MEASX ... (u-blox 8/9
    messages, or not in the LEA-6T's profile), and the recording's NMEA and RTCM3 (the
    profile's UART1 speaks UBX only; a LEA-6T cannot make RTCM3). A u-blox 6 recording's own
    messages (RXM-RAW, RXM-SFRB, AID-EPH) pass unchanged.
- ``original``: every intact UBX frame of the recording, byte for byte (RXM-RAWX with its lock
  times), so that the same link faults can be compared on both forms. NMEA and RTCM3 between
  the frames are not carried in either form.

Timing: a recording holds no transmission times, so every message is sent as the simulator
sends its own (:class:`~groundstation.sim.messages.Uart`): with the latest epoch before it in the
recording, :data:`~groundstation.sim.stream.OUTPUT_LATENCY_NS` after the epoch, in the
recording's order, at ``baud``. (The recordings' TIM-TM2 come after the epoch that follows the
edge, as the simulator outputs them.)

Link faults (:mod:`groundstation.sim.faults`): a recording has no take-off and landing. The
``flight_dropout_per_min`` outages of the ``seed`` link fall over ``flight_ns`` when given, else
over the whole recording, first epoch to one interval after the last (the jdesbonnet rovers
walk and stop throughout, with no static phase to tell apart, and their marks span the whole
recording). The outages are drawn first, so one seed gives the same outages to both forms.
Mark faults act per mark (:func:`~groundstation.rules.marks.mark_number`: its falling- and
rising-edge records together).

:func:`rewrite` reads a file; :func:`convert_frames` is the sans-I/O part.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from groundstation import jsonio
from groundstation.errors import InputError
from groundstation.gnss.orbit import L1_WAVELENGTH_M
from groundstation.gpstime import NS_PER_WEEK
from groundstation.offline.ephemeris import ublox_sfrbx_data_words
from groundstation.records import Frame, TimeMark
from groundstation.rules.epochs import nominal_interval_ns
from groundstation.rules.marks import mark_number
from groundstation.rules.phase import (
    LLI_HALF_CYCLE,
    LLI_SLIP,
    TRK_HALF_SUB,
    TRK_HALF_VALID,
    TRK_PR_VALID,
    rawx_cp_valid,
)
from groundstation.sim import messages as ubx
from groundstation.sim.faults import (
    DEFAULT_BAUD,
    FaultConfig,
    FaultLog,
    apply_link_faults,
    apply_mark_faults,
)
from groundstation.sim.messages import TimedMessage
from groundstation.sim.stream import OUTPUT_LATENCY_NS
from groundstation.storage.reading import Recording
from groundstation.ubx import layouts as L
from groundstation.ubx.decode import Decoder, message_name
from groundstation.ubx.framer import UbxFramer

Form = Literal["lea6t", "original"]
FORMS: tuple[Form, ...] = ("lea6t", "original")
LOG_SCHEMA = "groundstation.sim.rewrite/1"

LOCK_MAX_MS = 64_500
"""u-blox 8/9 RXM-RAWX ``locktime`` stops counting here (a u-blox 9 may count on to 65 535)."""
LOCK_STEP_MS = 20
"""``locktime`` counts in 20 ms steps (every value in the jdesbonnet recordings is a multiple),
and grows by exactly the epoch interval while the loop holds (all 8 779 unsaturated pairs of
consecutive epochs on 2018-10-09): a shortfall of more than one step is a restart."""
MESQI_CLEAN = 7
MESQI_HALF_CYCLE = 6
MESQI_SLIP = 5
"""u-blox 6 ``mesQI`` < 6: "likely loss of carrier lock in the previous interval"."""
MESQI_CODE_ONLY = 4
"""u-blox 6 ``mesQI`` 4: pseudorange and Doppler usable, carrier phase not."""
LLI_CODE_ONLY = LLI_SLIP | LLI_HALF_CYCLE
"""The LLI of a measurement without a usable phase: a u-blox 6 gives both bits with ``mesQI``
4 and 5 (every such measurement of the NEO-6P recordings in ``../shared/data``; ``mesQI`` 6
comes with bit 1 alone, 7 with none)."""
CHIP_GEN_UBLOX6 = 2
GNSS_GPS = 0
SIG_GPS_L1CA = 0
GPS_SVS = range(1, 33)
WEEK_MS = 604_800_000
MAX_RAW_WEEK = 32_767
"""RXM-RAW's ``week`` is an I2."""

_PR_VALID = TRK_PR_VALID
_HALF_VALID = TRK_HALF_VALID
_HALF_SUB = TRK_HALF_SUB
_CHIP_GEN = L.NAV_SVINFO_GLOBAL.mask("chipGen")
_PVT_FIX_OK = L.NAV_PVT_FLAGS.mask("gnssFixOk")
_TIMED = {L.RXM_RAWX.key, L.RXM_RAW.key}
_PASS_LEA6T = {
    L.RXM_RAW.key, L.RXM_SFRB.key, L.AID_EPH.key, L.TIM_TM2.key, L.NAV_SOL.key,
    L.NAV_POSLLH.key,
}  # fmt: skip
"""Messages a LEA-6T sends as the recording has them (u-blox 6 messages, same layout)."""
_UNFIT = (ValueError, struct.error, ArithmeticError)
"""A frame that passed its checksum but whose payload or values do not fit (as the decoder)."""


@dataclass(frozen=True, slots=True)
class LockEvent:
    """A measurement whose LLI bit 0 the rewrite set, and why.

    ``kind``: ``acquired`` (the satellite's first usable phase in the recording), ``restart``
    (the lock time restarted since its last usable phase), ``phase_gap`` (no usable phase at the
    previous epoch, absent or marked unusable, although the lock time says the loop held),
    ``half_cycle_jump`` (the half cycle was subtracted or added back other than where the
    half-cycle ambiguity was resolved).
    """

    sv: int
    t_gps_ns: int
    kind: str


class LeaLli:
    """The LLI a LEA-6T would have given, from an RXM-RAWX's lock time and tracking status.

    RXM-RAW's LLI is the receiver's own word on its carrier loop since the previous epoch;
    RXM-RAWX says the same with ``locktime`` (how long the loop has held) and ``trkStat``. The
    rule, per GPS satellite with a usable phase at an epoch:

    - bit 0 (lost lock since the previous epoch) when the satellite had no usable phase at the
      previous epoch of the recording (new, absent, or marked unusable), or when its lock time
      fell short of its lock time at its last usable phase plus the time since
      (:data:`LOCK_STEP_MS`, saturating at :data:`LOCK_MAX_MS`), or when ``trkStat``'s
      half-cycle-subtracted bit changed other than at the epoch where the half cycle became
      valid;
    - bit 1 (half cycle not resolved) when ``trkStat``'s half-cycle-valid bit is clear.

    Why the elapsed time and not only a decrease (RTKLIB's rule, :class:`~groundstation.rules.
    phase.RawxPhase`): a loop that restarted just after the previous epoch can hold longer by
    the next than it had held before (320 ms, then 580 ms one second later): only a lock time
    that grew by less than the interval shows it. Why the resolution is not a slip: a u-blox 6
    (and the simulator's LEA-6T) resolves the half cycle by clearing bit 1 and moving the phase
    by half a cycle, with no loss of lock; the u-blox 8 reports the same event as a
    half-cycle-subtracted bit set where the half-cycle-valid bit comes on, and the phase moves
    by the same half cycle. Why a phase gap is a slip even where the lock time held: RXM-RAW
    cannot say "continuous across epochs without a usable phase"; a u-blox 6 flags such epochs
    with ``mesQI`` 4 and both LLI bits (:data:`LLI_CODE_ONLY`), and the phase after them is not
    to be trusted blindly (8 such cases on 2018-10-09, 475 gaps where the lock time restarted
    too).
    """

    def __init__(self) -> None:
        # per satellite: (t ms, lock ms, half-cycle valid, half-cycle subtracted) at its last
        # usable phase
        self._last: dict[int, tuple[int, int, bool, bool]] = {}
        self._usable_before: set[int] = set()
        self._usable_now: set[int] = set()

    def measurement(
        self, sv: int, t_ms: int, lock_ms: int, trk_stat: int
    ) -> tuple[int, str | None]:
        """LLI and lock-event kind (None: no bit 0) of one usable phase (call in stream order,
        then :meth:`end_epoch`)."""
        half_valid = bool(trk_stat & _HALF_VALID)
        half_sub = bool(trk_stat & _HALF_SUB)
        last = self._last.get(sv)
        kind: str | None = None
        if last is None:
            kind = "acquired"
        else:
            last_t, last_lock, last_half_valid, last_sub = last
            expected = min(last_lock + (t_ms - last_t), LOCK_MAX_MS)
            if lock_ms < expected - LOCK_STEP_MS:
                kind = "restart"
            elif sv not in self._usable_before:
                kind = "phase_gap"
            elif half_sub != last_sub and not (half_valid and not last_half_valid):
                kind = "half_cycle_jump"
        self._last[sv] = (t_ms, lock_ms, half_valid, half_sub)
        self._usable_now.add(sv)
        lli = (LLI_SLIP if kind else 0) | (0 if half_valid else LLI_HALF_CYCLE)
        return lli, kind

    def end_epoch(self) -> None:
        self._usable_before, self._usable_now = self._usable_now, set()


@dataclass(slots=True)
class ConversionStats:
    """What the rewrite kept, changed and dropped (counts)."""

    frames_in: int = 0
    epochs: int = 0
    gps_measurements: int = 0
    measurements_sent: int = 0
    no_pseudorange: int = 0
    other_signals: int = 0
    phase_blank: int = 0
    lli_slip: int = 0
    lli_half_cycle: int = 0
    time_moved_epochs: int = 0
    subframes_sent: int = 0
    subframes_parity_failed: int = 0
    subframes_other_systems: int = 0
    converted: dict[str, int] = field(default_factory=dict)
    not_sent: dict[str, int] = field(default_factory=dict)
    undecodable: dict[str, int] = field(default_factory=dict)


@dataclass(slots=True)
class Conversion:
    """The recording's messages as they leave the receiver, before the link.

    Attributes:
        messages: ``(ready_ns, name, frame, tag)`` in the recording's order; ``ready_ns`` is
            the latest epoch's GPS time (``None`` before the first epoch).
        epoch_t_gps_ns: every epoch's time, in order.
        lock_events: where the LLI carries bit 0 (``lea6t`` from RXM-RAWX only).
        stats: the counts.
    """

    messages: list[tuple[int | None, str, bytes, int]] = field(default_factory=list)
    epoch_t_gps_ns: list[int] = field(default_factory=list)
    lock_events: list[LockEvent] = field(default_factory=list)
    stats: ConversionStats = field(default_factory=ConversionStats)


class _Converter:
    def __init__(self, form: Form, has_posllh: bool) -> None:
        self.form = form
        self.has_posllh = has_posllh
        self.out = Conversion()
        self.epoch_ns: int | None = None
        self.lli = LeaLli()
        self.gen9 = False  # an earlier RXM-RAWX carried a second band (rules/phase's limit)
        self.decoder = Decoder()  # TIM-TM2 records, for the mark numbers
        self._converted: Counter[str] = Counter()
        self._not_sent: Counter[str] = Counter()
        self._undecodable: Counter[str] = Counter()

    def finish(self) -> Conversion:
        st = self.out.stats
        st.converted = dict(sorted(self._converted.items()))
        st.not_sent = dict(sorted(self._not_sent.items()))
        st.undecodable = dict(sorted(self._undecodable.items()))
        return self.out

    def _emit(self, name: str, raw: bytes, tag: int = 0) -> None:
        self.out.messages.append((self.epoch_ns, name, raw, tag))

    def _epoch(self, week: int, tow_ns: int) -> None:
        if week > 0:
            self.epoch_ns = week * NS_PER_WEEK + tow_ns
            self.out.epoch_t_gps_ns.append(self.epoch_ns)
        self.out.stats.epochs += 1

    def add(self, frame: Frame) -> None:
        self.out.stats.frames_in += 1
        key = frame.key
        name = message_name(frame.cls, frame.id)
        if self.form == "original":
            self._original(frame, name)
            return
        try:
            if key == L.RXM_RAWX.key:
                self._rawx(frame, name)
            elif key == L.RXM_RAW.key:
                head, _ = L.RXM_RAW.unpack(frame.payload)
                self._epoch(head["week"], head["iTOW"] * 1_000_000)
                self._emit(name, frame.raw, head["iTOW"])
            elif key == L.TIM_TM2.key:
                self._emit(name, frame.raw, self._mark(frame))
            elif key in _PASS_LEA6T:
                sv = frame.payload[1] if key == L.RXM_SFRB.key and len(frame.payload) > 1 else 0
                self._emit(name, frame.raw, sv)
            elif key == L.RXM_SFRBX.key:
                self._sfrbx(frame)
            elif key == L.NAV_SVINFO.key:
                self._svinfo(frame, name)
            elif key == L.NAV_PVT.key and not self.has_posllh:
                self._pvt(frame, name)
            else:
                self._not_sent[name] += 1
        except _UNFIT:  # does not fit its layout or its values: not sent, counted
            self._undecodable[name] += 1

    def _mark(self, frame: Frame) -> int:
        record = self.decoder.decode(frame)
        return mark_number(record) if isinstance(record, TimeMark) else 0

    def _original(self, frame: Frame, name: str) -> None:
        """Every frame as it is; an epoch's time (and a mark's number) read where it can be."""
        key = frame.key
        tag = 0
        try:
            if key == L.RXM_RAWX.key:
                head, _ = L.RXM_RAWX.unpack(frame.payload)
                tag = round(head["rcvTow"] * 1000)
                self._epoch(head["week"], round(head["rcvTow"] * 1e9))
            elif key == L.RXM_RAW.key:
                head, _ = L.RXM_RAW.unpack(frame.payload)
                tag = head["iTOW"]
                self._epoch(head["week"], tag * 1_000_000)
            elif key == L.TIM_TM2.key:
                tag = self._mark(frame)
            elif key in (L.RXM_SFRBX.key, L.RXM_SFRB.key) and len(frame.payload) > 1:
                tag = frame.payload[1]
        except _UNFIT:  # does not fit its layout or its values: sent all the same, counted
            self._undecodable[name] += 1
        self._emit(name, frame.raw, tag)

    # -- measurements -------------------------------------------------------------------------

    def _rawx(self, frame: Frame, name: str) -> None:
        head, rows = L.RXM_RAWX.unpack(frame.payload)
        week = head["week"]
        rcv_tow_s = head["rcvTow"]
        tow_ms = round(rcv_tow_s * 1000)
        if not (0 <= tow_ms < WEEK_MS and week <= MAX_RAW_WEEK):  # before any state changes
            raise ValueError(f"rcvTow {rcv_tow_s} s, week {week}: not an RXM-RAW time")
        self._epoch(week, tow_ms * 1_000_000)
        st = self.out.stats
        # RXM-RAW's time is whole ms: a measurement off it is moved onto it along the Doppler
        # (range rate = -wavelength * Doppler); 1 us of float noise is not a move.
        shift_s = tow_ms / 1000 - rcv_tow_s
        moved = abs(shift_s) > 1e-6
        st.time_moved_epochs += moved
        out = []
        for r in rows:
            if r["gnssId"] != GNSS_GPS or r["sigId"] != SIG_GPS_L1CA:
                st.other_signals += 1
                continue
            st.gps_measurements += 1
            pr, cp, do = r["prMes"], r["cpMes"], r["doMes"]
            if not r["trkStat"] & _PR_VALID or not (math.isfinite(pr) and pr > 0):
                st.no_pseudorange += 1
                continue
            usable = week > 0 and rawx_cp_valid(r["trkStat"], cp, r["cpStdev"], self.gen9)
            if moved:
                pr -= L1_WAVELENGTH_M * do * shift_s
                cp -= do * shift_s
            sv = r["svId"]
            cno = min(r["cno"], 127)
            if not usable:
                st.phase_blank += 1
                out.append((0.0, pr, do, sv, MESQI_CODE_ONLY, cno, LLI_CODE_ONLY))
                continue
            lli, kind = self.lli.measurement(sv, tow_ms, r["locktime"], r["trkStat"])
            if kind is not None:
                st.lli_slip += 1
                self.out.lock_events.append(LockEvent(sv, week * NS_PER_WEEK + tow_ms * 1_000_000,
                                                      kind))
            st.lli_half_cycle += bool(lli & LLI_HALF_CYCLE)
            qi = MESQI_SLIP if lli & LLI_SLIP else MESQI_HALF_CYCLE if lli else MESQI_CLEAN
            out.append((cp, pr, do, sv, qi, cno, lli))
        if week > 0:
            self.lli.end_epoch()
            if any(r["sigId"] > 1 for r in rows):
                self.gen9 = True
        st.measurements_sent += len(out)
        self._converted["RXM-RAWX -> RXM-RAW"] += 1
        self._emit("RXM-RAW", ubx.rxm_raw(tow_ms, week, out), tow_ms)

    # -- navigation data ----------------------------------------------------------------------

    def _sfrbx(self, frame: Frame) -> None:
        head, rows = L.RXM_SFRBX.unpack(frame.payload)
        st = self.out.stats
        if (head["gnssId"] != GNSS_GPS or head["sigId"] != SIG_GPS_L1CA
                or head["svId"] not in GPS_SVS or len(rows) != 10):
            st.subframes_other_systems += 1
            return
        words = ublox_sfrbx_data_words(tuple(r["dwrd"] for r in rows))
        if words is None:
            st.subframes_parity_failed += 1
            return
        st.subframes_sent += 1
        self._converted["RXM-SFRBX -> RXM-SFRB"] += 1
        self._emit("RXM-SFRB", ubx.rxm_sfrb(head["chn"], head["svId"], words), head["svId"])

    # -- the receiver's own solution and tracking ---------------------------------------------

    def _svinfo(self, frame: Frame, name: str) -> None:
        head, rows = L.NAV_SVINFO.unpack(frame.payload)
        if head["globalFlags"] & _CHIP_GEN <= CHIP_GEN_UBLOX6:
            self._emit(name, frame.raw, head["iTOW"])
            return
        gps = [r for r in rows if r["svid"] in GPS_SVS]
        raw = L.NAV_SVINFO.frame(gps, iTOW=head["iTOW"],
                                 globalFlags=L.NAV_SVINFO_GLOBAL.compose(chipGen=CHIP_GEN_UBLOX6))
        self._converted["NAV-SVINFO -> NAV-SVINFO (GPS, u-blox 6)"] += 1
        self._emit(name, raw, head["iTOW"])

    def _pvt(self, frame: Frame, name: str) -> None:
        payload = frame.payload
        size = L.NAV_PVT.head.size
        if len(payload) < size:  # older firmware: the missing trailing fields read as zero
            payload = payload + bytes(size - len(payload))
        head, _ = L.NAV_PVT.unpack(payload)
        if not head["flags"] & _PVT_FIX_OK:
            self._not_sent[f"{name} (no fix)"] += 1
            return
        raw = L.NAV_POSLLH.frame(**{k: head[k] for k in (
            "iTOW", "lon", "lat", "height", "hMSL", "hAcc", "vAcc")})
        self._converted["NAV-PVT -> NAV-POSLLH"] += 1
        self._emit("NAV-POSLLH", raw, head["iTOW"])


def convert_frames(frames: Iterable[Frame], form: Form = "lea6t") -> Conversion:
    """The messages a receiver sends for these frames of a recording (module docstring).

    Raises:
        ValueError: an unknown form.
    """
    if form not in FORMS:
        raise ValueError(f"unknown form {form!r} (one of {', '.join(FORMS)})")
    frames = list(frames)
    has_posllh = any(f.key == L.NAV_POSLLH.key for f in frames)
    conv = _Converter(form, has_posllh)
    for f in frames:
        conv.add(f)
    return conv.finish()


@dataclass(frozen=True, slots=True)
class RewriteConfig:
    """How a recording is replayed.

    Attributes:
        form: ``lea6t`` or ``original`` (:data:`FORMS`).
        faults: the link and mark faults.
        seed: the faults' random seed (same seed, same damage).
        baud: the UART speed that spaces the bytes in time.
        flight_ns: where the ``flight_dropout_per_min`` outages fall (GPS ns); ``None``: the
            whole recording.
    """

    form: Form = "lea6t"
    faults: FaultConfig = field(default_factory=FaultConfig.none)
    seed: int = 1
    baud: int = DEFAULT_BAUD
    flight_ns: tuple[int, int] | None = None


@dataclass(slots=True)
class RewriteResult:
    """A replayed recording.

    Attributes:
        chunks: ``(t_gps_ns, bytes)`` as the ground receives them (faults applied).
        messages: the messages before the link (mark faults not yet applied).
        fault_log: what the faults did.
        log: the JSON log (``--truth``): conversion counts, lock events, faults.
    """

    chunks: list[tuple[int, bytes]]
    messages: list[TimedMessage]
    fault_log: FaultLog
    log: dict[str, Any]

    @property
    def data(self) -> bytes:
        return b"".join(c for _, c in self.chunks)

    def write_log(self, path: str | Path) -> None:
        Path(path).write_bytes(jsonio.dumps(self.log))


def _read_frames(path: str | Path) -> list[Frame]:
    """The intact UBX frames of a recording (``.ubx``, ``.ubx.gz``, ``.mcap``).

    Raises:
        InputError: missing, unreadable, or not a recording.
    """
    framer = UbxFramer()
    frames: list[Frame] = []
    for chunk, t_host_ns in Recording(path).chunks():
        frames += framer.feed(chunk, t_host_ns)
    frames += framer.flush(0)
    return frames


def rewrite(path: str | Path, config: RewriteConfig = RewriteConfig()) -> RewriteResult:
    """Read a recording and replay it (:func:`replay_frames`).

    Raises:
        InputError: the file cannot be read, or holds no measurement epoch with a GPS week.
    """
    return replay_frames(_read_frames(path), config, source=str(path))


def replay_frames(
    frames: Iterable[Frame], config: RewriteConfig = RewriteConfig(), source: str = ""
) -> RewriteResult:
    """Convert frames to ``config.form``, time them on the UART and pass them through the link.

    Raises:
        InputError: no measurement epoch (RXM-RAWX or RXM-RAW) with a GPS week.
    """
    conv = convert_frames(frames, config.form)
    epochs = conv.epoch_t_gps_ns
    if not epochs:
        raise InputError(f"{source or 'recording'}: no measurement epochs with a GPS week "
                         "(RXM-RAWX or RXM-RAW): nothing to replay")
    interval = nominal_interval_ns(epochs) or 1_000_000_000
    span = (epochs[0], epochs[-1] + interval)
    uart = ubx.Uart(config.baud, "rover")
    for ready, name, raw, tag in conv.messages:
        uart.send((epochs[0] if ready is None else ready) + OUTPUT_LATENCY_NS, name, raw, tag)
    messages = uart.out
    rng = np.random.default_rng(np.random.SeedSequence(config.seed))
    sent, mark_faults = apply_mark_faults(messages, config.faults, rng)
    flight = config.flight_ns if config.flight_ns is not None else span
    chunks, fault_log = apply_link_faults(sent, config.faults, rng, config.baud,
                                          flight_ns=flight, span_ns=span)
    fault_log.faults = sorted(mark_faults + fault_log.faults,
                              key=lambda f: f.get("t_gps_ns", f.get("start_gps_ns", 0)))
    log = _log(source, config, conv, span, flight, interval, messages, sent, fault_log)
    return RewriteResult(chunks, messages, fault_log, log)


def link_gaps(
    sent_epoch_tags: list[int], lost: set[int], interval_ms: int
) -> list[dict[str, Any]]:
    """Runs of consecutive epochs the link lost: the epoch before and after (tow ms, ``None``
    at an end), how many, and the seconds between the epochs around them."""
    out: list[dict[str, Any]] = []
    run: list[int] = []
    before: int | None = None
    for tag in [*sent_epoch_tags, None]:
        if tag is not None and tag in lost:
            run.append(tag)
            continue
        if run:
            span_ms = ((tag if tag is not None else run[-1] + interval_ms)
                       - (before if before is not None else run[0] - interval_ms))
            out.append({"after_tow_ms": before, "before_tow_ms": tag, "missing_epochs": len(run),
                        "duration_s": span_ms / 1000})
            run = []
        before = tag
    return out


def _log(
    source: str,
    config: RewriteConfig,
    conv: Conversion,
    span: tuple[int, int],
    flight: tuple[int, int],
    interval_ns: int,
    messages: list[TimedMessage],
    sent: list[TimedMessage],
    fault_log: FaultLog,
) -> dict[str, Any]:
    lost = set(fault_log.epochs_lost_tow_ms)
    epoch_name = "RXM-RAW" if config.form == "lea6t" else "RXM-RAWX"
    epoch_tags = [m.tag for m in messages if m.name in (epoch_name, "RXM-RAW")]
    events = [
        {**asdict(e), "tow_ms": (e.t_gps_ns % NS_PER_WEEK) // 1_000_000,
         "visible": (e.t_gps_ns % NS_PER_WEEK) // 1_000_000 not in lost}
        for e in conv.lock_events
    ]
    slips = [e for e in events if e["kind"] != "acquired"]
    marks = sorted({m.tag for m in messages if m.name == "TIM-TM2"})
    records = Counter(m.tag for m in sent if m.name == "TIM-TM2")
    damaged = Counter(fault_log.marks_lost_in_link)
    # a mark is lost when none of its records arrived (missed by the receiver, or all damaged)
    marks_lost = [n for n in marks if damaged[n] >= records[n]]
    return {
        "schema": LOG_SCHEMA,
        "source": source,
        "form": config.form,
        "seed": config.seed,
        "baud": config.baud,
        "start_gps_ns": span[0],
        "end_gps_ns": span[1],
        "epoch_interval_ms": interval_ns // 1_000_000,
        "flight_gps_ns": list(flight),
        "epochs": len(epoch_tags),
        "marks": len(marks),
        "timemark_messages": sum(records.values()),
        "marks_lost": marks_lost,
        "marks_hit": sorted(n for n in damaged if n not in set(marks_lost)),
        "messages": dict(Counter(m.name for m in messages)),
        "conversion": asdict(conv.stats),
        "lock_events": events,
        "slips": len(slips),
        "slips_hidden": sum(not e["visible"] for e in slips),
        "link_gaps": link_gaps(epoch_tags, lost, interval_ns // 1_000_000),
        "faults_config": asdict(config.faults),
        "faults": fault_log.faults,
        "fault_summary": {k: v for k, v in fault_log.to_json().items() if k != "faults"},
    }
