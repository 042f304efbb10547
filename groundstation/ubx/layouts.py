"""The UBX protocol as data: message ids and names, payload layouts, flag bits (the one place).

Every layout here is written once, with the u-blox field names and types (as pyubx2 spells
them, so tests compare field for field), and everything else is derived from it: the
``struct`` formats of the scalar decoder (:mod:`groundstation.ubx.decode`), the numpy dtypes of
the vectorised decoder (:mod:`groundstation.ubx.fastraw`) and the encoders of the simulator and
the test builders (:meth:`Message.payload` / :meth:`Message.frame`).

A message is a fixed part (``fields``) optionally followed by a repeated block (``group``)
whose count is a field of the fixed part, a constant, or "as many as the payload holds".
Types are u-blox's: ``U1 I1 X1 U2 I2 X2 U4 I4 X4 R4 R8``; a field with ``count > 1`` is a
run of reserved bytes (skipped when decoding, zero when encoding). ``scale`` is the
resolution pyubx2 applies (value = round(raw * scale, 12)).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from groundstation.ubx.build import build_frame

_STRUCT = {
    "U1": "B", "I1": "b", "X1": "B", "U2": "H", "I2": "h", "X2": "H",
    "U4": "I", "I4": "i", "X4": "I", "R4": "f", "R8": "d",
}  # fmt: skip
_NUMPY = {
    "U1": "u1", "I1": "i1", "X1": "u1", "U2": "<u2", "I2": "<i2", "X2": "<u2",
    "U4": "<u4", "I4": "<i4", "X4": "<u4", "R4": "<f4", "R8": "<f8",
}  # fmt: skip
SCALE_ROUND = 12
"""Decimal places a scaled value is rounded to (pyubx2's ``SCALROUND``)."""


@dataclass(frozen=True, slots=True)
class Bits:
    """The named bits of one flag field: name -> (lowest bit, width)."""

    parts: Mapping[str, tuple[int, int]]

    def mask(self, name: str) -> int:
        """The field's bits in place (e.g. ``0x18`` for TIM-TM2 ``timeBase``)."""
        lo, width = self.parts[name]
        return ((1 << width) - 1) << lo

    def get(self, value: int, name: str) -> int:
        """The value of one named part of ``value``."""
        lo, width = self.parts[name]
        return (value >> lo) & ((1 << width) - 1)

    def compose(self, **values: int) -> int:
        """The flag field with the given parts set (the others zero)."""
        out = 0
        for name, v in values.items():
            lo, width = self.parts[name]
            if not 0 <= v < 1 << width:
                raise ValueError(f"{name}={v} does not fit in {width} bits")
            out |= v << lo
        return out

    def decompose(self, value: int) -> dict[str, int]:
        """Every named part of ``value``."""
        return {name: self.get(value, name) for name in self.parts}


@dataclass(frozen=True, slots=True)
class Field:
    """One payload field: name, u-blox type, pyubx2 scale, repeat count (reserved runs)."""

    name: str
    type: str
    scale: float = 1.0
    count: int = 1

    @property
    def size(self) -> int:
        return int(self.type[1:]) * self.count

    @property
    def is_padding(self) -> bool:
        return self.count > 1


def _format(fields: Iterable[Field]) -> str:
    return "<" + "".join(f"{f.count}x" if f.is_padding else _STRUCT[f.type] for f in fields)


def _dtype(fields: Iterable[Field]) -> np.dtype[Any]:
    return np.dtype(
        [(f.name, "u1", (f.count,)) if f.is_padding else (f.name, _NUMPY[f.type]) for f in fields]
    )


BY_SIZE = -1
"""``Message.count``: the group repeats as many times as the rest of the payload holds."""


@dataclass(frozen=True)
class Message:
    """One UBX message type (output direction) as data.

    Attributes:
        name: as pyubx2 spells it (``RXM-RAWX``).
        cls: class byte.
        id: id byte.
        fields: the fixed part, in payload order.
        group: the repeated block, in payload order (empty if none).
        count: name of the field that holds the number of repeats, a constant, or
            :data:`BY_SIZE`.
        bits: the named bits of flag fields, by field name (a group field's bits apply to
            every repetition).
        min_length: the shortest fixed part accepted (older firmware sends fewer trailing
            fields; the missing ones read as zero, as pyubx2 reads them).
    """

    name: str
    cls: int
    id: int
    fields: tuple[Field, ...]
    group: tuple[Field, ...] = ()
    count: str | int | None = None
    bits: Mapping[str, Bits] = field(default_factory=dict)
    min_length: int | None = None

    @property
    def key(self) -> tuple[int, int]:
        return (self.cls, self.id)

    @cached_property
    def head(self) -> struct.Struct:
        """``struct`` of the fixed part (reserved runs skipped)."""
        return struct.Struct(_format(self.fields))

    @cached_property
    def block(self) -> struct.Struct:
        """``struct`` of one repetition of the group."""
        return struct.Struct(_format(self.group))

    @cached_property
    def head_names(self) -> tuple[str, ...]:
        """Names of the values :attr:`head` unpacks, in order."""
        return tuple(f.name for f in self.fields if not f.is_padding)

    @cached_property
    def block_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.group if not f.is_padding)

    @cached_property
    def head_dtype(self) -> np.dtype[Any]:
        """numpy dtype of the fixed part (reserved runs as ``u1`` arrays)."""
        return _dtype(self.fields)

    @cached_property
    def block_dtype(self) -> np.dtype[Any]:
        return _dtype(self.group)

    @cached_property
    def offsets(self) -> dict[str, int]:
        """Byte offset of each field of the fixed part."""
        out, at = {}, 0
        for f in self.fields:
            out[f.name] = at
            at += f.size
        return out

    @cached_property
    def scales(self) -> dict[str, float]:
        return {f.name: f.scale for f in (*self.fields, *self.group) if f.scale != 1.0}

    def repeats(self, head: Mapping[str, Any], payload_len: int) -> int:
        """How many group repetitions a payload with this fixed part carries."""
        if not self.group:
            return 0
        if self.count == BY_SIZE:
            return (payload_len - self.head.size) // self.block.size
        if isinstance(self.count, int):
            return self.count
        assert self.count is not None
        return int(head[self.count])

    def unpack(self, payload: bytes) -> tuple[dict[str, Any], list[dict[str, Any]]]:
        """Raw (unscaled) field values: the fixed part and each repetition of the group.

        Raises:
            ValueError: the payload is shorter than the layout and its count need.
        """
        size = self.head.size
        if len(payload) < (self.min_length if self.min_length is not None else size):
            raise ValueError(f"{self.name}: {len(payload)} bytes, at least {size} needed")
        if len(payload) < size:
            payload = payload + bytes(size - len(payload))
        head = dict(zip(self.head_names, self.head.unpack_from(payload), strict=True))
        n = self.repeats(head, len(payload))
        end = size + n * self.block.size
        if len(payload) < end:
            raise ValueError(f"{self.name}: {len(payload)} bytes, {n} repeats need {end}")
        rows = [
            dict(zip(self.block_names, values, strict=True))
            for values in self.block.iter_unpack(payload[size:end])
        ] if n else []
        return head, rows

    def scaled(self, name: str, raw: int | float) -> int | float:
        """A field's value with its resolution applied, as pyubx2 computes it."""
        scale = self.scales.get(name)
        return raw if scale is None else round(raw * scale, SCALE_ROUND)

    def payload(self, rows: Iterable[Mapping[str, Any]] = (), **values: Any) -> bytes:
        """Encode a payload: fixed-part fields by name (missing ones zero), group rows.

        A count field that is not given is set to the number of rows.
        """
        rows = list(rows)
        if isinstance(self.count, str) and self.count not in values:
            values[self.count] = len(rows)
        unknown = set(values) - set(self.head_names)
        if unknown:
            raise ValueError(f"{self.name} has no field {sorted(unknown)}")
        out = [self.head.pack(*(values.get(n, 0) for n in self.head_names))]
        out.extend(self.row(**row) for row in rows)
        return b"".join(out)

    def row(self, **values: Any) -> bytes:
        """Encode one repetition of the group, fields by name (missing ones zero)."""
        bad = set(values) - set(self.block_names)
        if bad:
            raise ValueError(f"{self.name} group has no field {sorted(bad)}")
        return self.block.pack(*(values.get(n, 0) for n in self.block_names))

    def frame(self, rows: Iterable[Mapping[str, Any]] = (), **values: Any) -> bytes:
        """A complete frame (sync, header, :meth:`payload`, checksum)."""
        return build_frame(self.cls, self.id, self.payload(rows, **values))


def _f(spec: str) -> tuple[Field, ...]:
    """Fields from ``"name:TYPE name:TYPE*scale name:U1x3"`` (x3: three reserved bytes)."""
    out = []
    for item in spec.split():
        name, t = item.split(":")
        scale = 1.0
        count = 1
        if "*" in t:
            t, s = t.split("*")
            scale = float(s)
        if "x" in t:
            t, c = t.split("x")
            count = int(c)
        if t not in _STRUCT:
            raise ValueError(f"unknown UBX type {t!r} in {item!r}")
        out.append(Field(name, t, scale, count))
    return tuple(out)


# -- flag bits -----------------------------------------------------------------------------------

TIM_TM2_FLAGS = Bits({
    "mode": (0, 1), "run": (1, 1), "newFallingEdge": (2, 1), "timeBase": (3, 2), "utc": (5, 1),
    "time": (6, 1), "newRisingEdge": (7, 1),
})  # fmt: skip
"""TIM-TM2 ``flags``: mode 1 = running; timeBase 0 receiver, 1 GPS, 2 UTC; utc = UTC
available; time = time valid."""
RAWX_REC_STAT = Bits({"leapSec": (0, 1), "clkReset": (1, 1)})
RAWX_TRK_STAT = Bits({
    "prValid": (0, 1), "cpValid": (1, 1), "halfCyc": (2, 1), "subHalfCyc": (3, 1),
})  # fmt: skip
"""RXM-RAWX ``trkStat``: halfCyc = half-cycle valid; subHalfCyc = half cycle subtracted."""
RAWX_PR_STDEV = Bits({"prStd": (0, 4)})
"""RXM-RAWX ``prStdev`` (and ``cpStdev``, ``doStdev``): the index in the low four bits."""
RAWX_CP_STDEV = Bits({"cpStd": (0, 4)})
RAWX_DO_STDEV = Bits({"doStd": (0, 4)})
RAW_LLI = Bits({"slip": (0, 1), "halfCyc": (1, 1)})
"""RXM-RAW ``lli`` (RINEX LLI): bit 0 loss of lock, bit 1 half-cycle ambiguity."""
NAV_SOL_FLAGS = Bits({"gpsfixOK": (0, 1), "diffSoln": (1, 1), "wknSet": (2, 1), "towSet": (3, 1)})
NAV_PVT_FLAGS = Bits({
    "gnssFixOk": (0, 1), "diffSoln": (1, 1), "psmState": (2, 3), "headVehValid": (5, 1),
    "carrSoln": (6, 2),
})  # fmt: skip
NAV_SVINFO_FLAGS = Bits({
    "svUsed": (0, 1), "diffCorr": (1, 1), "orbitAvail": (2, 1), "orbitEph": (3, 1),
    "unhealthy": (4, 1), "orbitAlm": (5, 1), "orbitAop": (6, 1), "smoothed": (7, 1),
})  # fmt: skip
NAV_SVINFO_QUALITY = Bits({"qualityInd": (0, 4)})
NAV_SVINFO_GLOBAL = Bits({"chipGen": (0, 3)})
"""NAV-SVINFO ``globalFlags``: 0 Antaris, 1 u-blox 5, 2 u-blox 6, 3 u-blox 7, 4 u-blox 8."""
NAV_PVT_VALID = Bits({"validDate": (0, 1), "validTime": (1, 1), "fullyResolved": (2, 1),
                      "validMag": (3, 1)})  # fmt: skip
NAV_PVT_FLAGS2 = Bits({"confirmedAvai": (5, 1), "confirmedDate": (6, 1), "confirmedTime": (7, 1)})
NAV_PVT_FLAGS3 = Bits({"invalidLlh": (0, 1), "lastCorrectionAge": (1, 4), "authTime": (13, 1),
                       "nmaFixStatus": (14, 1)})  # fmt: skip
NAV_SAT_FLAGS = Bits({
    "qualityInd": (0, 3), "svUsed": (3, 1), "health": (4, 2), "diffCorr": (6, 1),
    "smoothed": (7, 1), "orbitSource": (8, 3), "ephAvail": (11, 1), "almAvail": (12, 1),
})  # fmt: skip

# -- messages ------------------------------------------------------------------------------------

RXM_RAW = Message(
    "RXM-RAW", 0x02, 0x10,
    _f("iTOW:I4 week:I2 numSV:U1 reserved1:U1"),
    _f("cpMes:R8 prMes:R8 doMes:R4 sv:U1 mesQI:I1 cno:I1 lli:U1"),
    count="numSV", bits={"lli": RAW_LLI},
)  # fmt: skip
RXM_SFRB = Message(
    "RXM-SFRB", 0x02, 0x11, _f("chn:U1 svid:U1"), _f("dwrd:X4"), count=10,
)  # fmt: skip
RXM_SFRBX = Message(
    "RXM-SFRBX", 0x02, 0x13,
    _f("gnssId:U1 svId:U1 sigId:U1 freqId:U1 numWords:U1 chn:U1 version:U1 reserved0:U1"),
    _f("dwrd:U4"), count="numWords",
)  # fmt: skip
RXM_RAWX = Message(
    "RXM-RAWX", 0x02, 0x15,
    _f("rcvTow:R8 week:U2 leapS:I1 numMeas:U1 recStat:X1 version:U1 reserved1:U1x2"),
    _f("prMes:R8 cpMes:R8 doMes:R4 gnssId:U1 svId:U1 sigId:U1 freqId:U1 locktime:U2 cno:U1 "
       "prStdev:X1 cpStdev:X1 doStdev:X1 trkStat:X1 reserved2:U1"),
    count="numMeas",
    bits={"recStat": RAWX_REC_STAT, "trkStat": RAWX_TRK_STAT, "prStdev": RAWX_PR_STDEV,
          "cpStdev": RAWX_CP_STDEV, "doStdev": RAWX_DO_STDEV},
)  # fmt: skip
AID_EPH = Message(
    "AID-EPH", 0x0B, 0x31,
    _f("svid:U4 how:U4"),
    _f(" ".join(f"sf{k}d{j}:U4" for k in (1, 2, 3) for j in range(1, 9))),
    count=BY_SIZE,
)
TIM_TM2 = Message(
    "TIM-TM2", 0x0D, 0x03,
    _f("ch:U1 flags:X1 count:U2 wnR:U2 wnF:U2 towMsR:U4 towSubMsR:U4 towMsF:U4 towSubMsF:U4 "
       "accEst:U4"),
    bits={"flags": TIM_TM2_FLAGS},
)  # fmt: skip
NAV_POSLLH = Message(
    "NAV-POSLLH", 0x01, 0x02,
    _f("iTOW:U4 lon:I4*1e-7 lat:I4*1e-7 height:I4 hMSL:I4 hAcc:U4 vAcc:U4"),
)
NAV_SOL = Message(
    "NAV-SOL", 0x01, 0x06,
    _f("iTOW:U4 fTOW:I4 week:I2 gpsFix:U1 flags:X1 ecefX:I4 ecefY:I4 ecefZ:I4 pAcc:U4 "
       "ecefVX:I4 ecefVY:I4 ecefVZ:I4 sAcc:U4 pDOP:U2*0.01 reserved1:U1 numSV:U1 reserved2:U4"),
    bits={"flags": NAV_SOL_FLAGS},
)  # fmt: skip
NAV_PVT = Message(
    "NAV-PVT", 0x01, 0x07,
    _f("iTOW:U4 year:U2 month:U1 day:U1 hour:U1 min:U1 second:U1 valid:X1 tAcc:U4 nano:I4 "
       "fixType:U1 flags:X1 flags2:X1 numSV:U1 lon:I4*1e-7 lat:I4*1e-7 height:I4 hMSL:I4 "
       "hAcc:U4 vAcc:U4 velN:I4 velE:I4 velD:I4 gSpeed:I4 headMot:I4*1e-5 sAcc:U4 "
       "headAcc:U4*1e-5 pDOP:U2*0.01 flags3:X2 reserved0:U4 headVeh:I4*1e-5 magDec:I2*0.01 "
       "magAcc:U2*0.01"),
    bits={"valid": NAV_PVT_VALID, "flags": NAV_PVT_FLAGS, "flags2": NAV_PVT_FLAGS2,
          "flags3": NAV_PVT_FLAGS3},
    min_length=84,  # u-blox 7 (protocol 14) ends after headAcc/pDOP/reserved
)  # fmt: skip
NAV_SVINFO = Message(
    "NAV-SVINFO", 0x01, 0x30,
    _f("iTOW:U4 numCh:U1 globalFlags:X1 reserved1:U2"),
    _f("chn:U1 svid:U1 flags:X1 quality:X1 cno:U1 elev:I1 azim:I2 prRes:I4"),
    count="numCh",
    bits={"globalFlags": NAV_SVINFO_GLOBAL, "flags": NAV_SVINFO_FLAGS,
          "quality": NAV_SVINFO_QUALITY},
)  # fmt: skip
NAV_SAT = Message(
    "NAV-SAT", 0x01, 0x35,
    _f("iTOW:U4 version:U1 numSvs:U1 reserved0:U1x2"),
    _f("gnssId:U1 svId:U1 cno:U1 elev:I1 azim:I2 prRes:I2*0.1 flags:X4"),
    count="numSvs", bits={"flags": NAV_SAT_FLAGS},
)  # fmt: skip

MESSAGES: dict[tuple[int, int], Message] = {
    m.key: m
    for m in (
        RXM_RAW, RXM_SFRB, RXM_SFRBX, RXM_RAWX, AID_EPH, TIM_TM2,
        NAV_POSLLH, NAV_SOL, NAV_PVT, NAV_SVINFO, NAV_SAT,
    )
}  # fmt: skip
"""The messages decoded here rather than by pyubx2 (the hot ones), by (class, id)."""
