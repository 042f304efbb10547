"""Vectorised (numpy) bulk decoding of UBX recordings: frame index, RXM-RAW and RXM-RAWX arrays.

For offline work on whole files, where a record per satellite would cost seconds.
:func:`index_frames` is the framer's rule (:func:`~groundstation.ubx.framer.scan_ubx_arrays`,
the array form of :func:`~groundstation.ubx.framer.scan_ubx`) run over the whole recording;
:func:`index_chunks` does the same over a stream of chunks and keeps only the frames' bytes, so
a recording is read in bounded memory (a 2 GB log of zeros holds nothing);
:func:`decode_rawx` and :func:`decode_raw` turn all RXM-RAWX / RXM-RAW payloads into
structured arrays in one ``np.frombuffer`` each. The dtypes are derived from
:mod:`~groundstation.ubx.layouts` (field names as in the u-blox specification).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from numpy.lib.stride_tricks import sliding_window_view

from groundstation.gpstime import NS_PER_WEEK, leap_seconds_at_gps_array
from groundstation.rules import plausible as P
from groundstation.ubx import layouts as L
from groundstation.ubx.framer import DEFAULT_MAX_PAYLOAD, OVERHEAD, scan_ubx_arrays

RAWX_HEADER = L.RXM_RAWX.head_dtype
RAWX_MEAS = L.RXM_RAWX.block_dtype
RAW_HEADER = L.RXM_RAW.head_dtype
RAW_SV = L.RXM_RAW.block_dtype

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class FrameIndex:
    """Where the valid UBX frames of a byte string are, in stream order.

    Attributes:
        start: byte offset of each frame's sync word.
        cls: message class of each frame.
        id: message id of each frame.
        length: payload length of each frame (the frame is ``length + 8`` bytes).
        damaged: sync words that did not start a frame (bad checksum, a valid frame inside,
            impossible length, cut off by the end of the data) and were not inside a frame:
            the framer's ``damaged_frames`` for the same bytes.
        t_host: each frame's host reception time, the time of the chunk that completed it
            (the framer's ``Frame.t_host_ns``), when the chunks had times (None: they had not).
    """

    start: IntArray
    cls: npt.NDArray[np.uint8]
    id: npt.NDArray[np.uint8]
    length: IntArray
    damaged: int
    t_host: IntArray | None = None

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


def index_frames(data: bytes | memoryview, max_payload: int = DEFAULT_MAX_PAYLOAD) -> FrameIndex:
    """Index every UBX frame of ``data``: the framer's rule
    (:func:`~groundstation.ubx.framer.scan_ubx_arrays`) over the whole recording at once.

    Args:
        data: the whole recording.
        max_payload: longest payload accepted as possible.

    Returns:
        The frame index; its frames are those :class:`~groundstation.ubx.framer.UbxFramer`
        returns for the same bytes in any chunking.
    """
    buf = data if isinstance(data, bytes) else bytes(data)
    scan = scan_ubx_arrays(buf, 0, len(buf), max_payload, final=True)
    return _index(buf, scan.start, scan.length, scan.bad_checksum + scan.too_long + scan.truncated)


def _index(
    data: bytes | bytearray, start: IntArray, length: IntArray, damaged: int,
    t_host: IntArray | None = None,
) -> FrameIndex:
    arr = np.frombuffer(data, dtype=np.uint8)
    cls = arr[start + 2] if start.size else np.zeros(0, dtype=np.uint8)
    mid = arr[start + 3] if start.size else np.zeros(0, dtype=np.uint8)
    return FrameIndex(start, cls, mid, length, damaged, t_host)


BLOCK_BYTES = 1 << 22
""":func:`index_chunks` decides on blocks of at least this many bytes (one numpy pass each)."""


def index_chunks(
    chunks: Iterable[bytes],
    max_payload: int = DEFAULT_MAX_PAYLOAD,
    on_block: Callable[[], None] | None = None,
) -> tuple[bytes, FrameIndex]:
    """The valid frames of a stream of chunks, back to back, and their index.

    The framer's rule is run block by block (``final`` only at the end, the undecided tail
    carried into the next block), so the frames and the damage count are those of
    :func:`index_frames` over the whole stream, while memory holds one block plus the frames
    found: bytes between frames (garbage, NMEA, RTCM3, a sparse file's zeros) are dropped as
    soon as they are decided.

    Args:
        chunks: the recording's bytes in order (any chunking).
        max_payload: longest payload accepted as possible.
        on_block: called after each block (progress).

    Returns:
        The frames' bytes (sync word to checksum, one after the other) and their index
        (``start`` is into those bytes; ``damaged`` counts the whole stream's damage).
    """
    return _index_stream(((c, 0) for c in chunks), max_payload, on_block, timed=False)


def index_timed_chunks(
    chunks: Iterable[tuple[bytes, int]],
    max_payload: int = DEFAULT_MAX_PAYLOAD,
    on_block: Callable[[], None] | None = None,
) -> tuple[bytes, FrameIndex]:
    """:func:`index_chunks` of ``(chunk, t_host_ns)`` pairs (a recording's chunks as read): the
    index also holds each frame's host time (``FrameIndex.t_host``), the time of the chunk that
    completed it, as the framer stamps its frames."""
    return _index_stream(chunks, max_payload, on_block, timed=True)


def _index_stream(
    chunks: Iterable[tuple[bytes, int]],
    max_payload: int,
    on_block: Callable[[], None] | None,
    *,
    timed: bool,
) -> tuple[bytes, FrameIndex]:
    out = bytearray()
    starts: list[IntArray] = []
    lengths: list[IntArray] = []
    times: list[IntArray] = []
    damaged = 0
    buf = bytearray()
    ends: list[int] = []  # where each chunk now in ``buf`` ends, and its time
    ends_t: list[int] = []

    def decide(final: bool) -> None:
        nonlocal damaged, buf, ends, ends_t
        scan = scan_ubx_arrays(buf, 0, len(buf), max_payload, final=final)
        damaged += scan.bad_checksum + scan.too_long + scan.truncated
        if timed and scan.start.size:
            last_byte = scan.start + scan.length + (OVERHEAD - 1)
            k = np.searchsorted(np.asarray(ends, dtype=np.int64), last_byte, side="right")
            times.append(np.asarray(ends_t, dtype=np.int64)[np.minimum(k, len(ends) - 1)])
        if scan.start.size:
            size = scan.length + OVERHEAD
            new_start = len(out) + np.cumsum(size) - size
            # copy runs of back-to-back frames, one slice each
            end = scan.start + size
            brk = np.flatnonzero(scan.start[1:] != end[:-1]) + 1
            run_a = np.concatenate(([0], brk))
            run_b = np.concatenate((brk, [scan.start.size])) - 1
            mv = memoryview(buf)
            for a, b in zip(scan.start[run_a].tolist(), end[run_b].tolist(), strict=True):
                out.extend(mv[a:b])
            mv.release()
            starts.append(new_start)
            lengths.append(scan.length)
        hold = scan.hold
        buf = buf[hold:] if hold < len(buf) else bytearray()
        if timed:
            kept = [(e - hold, t) for e, t in zip(ends, ends_t, strict=True) if e > hold]
            ends, ends_t = [e for e, _ in kept], [t for _, t in kept]

    for chunk, t_host_ns in chunks:
        buf += chunk
        if timed and chunk:
            ends.append(len(buf))
            ends_t.append(t_host_ns)
        if len(buf) >= BLOCK_BYTES:
            decide(False)
            if on_block is not None:
                on_block()
    decide(True)
    data = bytes(out)
    out.clear()
    start = np.concatenate(starts) if starts else np.zeros(0, dtype=np.int64)
    length = np.concatenate(lengths) if lengths else np.zeros(0, dtype=np.int64)
    t_host = None
    if timed:
        t_host = np.concatenate(times) if times else np.zeros(0, dtype=np.int64)
    return data, _index(data, start, length, damaged, t_host)


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
        implausible: positions of messages whose time cannot belong to the session
            (:func:`plausible_epochs`), left out of the rows.
    """

    source: str
    frame: IntArray
    header: npt.NDArray[Any]
    meas: npt.NDArray[Any]
    epoch: IntArray
    rejected: IntArray
    implausible: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def subset(self, rows: npt.NDArray[np.bool_]) -> RawBlock:
        """The messages where ``rows`` (one flag per message) is true, as a block."""
        keep_meas = rows[self.epoch]
        new_row = np.cumsum(rows) - 1
        return RawBlock(
            self.source,
            self.frame[rows],
            take_rows(self.header, rows),
            take_rows(self.meas, keep_meas),
            new_row[self.epoch[keep_meas]],
            self.rejected,
            self.implausible,
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


def take_rows(rows: npt.NDArray[Any], which: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """``rows[which]`` (indices or a mask) of a structured array, copied as whole records.

    numpy copies structured rows field by field under fancy indexing; through a void view of
    the same bytes it is one copy per row (70 000 RXM-RAWX measurements: 6 ms -> 0.4 ms).
    """
    picked: npt.NDArray[Any]
    if rows.dtype.names is None:
        picked = rows[which]
    else:
        void = np.dtype((np.void, rows.dtype.itemsize))
        picked = np.ascontiguousarray(rows).view(void)[which].view(rows.dtype)
    return picked


def _rows(arr: npt.NDArray[np.uint8], starts: IntArray, size: int) -> npt.NDArray[np.uint8]:
    """``size`` bytes from each start, as a (starts x size) view (no copy of the data)."""
    if starts.size == 0:  # also when the data is shorter than one row (no window to take)
        return np.zeros((0, size), dtype=np.uint8)
    return sliding_window_view(arr, size)[starts]


def _decode_block(layout: L.Message, data: bytes | memoryview, index: FrameIndex) -> RawBlock:
    """Every message of one layout with a counted group: fixed parts and group rows as arrays."""
    assert isinstance(layout.count, str)
    header_dtype, meas_dtype, count_field = layout.head_dtype, layout.block_dtype, layout.count
    arr = np.frombuffer(data, dtype=np.uint8)
    sel = index.select(layout.key)
    hsize, msize = header_dtype.itemsize, meas_dtype.itemsize
    sel = sel[index.length[sel] >= hsize]
    pstart = index.start[sel] + 6
    # Rows gathered from a sliding-window view: no (rows x size) int64 offset matrix (for a
    # 10-hour flight's 2 million measurements that matrix alone was 400 MB).
    hbytes = _rows(arr, pstart, hsize)
    header = hbytes.reshape(-1).view(header_dtype)
    count = header[count_field].astype(np.int64)
    fits = index.length[sel] >= hsize + msize * count
    rejected = sel[~fits]
    sel, pstart, header, count = sel[fits], pstart[fits], take_rows(header, fits), count[fits]
    total = int(count.sum())
    epoch = np.repeat(np.arange(sel.size, dtype=np.int64), count)
    first = np.cumsum(count) - count
    k = np.arange(total, dtype=np.int64) - np.repeat(first, count)
    offs = np.repeat(pstart + hsize, count) + k * msize
    mbytes = _rows(arr, offs, msize)
    meas = mbytes.reshape(-1).view(meas_dtype)
    # header and meas are views of arrays gathered above (fancy indexing copies), not of
    # the recording: no further copy (the 10-hour flight's rows are 50 MB)
    return RawBlock(layout.name, sel, header, meas, epoch, rejected)


def decode_rawx(data: bytes | memoryview, index: FrameIndex) -> RawBlock:
    """Every RXM-RAWX message of ``data`` as arrays (``RAWX_HEADER`` / ``RAWX_MEAS`` rows)."""
    return _decode_block(L.RXM_RAWX, data, index)


def decode_raw(data: bytes | memoryview, index: FrameIndex) -> RawBlock:
    """Every RXM-RAW (u-blox 6) message of ``data`` as arrays (``RAW_HEADER`` / ``RAW_SV``)."""
    return _decode_block(L.RXM_RAW, data, index)


TIM_TM2_DTYPE = L.TIM_TM2.head_dtype


def decode_timtm2(data: bytes | memoryview, index: FrameIndex) -> tuple[IntArray, npt.NDArray[Any]]:
    """Every TIM-TM2 message as (frame positions, ``TIM_TM2_DTYPE`` rows)."""
    arr = np.frombuffer(data, dtype=np.uint8)
    sel = index.select(L.TIM_TM2.key)
    size = TIM_TM2_DTYPE.itemsize
    sel = sel[index.length[sel] >= size]
    rows = arr[(index.start[sel] + 6)[:, None] + np.arange(size)]
    return sel, rows.reshape(-1).view(TIM_TM2_DTYPE).copy()


# -- which epochs, marks and fixes can belong to the session (rules/plausible, bulk form) -----


@dataclass(frozen=True, slots=True)
class SessionTimes:
    """The plausibility rule (:mod:`groundstation.rules.plausible`) over a recording: the
    verdicts on its measurement epochs (RXM-RAW and RXM-RAWX together, in stream order, as the
    streaming decoder meets them) and the session's clock before any frame, to judge the time
    marks and fixes the same way.

    Attributes:
        frame: index positions of the epoch messages, in stream order.
        verdicts: the rule's verdicts on them.
        now_ns: the host's clock for frames without a reception time.
        t_host: the index's host times (None: the recording has none).
    """

    frame: IntArray
    verdicts: P.EpochVerdicts
    now_ns: int
    t_host: IntArray | None

    @property
    def implausible(self) -> int:
        """Epochs that failed."""
        return int(self.verdicts.ok.size - np.count_nonzero(self.verdicts.ok))

    def state_at(self, i: int) -> P.ClockState | None:
        """The session's clock when frame ``i`` arrives (after the epochs before it)."""
        k = int(np.searchsorted(self.frame, i, side="left")) - 1
        return self.verdicts.state_after(k)

    def host(self, i: int) -> int | None:
        """Frame ``i``'s reception time as the rule uses it."""
        if self.t_host is None:
            return None
        t = int(self.t_host[i])
        return t if t > P.HOST_TIME_MIN_NS else None

    def mark_problem(
        self, i: int, edges: tuple[tuple[int | None, bool], tuple[int | None, bool]]
    ) -> str | None:
        """:func:`~groundstation.rules.plausible.mark_problem` of the time mark at frame ``i``."""
        return P.mark_problem(self.state_at(i), edges, self.host(i), self.now_ns)

    def fix_problem(self, i: int, itow_ms: int, ftow_ns: int, week: int | None) -> str | None:
        """:func:`~groundstation.rules.plausible.fix_problem` of a fix at frame ``i``."""
        return P.fix_problem(self.state_at(i), itow_ms, ftow_ns, week, self.host(i), self.now_ns)


def _static_epochs(block: RawBlock) -> tuple[IntArray, IntArray, dict[int, str]]:
    """(week, tow_ns, row -> why) of a block's messages: the receiver's ranges (rule 1), as
    :mod:`groundstation.ubx.decode` checks them one message at a time."""
    h = block.header
    n = int(h.size)
    week = h["week"].astype(np.int64)
    if block.source == "RXM-RAWX":
        tow_s = h["rcvTow"].astype(np.float64)
        with np.errstate(invalid="ignore"):
            tow_ok = (tow_s >= 0.0) & (tow_s < P.WEEK_S)
        tow_ns = np.rint(np.where(tow_ok, tow_s, 0.0) * 1e9).astype(np.int64)
        m = block.meas
        finite = P.measurement_rows(m["prMes"], m["cpMes"], m["doMes"])
    else:
        itow = h["iTOW"].astype(np.int64)
        tow_ok = (itow >= 0) & (itow < P.WEEK_MS)
        tow_ns = np.where(tow_ok, itow, 0) * 1_000_000
        m = block.meas
        finite = P.measurement_rows(m["prMes"], m["cpMes"], m["doMes"])
    week_ok = (week == 0) | ((week >= P.MIN_WEEK) & (week <= P.MAX_WEEK))
    all_finite = np.bincount(block.epoch[~finite], minlength=n) == 0
    leap_bad: dict[int, str] = {}
    if block.source == "RXM-RAWX":  # a stated GPS - UTC near the table's
        timed = tow_ok & week_ok & (week != 0)
        t = np.where(timed, week, 0) * NS_PER_WEEK + tow_ns
        known = leap_seconds_at_gps_array(t)
        stated = h["leapS"].astype(np.int64)
        valid = (h["recStat"] & L.RAWX_REC_STAT.mask("leapSec")) != 0
        for r in np.flatnonzero(valid & timed & (np.abs(stated - known) > P.LEAP_SLACK_S)).tolist():
            leap_bad[r] = P.leap_problem(int(stated[r]), int(t[r])) or "GPS - UTC"
    bad = np.flatnonzero(~(tow_ok & week_ok & all_finite))
    reasons: dict[int, str] = {}
    for r in bad.tolist():
        if not tow_ok[r]:
            reasons[r] = (P.tow_s_problem(float(h["rcvTow"][r])) if block.source == "RXM-RAWX"
                          else P.tow_ms_problem(int(h["iTOW"][r]))) or "time of week"
        elif not week_ok[r]:
            reasons[r] = P.week_problem(int(week[r])) or "GPS week"
        else:
            reasons[r] = "a measurement no receiver makes (not finite or out of range)"
    for r, why in leap_bad.items():
        reasons.setdefault(r, why)
    return week, tow_ns, reasons


def plausible_epochs(
    index: FrameIndex, rawx: RawBlock, raw: RawBlock, now_ns: int | None = None
) -> tuple[RawBlock, RawBlock, SessionTimes]:
    """The RXM-RAWX and RXM-RAW messages whose times can belong to the session, and the rule's
    clock over the recording (:class:`SessionTimes`): the verdicts of
    :class:`~groundstation.ubx.decode.Decoder` on the same frames.

    Args:
        index: the recording's frame index (``t_host`` where it has host times).
        rawx: :func:`decode_rawx` of it.
        raw: :func:`decode_raw` of it.
        now_ns: the host's clock for frames without a reception time (default: now).

    Returns:
        The two blocks without their implausible messages (``implausible`` lists them), and
        the session's times.
    """
    now = P.SessionClock(now_ns).now_ns
    weeks, tows, frames, reasons = [], [], [], {}
    offset = 0
    for block in (rawx, raw):
        w, t, why = _static_epochs(block)
        weeks.append(w)
        tows.append(t)
        frames.append(block.frame)
        reasons.update({offset + r: v for r, v in why.items()})
        offset += int(block.frame.size)
    frame_all = np.concatenate(frames).astype(np.int64)
    order = np.argsort(frame_all, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    t_host = index.t_host[frame_all[order]] if index.t_host is not None else None
    verdicts = P.epoch_verdicts(
        np.concatenate(weeks)[order], np.concatenate(tows)[order],
        {int(rank[k]): v for k, v in reasons.items()}, t_host, now,
    )
    ok = verdicts.ok[rank]
    n_x = int(rawx.frame.size)
    out = []
    for block, keep in ((rawx, ok[:n_x]), (raw, ok[n_x:])):
        sub = block if bool(keep.all()) else block.subset(keep)
        out.append(replace(sub, implausible=block.frame[~keep]))
    times = SessionTimes(frame_all[order], verdicts, now, index.t_host)
    return out[0], out[1], times

