"""Phase continuity: which measurements carry usable carrier phase, cycle slips, half cycles, LLI.

The one rule for the RINEX loss-of-lock indicator (bit 0 lost lock since the previous epoch,
bit 1 half-cycle ambiguity unresolved), after RTKLIB demo5's u-blox decoder (``ublox.c``
``decode_rxmraw`` and ``decode_rxmrawx``):

- RXM-RAW: the receiver's own ``lli`` bits; a slip flagged while the phase was blank (zero) is
  carried to the signal's next valid phase.
- RXM-RAWX: phase valid when ``trkStat`` bit 1 is set, ``cpMes`` is not -0.5 or 0 and ``cpStdev`` is
  within the receiver class's limit (5 for u-blox 8, 14 once an earlier message carried a
  second-band signal); a slip is a lock-time reset or decrease, a change of the
  half-cycle-subtracted bit or ``cpStdev`` = 15, carried over blank phase to the next valid
  one; a change of the half-cycle-subtracted bit sets bit 0 even on a blank phase; bit 1 = half
  cycle not yet resolved on a valid phase (SBAS: lock time <= 8 s, others ``trkStat`` bit 2).

Two forms of the same rule: :class:`RawPhase` / :class:`RawxPhase` take one message at a time
(the decoder, hence the monitor), :func:`raw_lli` / :func:`rawx_lli` take whole arrays (RINEX).
``tests/unit/test_rules_phase.py`` proves they agree on every real recording.
The operator's events follow from the LLI sequence of a signal (:func:`phase_events`).
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from groundstation.ubx import layouts as L

LLI_SLIP = L.RAW_LLI.mask("slip")
"""LLI bit 0: lost lock since the previous epoch (cycle slip possible)."""
LLI_HALF_CYCLE = L.RAW_LLI.mask("halfCyc")
"""LLI bit 1: half-cycle ambiguity unresolved."""

CPSTD_VALID_GEN8 = 5
"""Largest ``cpStdev`` index of a usable phase from a u-blox 8 (one band)."""
CPSTD_VALID_GEN9 = 14
"""Largest ``cpStdev`` index of a usable phase once the receiver showed a second band."""
CPSTD_SLIP = 15
"""A ``cpStdev`` index this high counts as a slip."""
SBAS_HALF_CYCLE_LOCK_MS = 8000
"""SBAS phase is half-cycle ambiguous until locked this long (``trkStat`` bit 2 says nothing)."""
GNSS_SBAS = 1

TRK_PR_VALID = L.RAWX_TRK_STAT.mask("prValid")
TRK_CP_VALID = L.RAWX_TRK_STAT.mask("cpValid")
TRK_HALF_VALID = L.RAWX_TRK_STAT.mask("halfCyc")
TRK_HALF_SUB = L.RAWX_TRK_STAT.mask("subHalfCyc")

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


# -- streaming form ---------------------------------------------------------------------------


class RawPhase:
    """RXM-RAW LLI, one measurement at a time (per-satellite slip carried over blank phase)."""

    def __init__(self) -> None:
        # signals whose slip was flagged on a blank phase and not yet shown on a valid one
        self._pending: set[Hashable] = set()

    def lli(self, key: Hashable, receiver_lli: int, cp_cyc: float) -> int:
        """The LLI of one measurement of a message with a GPS week (call in stream order).

        Called once per satellite of every epoch: the usual case (phase present, nothing
        pending) costs one set lookup.

        Args:
            key: the signal (the satellite number).
            receiver_lli: the receiver's ``lli`` byte.
            cp_cyc: carrier phase; 0.0 is blank.
        """
        lli = receiver_lli & 3
        pending = self._pending
        if cp_cyc != 0.0:
            if key in pending:
                pending.discard(key)
                return lli | LLI_SLIP
            return lli
        if lli & LLI_SLIP:
            pending.add(key)
        return lli


@dataclass(frozen=True, slots=True)
class RawxPhaseResult:
    """What the rule says about one RXM-RAWX measurement."""

    cp_valid: bool
    lli: int

    @property
    def slip(self) -> bool:
        return bool(self.lli & LLI_SLIP)

    @property
    def half_cycle_unresolved(self) -> bool:
        return bool(self.lli & LLI_HALF_CYCLE)


def rawx_cp_valid(trk_stat: int, cp_cyc: float, cp_stdev_idx: int, gen9: bool) -> bool:
    """Whether an RXM-RAWX carrier phase is usable (else it is written blank)."""
    limit = CPSTD_VALID_GEN9 if gen9 else CPSTD_VALID_GEN8
    return (bool(trk_stat & TRK_CP_VALID) and cp_cyc not in (-0.5, 0.0)
            and (cp_stdev_idx & 15) <= limit)


class RawxPhase:
    """RXM-RAWX LLI, one measurement at a time.

    Call :meth:`measurement` for each measurement of a message with a GPS week, then
    :meth:`end_message` with that message's signal ids (the receiver-class rule looks at them).
    """

    def __init__(self) -> None:
        # per signal: (lock time ms, half-cycle-subtracted bit, slip pending since valid phase)
        self._state: dict[Hashable, tuple[int, int, bool]] = {}
        self.gen9 = False

    def measurement(
        self,
        key: Hashable,
        *,
        gnss: int,
        trk_stat: int,
        lock_ms: int,
        cp_cyc: float,
        cp_stdev_idx: int,
    ) -> RawxPhaseResult:
        """The rule's verdict on one measurement (call in stream order).

        Args:
            key: the signal (e.g. ``(gnssId, svId, sigId)``).
            gnss: u-blox gnssId (SBAS has its own half-cycle rule).
            trk_stat: ``trkStat`` byte.
            lock_ms: ``locktime`` [ms].
            cp_cyc: ``cpMes`` [cycles].
            cp_stdev_idx: ``cpStdev`` index (low 4 bits used).
        """
        cpstd = cp_stdev_idx & 15
        valid = rawx_cp_valid(trk_stat, cp_cyc, cpstd, self.gen9)
        half_sub = 1 if trk_stat & TRK_HALF_SUB else 0
        prev_lock, prev_sub, pending = self._state.get(key, (0, 0, False))
        slip = lock_ms == 0 or lock_ms < prev_lock or half_sub != prev_sub or cpstd >= CPSTD_SLIP
        pending = pending or slip
        if gnss == GNSS_SBAS:
            half_valid = lock_ms > SBAS_HALF_CYCLE_LOCK_MS
        else:
            half_valid = bool(trk_stat & TRK_HALF_VALID)
        lli = (
            (LLI_HALF_CYCLE if valid and not half_valid else 0)
            | (LLI_SLIP if half_sub != prev_sub else 0)
            | (LLI_SLIP if valid and pending else 0)
        )
        self._state[key] = (lock_ms, half_sub, pending and not valid)
        return RawxPhaseResult(valid, lli)

    def end_message(self, max_sig_id: int) -> None:
        """After a message: a second-band signal (sigId > 1) switches to the gen-9 limit."""
        if max_sig_id > 1:
            self.gen9 = True


# -- vectorised form --------------------------------------------------------------------------


def _slip_since_valid(
    ks: IntArray, same_prev: BoolArray, slip: BoolArray, valid: BoolArray
) -> BoolArray:
    """For rows sorted by signal (time order inside), whether a slip happened since the
    signal's last valid phase, this row included (RTKLIB's carried-forward ``lockflag``)."""
    n = ks.size
    pos = np.arange(n)
    group_start = np.maximum.accumulate(np.where(np.concatenate(([True], ~same_prev)), pos, 0))
    last_valid_incl = np.maximum.accumulate(np.where(valid, pos, -1))
    last_valid_excl = np.concatenate(([-1], last_valid_incl[:-1]))
    base = np.maximum(last_valid_excl, group_start - 1)
    csum = np.cumsum(slip.astype(np.int64))
    csum_at = np.where(base >= 0, csum[np.maximum(base, 0)], 0)
    return np.asarray((csum - csum_at) > 0)


def _group_prev(values: IntArray, same_prev: BoolArray, default: int) -> IntArray:
    prev = np.empty_like(values)
    prev[0:1] = default
    prev[1:] = np.where(same_prev, values[:-1], default)
    return prev


def raw_lli(sv: IntArray, receiver_lli: IntArray, cp_cyc: FloatArray) -> IntArray:
    """RXM-RAW LLI of every measurement at once (rows in stream order), as :class:`RawPhase`."""
    lli = receiver_lli.astype(np.int64) & 3
    n = sv.size
    if n == 0:
        return lli
    order = np.argsort(sv, kind="stable")
    ks = sv[order]
    same_prev = ks[1:] == ks[:-1]
    valid = cp_cyc[order] != 0.0
    carried = _slip_since_valid(ks, same_prev, (lli[order] & LLI_SLIP) != 0, valid)
    out = np.empty(n, dtype=np.int64)
    out[order] = lli[order] | np.where(carried & valid, LLI_SLIP, 0)
    return out


def rawx_gen9_before(msg_has_second_band: BoolArray) -> BoolArray:
    """Per message: whether an earlier message carried a second-band signal (gen-9 limit)."""
    return np.concatenate(([False], np.logical_or.accumulate(msg_has_second_band)[:-1]))


def rawx_lli(
    key: IntArray,
    gnss: IntArray,
    trk_stat: IntArray,
    lock_ms: IntArray,
    cp_cyc: FloatArray,
    cp_stdev_idx: IntArray,
    gen9: BoolArray,
) -> tuple[BoolArray, IntArray]:
    """RXM-RAWX phase validity and LLI of every measurement at once, as :class:`RawxPhase`.

    Args:
        key: one integer per signal, rows in stream order.
        gnss, trk_stat, lock_ms, cp_cyc, cp_stdev_idx: the measurement fields.
        gen9: per row, whether the gen-9 ``cpStdev`` limit applies (:func:`rawx_gen9_before`).

    Returns:
        (phase valid, LLI) per row.
    """
    cpstd = cp_stdev_idx.astype(np.int64) & 15
    trk = trk_stat.astype(np.int64)
    lockt = lock_ms.astype(np.int64)
    limit = np.where(gen9, CPSTD_VALID_GEN9, CPSTD_VALID_GEN8)
    valid = ((trk & TRK_CP_VALID) != 0) & (cp_cyc != -0.5) & (cp_cyc != 0.0) & (cpstd <= limit)
    n = key.size
    if n == 0:
        return valid, np.zeros(0, dtype=np.int64)
    sbas = gnss == GNSS_SBAS
    halfv = np.where(sbas, lockt > SBAS_HALF_CYCLE_LOCK_MS, (trk & TRK_HALF_VALID) != 0)
    halfc = ((trk & TRK_HALF_SUB) != 0).astype(np.int64)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    same_prev = ks[1:] == ks[:-1]
    lt, hc, cpv = lockt[order], halfc[order], valid[order]
    prev_lt = _group_prev(lt, same_prev, 0)
    prev_hc = _group_prev(hc, same_prev, 0)
    slip = (lt == 0) | (lt < prev_lt) | (hc != prev_hc) | (cpstd[order] >= CPSTD_SLIP)
    lockflag = _slip_since_valid(ks, same_prev, slip, cpv)
    lli_s = (
        np.where(~halfv[order] & cpv, LLI_HALF_CYCLE, 0)
        | np.where(hc != prev_hc, LLI_SLIP, 0)
        | np.where(cpv & lockflag, LLI_SLIP, 0)
    )
    lli = np.empty(n, dtype=np.int64)
    lli[order] = lli_s
    return valid, lli


# -- what the operator is told ----------------------------------------------------------------

SIGNAL_LOST_AFTER_EPOCHS = 5
"""A signal missing from more than this many received epochs is lost; when it comes back it is
a new signal (RTKLIB's default ``maxout``). A link dropout says nothing about tracking, so only
epochs that arrived count."""


@dataclass(frozen=True, slots=True)
class PhaseEvents:
    """The events one measurement's LLI causes."""

    slip: bool
    half_cycle_set: bool
    half_cycle_cleared: bool


def phase_events(lli: int, half_before: bool, new: bool) -> PhaseEvents:
    """Events from one LLI: bit 0 is a slip; a change of bit 1 sets or clears the half cycle.

    Args:
        lli: the measurement's LLI (this module's rule).
        half_before: the signal's bit 1 at its previous appearance (False when ``new``).
        new: the signal's first appearance, or its first after it was lost
            (:data:`SIGNAL_LOST_AFTER_EPOCHS`): bit 0 then only says the receiver just locked.
    """
    half = bool(lli & LLI_HALF_CYCLE)
    before = half_before and not new
    return PhaseEvents(bool(lli & LLI_SLIP) and not new, half and not before, before and not half)
