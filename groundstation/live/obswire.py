"""The measurements a live engine needs, compactly: the payloads of
``groundstation/<station>/obs`` (docs/zenoh.md).

Two kinds of message, little-endian, each starting with its kind and the format's version:

- an epoch (``E``): ``t_gps_ns`` (int64), the number of measurements and flags (bit 0 the
  receiver's clock was reset, bit 1 RXM-RAWX), then per measurement 25 bytes: gnssId, svId,
  pseudorange (m, float64), carrier phase (cycles, float64), Doppler (Hz, float32), C/N0
  (dBHz), the phase rule's LLI (:mod:`groundstation.rules.phase`, as the RINEX files get it)
  and validity bits (pseudorange valid, phase valid, half cycle unresolved, slip, half cycle
  subtracted);
- a navigation subframe (``F``): gnssId, svId, source (RXM-SFRB or RXM-SFRBX), the number of
  words, the words (uint32) as the receiver sent them.

Ten satellites at 5 Hz are 1.3 kB/s (the JSON ``epoch`` topic: 11 kB/s;
benchmarks/RESULTS.md). Everything else in a record (lock times, standard deviations, reception
times) stays in the recording.
"""

from __future__ import annotations

import struct

from groundstation.gpstime import NS_PER_WEEK
from groundstation.records import RawEpoch, SatObs, Subframe

VERSION = 1
EPOCH, SUBFRAME = b"E", b"F"
_EPOCH_HEAD = struct.Struct("<cBqBB")
_SAT = struct.Struct("<BBddfBBB")
_SF_HEAD = struct.Struct("<cBBBBB")
_SOURCES = ("RXM-SFRB", "RXM-SFRBX")
_CLOCK_RESET, _RAWX = 1, 2
_PR_VALID, _CP_VALID, _HALF, _SLIP, _HALF_SUB = 1, 2, 4, 8, 16
MAX_SATS = 255
MAX_WORDS = 255


class ObsWireError(ValueError):
    """A payload that is not one of ours (wrong kind, version or length)."""


def encode_epoch(epoch: RawEpoch) -> bytes:
    """One epoch's measurements (at most :data:`MAX_SATS`)."""
    sats = epoch.sats[:MAX_SATS]
    flags = (_CLOCK_RESET if epoch.clock_reset else 0) | (
        _RAWX if epoch.source == "RXM-RAWX" else 0)
    out = [_EPOCH_HEAD.pack(EPOCH, VERSION, epoch.t_gps_ns, len(sats), flags)]
    for s in sats:
        bits = ((_PR_VALID if s.pr_valid else 0) | (_CP_VALID if s.cp_valid else 0)
                | (_HALF if s.half_cycle_unresolved else 0) | (_SLIP if s.slip else 0)
                | (_HALF_SUB if s.half_cycle_subtracted else 0))
        out.append(_SAT.pack(s.gnss & 0xFF, s.sv & 0xFF, s.pseudorange_m, s.carrier_phase_cyc,
                             s.doppler_hz, max(0, min(255, s.cno_dbhz)), s.lli & 0xFF, bits))
    return b"".join(out)


def encode_subframe(sf: Subframe) -> bytes:
    """One navigation subframe."""
    words = sf.words[:MAX_WORDS]
    return _SF_HEAD.pack(SUBFRAME, VERSION, sf.gnss & 0xFF, sf.sv & 0xFF,
                         _SOURCES.index(sf.source), len(words)) + struct.pack(
        f"<{len(words)}I", *(w & 0xFFFFFFFF for w in words))


def decode(payload: bytes) -> RawEpoch | Subframe:
    """An epoch or a subframe from its payload.

    Raises:
        ObsWireError: not one of ours, or cut short.
    """
    if len(payload) < 2 or payload[1] != VERSION:
        raise ObsWireError(f"not an obs message of version {VERSION} ({len(payload)} bytes)")
    kind = payload[:1]
    if kind == EPOCH:
        if len(payload) < _EPOCH_HEAD.size:
            raise ObsWireError("epoch cut short")
        _, _, t, n, flags = _EPOCH_HEAD.unpack_from(payload)
        if len(payload) != _EPOCH_HEAD.size + n * _SAT.size:
            raise ObsWireError(f"epoch of {n} measurements is {len(payload)} bytes")
        sats = []
        for k in range(n):
            g, sv, pr, cp, do, cno, lli, bits = _SAT.unpack_from(
                payload, _EPOCH_HEAD.size + k * _SAT.size)
            sats.append(SatObs(
                gnss=g, sv=sv, carrier_phase_cyc=cp, pseudorange_m=pr, doppler_hz=do,
                cno_dbhz=cno, mes_qi=None, lli=lli, half_cycle_unresolved=bool(bits & _HALF),
                slip=bool(bits & _SLIP), pr_valid=bool(bits & _PR_VALID),
                cp_valid=bool(bits & _CP_VALID), half_cycle_subtracted=bool(bits & _HALF_SUB)))
        week, tow = divmod(t, NS_PER_WEEK)
        return RawEpoch(int(week), int(tow), tuple(sats),
                        "RXM-RAWX" if flags & _RAWX else "RXM-RAW",
                        clock_reset=bool(flags & _CLOCK_RESET))
    if kind == SUBFRAME:
        if len(payload) < _SF_HEAD.size:
            raise ObsWireError("subframe cut short")
        _, _, g, sv, src, n = _SF_HEAD.unpack_from(payload)
        if src >= len(_SOURCES) or len(payload) != _SF_HEAD.size + 4 * n:
            raise ObsWireError(f"subframe of {n} words is {len(payload)} bytes")
        words = struct.unpack_from(f"<{n}I", payload, _SF_HEAD.size)
        return Subframe(gnss=g, sv=sv, words=tuple(words), source=_SOURCES[src])  # type: ignore[arg-type]
    raise ObsWireError(f"unknown obs message kind {kind!r}")
