"""Vectorised (numpy) bulk decoding of UBX recordings: frame index, RXM-RAW and RXM-RAWX arrays.

For offline work on whole files, where :class:`~groundstation.ubx.framer.UbxFramer` plus pyubx2
would spend seconds in Python loops. :func:`index_frames` finds every checksum-valid UBX frame
with the same resynchronising rule as the framer (a failed frame never hides the next one);
:func:`decode_rawx` and :func:`decode_raw` turn all RXM-RAWX / RXM-RAW payloads into structured
arrays in one ``np.frombuffer`` each. Field names follow the u-blox protocol specification.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from groundstation.ubx.framer import DEFAULT_MAX_PAYLOAD, OVERHEAD, SYNC1, SYNC2

RXM_RAW = (0x02, 0x10)
RXM_RAWX = (0x02, 0x15)

_BLOCK_BYTES = 1 << 20
"""Checksums are computed over windows of this many candidate-start bytes (bounds memory)."""

RAWX_HEADER = np.dtype(
    [
        ("rcvTow", "<f8"),
        ("week", "<u2"),
        ("leapS", "i1"),
        ("numMeas", "u1"),
        ("recStat", "u1"),
        ("version", "u1"),
        ("reserved1", "u1", (2,)),
    ]
)
RAWX_MEAS = np.dtype(
    [
        ("prMes", "<f8"),
        ("cpMes", "<f8"),
        ("doMes", "<f4"),
        ("gnssId", "u1"),
        ("svId", "u1"),
        ("sigId", "u1"),
        ("freqId", "u1"),
        ("locktime", "<u2"),
        ("cno", "u1"),
        ("prStdev", "u1"),
        ("cpStdev", "u1"),
        ("doStdev", "u1"),
        ("trkStat", "u1"),
        ("reserved2", "u1"),
    ]
)
RAW_HEADER = np.dtype([("iTOW", "<i4"), ("week", "<i2"), ("numSV", "u1"), ("reserved1", "u1")])
RAW_SV = np.dtype(
    [
        ("cpMes", "<f8"),
        ("prMes", "<f8"),
        ("doMes", "<f4"),
        ("sv", "u1"),
        ("mesQI", "i1"),
        ("cno", "i1"),
        ("lli", "u1"),
    ]
)

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class FrameIndex:
    """Where the valid UBX frames of a byte string are, in stream order.

    Attributes:
        start: byte offset of each frame's sync word.
        cls: message class of each frame.
        id: message id of each frame.
        length: payload length of each frame (the frame is ``length + 8`` bytes).
        damaged: sync words that did not start a valid frame (bad checksum, impossible
            length, cut off by the end of the data) and were not inside a valid frame.
    """

    start: IntArray
    cls: npt.NDArray[np.uint8]
    id: npt.NDArray[np.uint8]
    length: IntArray
    damaged: int

    def __len__(self) -> int:
        return int(self.start.size)

    def select(self, key: tuple[int, int]) -> IntArray:
        """Positions (into this index) of the frames of one message type."""
        return np.flatnonzero((self.cls == key[0]) & (self.id == key[1]))

    def payload(self, data: bytes | memoryview, i: int) -> bytes:
        """The payload of frame ``i`` (a copy)."""
        s = int(self.start[i]) + 6
        return bytes(data[s : s + int(self.length[i])])

    def raw(self, data: bytes | memoryview, i: int) -> bytes:
        """The whole frame ``i``, sync word to checksum (a copy)."""
        s = int(self.start[i])
        return bytes(data[s : s + int(self.length[i]) + OVERHEAD])


def _valid_candidates(
    arr: npt.NDArray[np.uint8], lo: int, hi: int, max_payload: int
) -> tuple[IntArray, IntArray, int]:
    """Valid frames whose sync word lies in ``[lo, hi)``: (starts, payload lengths, bad count)."""
    n = arr.size
    stop = min(n, hi + 1)
    seg = arr[lo:stop]
    cand = np.flatnonzero((seg[:-1] == SYNC1) & (seg[1:] == SYNC2)).astype(np.int64) + lo
    if cand.size == 0:
        return cand, cand, 0
    has_header = cand + 6 <= n
    lengths = np.zeros(cand.size, dtype=np.int64)
    hc = cand[has_header]
    lengths[has_header] = arr[hc + 4].astype(np.int64) | (arr[hc + 5].astype(np.int64) << 8)
    ends = cand + OVERHEAD + lengths
    ok = has_header & (lengths <= max_payload) & (ends <= n)
    if not ok.any():
        return cand[:0], cand[:0], int(cand.size)
    # Fletcher checksum of body [s, e) from two prefix sums; uint32 wrap-around keeps the
    # sums right modulo 256, which is all the checksum needs.
    w_lo = int(cand[ok].min()) + 2
    w_hi = int(ends[ok].max()) - 2
    p1 = np.zeros(w_hi - w_lo + 1, dtype=np.uint32)
    np.cumsum(arr[w_lo:w_hi], dtype=np.uint32, out=p1[1:])
    q = np.zeros(p1.size, dtype=np.uint32)
    np.cumsum(p1[1:], dtype=np.uint32, out=q[1:])
    s = cand[ok] + 2 - w_lo
    e = ends[ok] - 2 - w_lo
    ck_a = (p1[e] - p1[s]) & np.uint32(0xFF)
    ck_b = (q[e] - q[s] - (e - s).astype(np.uint32) * p1[s]) & np.uint32(0xFF)
    okc = np.flatnonzero(ok)
    fe = ends[ok]
    good = (ck_a == arr[fe - 2]) & (ck_b == arr[fe - 1])
    valid = okc[good]
    return cand[valid], lengths[valid], int(cand.size - valid.size)


def index_frames(data: bytes | memoryview, max_payload: int = DEFAULT_MAX_PAYLOAD) -> FrameIndex:
    """Index every checksum-valid UBX frame of ``data``.

    A sync word starts a frame if its length is possible and its checksum is right; frames are
    then taken in order, each one starting at or after the end of the one before (so the bytes
    of an accepted frame are never re-read, and a damaged frame never hides the next one: the
    same rule as :class:`~groundstation.ubx.framer.UbxFramer`).

    Args:
        data: the whole recording.
        max_payload: longest payload accepted as possible.

    Returns:
        The frame index.
    """
    arr = np.frombuffer(data, dtype=np.uint8)
    starts: list[IntArray] = []
    lengths: list[IntArray] = []
    bad = 0
    for lo in range(0, max(arr.size - 1, 0), _BLOCK_BYTES):
        s, ln, b = _valid_candidates(arr, lo, lo + _BLOCK_BYTES, max_payload)
        starts.append(s)
        lengths.append(ln)
        bad += b
    start = np.concatenate(starts) if starts else np.zeros(0, dtype=np.int64)
    length = np.concatenate(lengths) if lengths else np.zeros(0, dtype=np.int64)
    end = start + length + OVERHEAD
    if start.size > 1 and bool((start[1:] < end[:-1]).any()):
        keep = np.zeros(start.size, dtype=bool)
        pos = 0
        for i, (s0, e0) in enumerate(zip(start.tolist(), end.tolist(), strict=True)):
            if s0 >= pos:
                keep[i] = True
                pos = e0
        # A valid-looking frame inside an accepted one is payload, not a frame nor damage.
        start, length = start[keep], length[keep]
    # Sync words inside accepted frames are payload bytes, not damage.
    if start.size:
        all_sync = np.flatnonzero((arr[:-1] == SYNC1) & (arr[1:] == SYNC2))
        end = start + length + OVERHEAD
        j = np.searchsorted(start, all_sync, side="right") - 1
        inside = (j >= 0) & (all_sync < end[np.maximum(j, 0)])
        bad = int(all_sync.size - inside.sum())
    cls = arr[start + 2] if start.size else np.zeros(0, dtype=np.uint8)
    mid = arr[start + 3] if start.size else np.zeros(0, dtype=np.uint8)
    return FrameIndex(start, cls, mid, length, bad)


@dataclass(frozen=True, slots=True)
class RawBlock:
    """All raw-measurement messages of one type, as arrays.

    Attributes:
        source: ``"RXM-RAWX"`` or ``"RXM-RAW"``.
        frame: position in the :class:`FrameIndex` of each message kept.
        header: one structured row per message (``RAWX_HEADER`` or ``RAW_HEADER``).
        meas: one structured row per measurement (``RAWX_MEAS`` or ``RAW_SV``).
        epoch: for each measurement, the row of its message in ``header``.
        rejected: positions of messages too short for their declared measurement count.
    """

    source: str
    frame: IntArray
    header: npt.NDArray[Any]
    meas: npt.NDArray[Any]
    epoch: IntArray
    rejected: IntArray

    def subset(self, rows: npt.NDArray[np.bool_]) -> RawBlock:
        """The messages where ``rows`` (one flag per message) is true, as a block."""
        keep_meas = rows[self.epoch]
        new_row = np.cumsum(rows) - 1
        return RawBlock(
            self.source,
            self.frame[rows],
            self.header[rows],
            self.meas[keep_meas],
            new_row[self.epoch[keep_meas]],
            self.rejected,
        )

    @property
    def gps_week(self) -> npt.NDArray[np.int64]:
        return self.header["week"].astype(np.int64)

    @property
    def tow_ns(self) -> npt.NDArray[np.int64]:
        """Time of week of each message in ns (RXM-RAWX ``rcvTow`` rounded to the ns)."""
        if self.source == "RXM-RAWX":
            return np.rint(self.header["rcvTow"] * 1e9).astype(np.int64)
        return self.header["iTOW"].astype(np.int64) * 1_000_000


def _decode_block(
    source: str,
    data: bytes | memoryview,
    index: FrameIndex,
    key: tuple[int, int],
    header_dtype: np.dtype[Any],
    meas_dtype: np.dtype[Any],
    count_field: str,
) -> RawBlock:
    arr = np.frombuffer(data, dtype=np.uint8)
    sel = index.select(key)
    hsize, msize = header_dtype.itemsize, meas_dtype.itemsize
    sel = sel[index.length[sel] >= hsize]
    pstart = index.start[sel] + 6
    hbytes = arr[pstart[:, None] + np.arange(hsize)]
    header = hbytes.reshape(-1).view(header_dtype)
    count = header[count_field].astype(np.int64)
    fits = index.length[sel] >= hsize + msize * count
    rejected = sel[~fits]
    sel, pstart, header, count = sel[fits], pstart[fits], header[fits], count[fits]
    total = int(count.sum())
    epoch = np.repeat(np.arange(sel.size, dtype=np.int64), count)
    first = np.cumsum(count) - count
    k = np.arange(total, dtype=np.int64) - np.repeat(first, count)
    offs = np.repeat(pstart + hsize, count) + k * msize
    mbytes = arr[offs[:, None] + np.arange(msize)]
    meas = mbytes.reshape(-1).view(meas_dtype)
    return RawBlock(source, sel, header.copy(), meas.copy(), epoch, rejected)


def decode_rawx(data: bytes | memoryview, index: FrameIndex) -> RawBlock:
    """Every RXM-RAWX message of ``data`` as arrays (``RAWX_HEADER`` / ``RAWX_MEAS`` rows)."""
    return _decode_block("RXM-RAWX", data, index, RXM_RAWX, RAWX_HEADER, RAWX_MEAS, "numMeas")


def decode_raw(data: bytes | memoryview, index: FrameIndex) -> RawBlock:
    """Every RXM-RAW (u-blox 6) message of ``data`` as arrays (``RAW_HEADER`` / ``RAW_SV``)."""
    return _decode_block("RXM-RAW", data, index, RXM_RAW, RAW_HEADER, RAW_SV, "numSV")


TIM_TM2 = (0x0D, 0x03)
TIM_TM2_DTYPE = np.dtype(
    [
        ("ch", "u1"),
        ("flags", "u1"),
        ("count", "<u2"),
        ("wnR", "<u2"),
        ("wnF", "<u2"),
        ("towMsR", "<u4"),
        ("towSubMsR", "<u4"),
        ("towMsF", "<u4"),
        ("towSubMsF", "<u4"),
        ("accEst", "<u4"),
    ]
)


def decode_timtm2(data: bytes | memoryview, index: FrameIndex) -> tuple[IntArray, npt.NDArray[Any]]:
    """Every TIM-TM2 message as (frame positions, ``TIM_TM2_DTYPE`` rows)."""
    arr = np.frombuffer(data, dtype=np.uint8)
    sel = index.select(TIM_TM2)
    size = TIM_TM2_DTYPE.itemsize
    sel = sel[index.length[sel] >= size]
    rows = arr[(index.start[sel] + 6)[:, None] + np.arange(size)]
    return sel, rows.reshape(-1).view(TIM_TM2_DTYPE).copy()
