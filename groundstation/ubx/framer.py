"""Sans-I/O UBX framer: bytes in, checksum-verified frames out, nothing intact ever lost.

This module owns the resynchronising rule: :func:`scan_ubx` decides it candidate by candidate
(the streaming :class:`UbxFramer`, any chunking), :func:`scan_ubx_arrays` decides the same on
whole arrays (the bulk index of recordings, :mod:`groundstation.ubx.fastraw`);
``tests/unit/test_framer_bulk.py`` holds the two equal. The rule:

- a sync word starts a frame if its length is at most ``max_payload``, its checksum is right,
  and no other valid frame *ends* strictly inside it (a valid frame inside the claimed span
  proves the length field false: that frame is released as soon as it is complete instead of
  being held back until a long false length has arrived, and the result does not depend on how
  the bytes were cut into chunks);
- frames are taken in stream order, each one at or after the end of the one before; a sync word
  that fails is damage and the search resumes at the next byte, so a damaged frame never
  swallows the frame that follows it (RTKLIB and pyubx2 skip the claimed length and lose it,
  often a TIM-TM2).

NMEA sentences and RTCM3 frames interleaved with UBX are recognised (checksum / CRC verified) in
the bytes between UBX frames and counted, so they are not mistaken for garbage; UBX framing never
depends on them. Every byte is accounted for: it is part of a valid UBX frame, a valid NMEA
sentence, a valid RTCM3 frame, or garbage.
"""

from __future__ import annotations

import operator
import re
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from groundstation.records import Frame, positional_constructor

SYNC1 = 0xB5
SYNC2 = 0x62
HEADER_LEN = 6
OVERHEAD = 8  # sync(2) + class + id + length(2) + checksum(2)
DEFAULT_MAX_PAYLOAD = 8192
NMEA_MAX_LEN = 120  # NMEA 0183 says 82; u-blox PUBX sentences run longer
RTCM3_PREAMBLE = 0xD3

_frame = positional_constructor(Frame)  # one per frame: the fast form of Frame(...)
_frame_key = operator.attrgetter("cls", "id")  # a frame's (class, id), counted per type
_CANDIDATE = re.compile(rb"[$\xd3]")
_NMEA = re.compile(rb"\$([A-Z][A-Z0-9]{1,9},[\x20-\x29\x2b-\x7e]*)\*([0-9A-Fa-f]{2})\r?\n")
# Weights n..1 for the Fletcher checksum's second byte, sliced from the end for each length.
_WEIGHTS = np.arange(65535 + 4, 0, -1, dtype=np.int64)


def ubx_checksum(body: bytes | bytearray | memoryview) -> tuple[int, int]:
    """8-bit Fletcher checksum over class, id, length and payload."""
    n = len(body)
    if n < 48:
        ck_a = ck_b = 0
        for b in body:
            ck_a = (ck_a + b) & 0xFF
            ck_b = (ck_b + ck_a) & 0xFF
        return ck_a, ck_b
    arr = np.frombuffer(body, dtype=np.uint8)
    ck_a = int(arr.sum(dtype=np.int64)) & 0xFF
    ck_b = int(np.dot(arr, _WEIGHTS[-n:])) & 0xFF
    return ck_a, ck_b


def _crc24q_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 16
        for _ in range(8):
            crc <<= 1
            if crc & 0x1000000:
                crc ^= 0x1864CFB
        table.append(crc & 0xFFFFFF)
    return table


_CRC24Q = _crc24q_table()


def crc24q(data: bytes | bytearray | memoryview) -> int:
    """The CRC-24Q of RTCM3 frames."""
    crc = 0
    for b in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ _CRC24Q[(crc >> 16) ^ b]
    return crc


def _nmea_checksum_ok(m: re.Match[bytes]) -> bool:
    """Whether a sentence matched by ``_NMEA`` carries the XOR of its body."""
    x = 0
    for b in m.group(1):
        x ^= b
    return x == int(m.group(2), 16)


IntArray = npt.NDArray[np.int64]

_CHECKSUM_WINDOW = 1 << 18
"""Checksums are computed over windows of about this many bytes (bounds memory on whole files)."""
# i mod 256 for every offset i of a window (a window may run a longest frame past its size)
_RAMP = np.tile(np.arange(256, dtype=np.uint8), (_CHECKSUM_WINDOW + 65536) // 256 + 2)


def _checksums_ok(
    arr: npt.NDArray[np.uint8], start: IntArray, end: IntArray
) -> npt.NDArray[np.bool_]:
    """Whether each complete candidate ``[start, end)`` has a right Fletcher checksum.

    Over the bytes ``x[b:e]`` a frame's checksum covers, CK_A is their sum and CK_B the sum of
    the running sums, ``sum((e - i) * x[i])`` = ``e * sum(x[i]) - sum(i * x[i])``: two sums per
    frame (``np.add.reduceat``, vectorised, unlike a running sum) over the bytes and over the
    bytes times their offset. Only their values modulo 256 matter, so everything is computed in
    wrapping uint8 arithmetic with offsets taken modulo 256.
    """
    ok = np.empty(start.size, dtype=bool)
    i, m = 0, start.size
    while i < m:
        if arr.size - int(start[i]) <= _CHECKSUM_WINDOW:  # the rest fits in one window
            j, w_hi = m, arr.size
        else:
            j = max(int(np.searchsorted(start, start[i] + _CHECKSUM_WINDOW, side="left")), i + 1)
            w_hi = int(end[i:j].max())
        s_, e_ = start[i:j], end[i:j]
        w_lo = int(s_[0]) + 2
        win = arr[w_lo:w_hi]
        # reduceat's rows [b0, e0), [e0, b1), [b1, e1) ...: the even ones are the frames (each
        # index is inside the window: a frame's checksum bytes follow its end)
        bounds = np.empty(2 * (j - i), dtype=np.int64)
        bounds[0::2] = s_ + (2 - w_lo)
        bounds[1::2] = e_ - (2 + w_lo)
        ck_a = np.add.reduceat(win, bounds, dtype=np.uint8)[0::2]
        weighted = np.add.reduceat(win * _RAMP[: win.size], bounds, dtype=np.uint8)[0::2]
        ck_b = bounds[1::2].astype(np.uint8) * ck_a - weighted
        ok[i:j] = (ck_a == arr[e_ - 2]) & (ck_b == arr[e_ - 1])
        i = j
    return ok


@dataclass(frozen=True, slots=True)
class UbxScan:
    """What :func:`scan_ubx` decided about ``data[lo:n]``.

    Attributes:
        start: offset of each accepted frame's sync word, in stream order.
        length: payload length of each accepted frame (the frame is ``length + 8`` bytes).
        bad_checksum: sync words that failed their checksum or hold a valid frame inside.
        too_long: sync words whose length field is above the maximum.
        truncated: sync words whose frame the data ended before (only when ``final``).
        hold: where the undecided bytes begin (``n`` when everything is decided): a sync word
            (or a last ``0xB5``) whose frame needs more bytes. Nothing after it is decided.
    """

    start: list[int]
    length: list[int]
    bad_checksum: int
    too_long: int
    truncated: int
    hold: int


_VECTOR_BYTES = 4096
"""From this many bytes on, sync words are found and checksums computed with numpy."""


_Candidates = tuple[list[int], list[int | None], list[bool], list[bool]]
_NO_END = 1 << 62


def _candidates_np(buf: bytes | bytearray, lo: int, n: int, max_payload: int) -> _Candidates:
    """:func:`scan_ubx`'s candidates, found with numpy (long inputs)."""
    c, has_header, _length, e, ok = _candidate_arrays(buf, lo, n, max_payload)
    # the smallest end of the valid candidates after each one
    valid_end = np.where(ok, e, _NO_END)
    after = np.empty(c.size, dtype=np.int64)
    if c.size:
        after[-1] = _NO_END
        after[:-1] = np.minimum.accumulate(valid_end[:0:-1])[::-1]
    ends: list[int | None] = list(e.tolist())
    for k in range(int(np.count_nonzero(has_header)), len(ends)):
        ends[k] = None  # the last sync words, whose header has not arrived
    return c.tolist(), ends, ok.tolist(), (after < e).tolist()


def _candidates_py(buf: bytes | bytearray, lo: int, n: int, max_payload: int) -> _Candidates:
    """:func:`scan_ubx`'s candidates, found with ``bytes.find`` (short inputs: serial reads)."""
    cand: list[int] = []
    ends: list[int | None] = []
    valid: list[bool] = []
    j = buf.find(b"\xb5\x62", lo, n)
    while j >= 0:
        cand.append(j)
        if j + HEADER_LEN > n:
            ends.append(None)
            valid.append(False)
        else:
            length = buf[j + 4] | (buf[j + 5] << 8)
            e = j + OVERHEAD + length
            ends.append(e)
            valid.append(
                length <= max_payload
                and e <= n
                and ubx_checksum(memoryview(buf)[j + 2 : e - 2]) == (buf[e - 2], buf[e - 1])
            )
        j = buf.find(b"\xb5\x62", j + 1, n)
    inside = [False] * len(cand)
    after = _NO_END  # the smallest end of the valid candidates after this one
    for k in range(len(cand) - 1, -1, -1):
        e_or_none = ends[k]
        if e_or_none is not None:
            inside[k] = after < e_or_none
            if valid[k]:
                after = min(after, e_or_none)
    return cand, ends, valid, inside


def scan_ubx(
    data: bytes | bytearray | memoryview, lo: int, n: int, max_payload: int, *, final: bool
) -> UbxScan:
    """The UBX framing rule (see the module docstring) over ``data[lo:n]``.

    Sync words and checksums are found with numpy on long inputs (whole files, big chunks) and
    with ``bytes.find`` / :func:`ubx_checksum` on short ones (serial reads), for speed; the rule
    that decides on them is this one loop.

    Args:
        data: the bytes; ``lo`` must be where an earlier scan's frames or ``hold`` left off.
        lo: first byte to look at.
        n: end of the bytes at hand.
        max_payload: longest payload accepted as possible.
        final: no more bytes will come: a frame still incomplete is truncated.
    """
    buf = data if isinstance(data, (bytes, bytearray)) else bytes(data)
    # Each sync word: its claimed end (None while its header has not arrived), whether it is
    # complete with a right checksum, and whether it holds a valid frame inside: some valid
    # frame after it ends before it does (a valid frame that starts after its end also ends
    # after it).
    if n - lo >= _VECTOR_BYTES:
        cand, ends, valid, insides = _candidates_np(buf, lo, n, max_payload)
    else:
        cand, ends, valid, insides = _candidates_py(buf, lo, n, max_payload)
    starts: list[int] = []
    lengths: list[int] = []
    n_bad = n_long = n_trunc = 0
    hold = n
    pos = lo
    for c, e, ok, inside in zip(cand, ends, valid, insides, strict=True):
        if c < pos:
            continue  # inside an accepted frame: payload, not a frame
        if e is None:  # header not complete
            if final:
                n_trunc += 1
                continue
            hold = c
            break
        if ok:  # length allowed, bytes at hand, right checksum: the usual case, decided here
            if inside:
                n_bad += 1  # a valid frame inside proves the length false
            else:
                starts.append(c)
                lengths.append(e - c - OVERHEAD)
                pos = e
            continue
        if e - c - OVERHEAD > max_payload:
            n_long += 1
            continue
        if inside:
            n_bad += 1  # a valid frame inside proves the length false
            continue
        if e > n:
            if final:
                n_trunc += 1
                continue
            hold = c
            break
        n_bad += 1  # complete, wrong checksum
    if not final and hold == n and n > max(lo, pos) and buf[n - 1] == SYNC1:
        hold = n - 1  # may be the first half of a sync word
    return UbxScan(starts, lengths, n_bad, n_long, n_trunc, hold)


@dataclass(frozen=True, slots=True)
class FramerStats:
    """A snapshot of the framer's counters.

    ``garbage_bytes`` counts every byte that is not part of a valid UBX frame, NMEA sentence or
    RTCM3 frame, including the bytes of damaged frames. ``damaged_frames`` counts sync words whose
    frame failed, by cause: bad checksum (or a valid frame inside its claimed span), length above
    the maximum, or cut off at end of stream.
    """

    bytes_in: int
    frames: int
    frames_by_type: dict[tuple[int, int], int]
    frame_bytes: int
    damaged_frames: int
    bad_checksum: int
    too_long: int
    truncated: int
    garbage_bytes: int
    nmea_sentences: int
    nmea_bytes: int
    rtcm3_frames: int
    rtcm3_bytes: int
    pending_bytes: int


@dataclass(slots=True)
class _Counters:
    bytes_in: int = 0
    frames: int = 0
    frames_by_type: Counter[tuple[int, int]] = field(default_factory=Counter)
    frame_bytes: int = 0
    bad_checksum: int = 0
    too_long: int = 0
    truncated: int = 0
    garbage_bytes: int = 0
    nmea_sentences: int = 0
    nmea_bytes: int = 0
    rtcm3_frames: int = 0
    rtcm3_bytes: int = 0


class UbxFramer:
    """Turns a byte stream cut into arbitrary chunks into verified UBX frames.

    Feeding the same bytes in any chunking yields the same frames and counts (only
    ``t_host_ns`` differs: a frame carries the time of the chunk that completed it); the frames
    are those :func:`~groundstation.ubx.fastraw.index_frames` finds in the whole stream. Call
    :meth:`flush` at the end of a stream to resolve bytes still waiting for more data.

    Args:
        max_payload: a claimed payload length above this is treated as damage.
        recognise_nmea: count valid NMEA sentences instead of calling them garbage.
        recognise_rtcm3: count valid RTCM3 frames instead of calling them garbage.
    """

    def __init__(
        self,
        max_payload: int = DEFAULT_MAX_PAYLOAD,
        *,
        recognise_nmea: bool = True,
        recognise_rtcm3: bool = True,
    ) -> None:
        if not 0 < max_payload <= 65535:
            raise ValueError(f"max_payload must be 1..65535, not {max_payload}")
        self.max_payload = max_payload
        self._nmea = recognise_nmea
        self._rtcm3 = recognise_rtcm3
        self._buf = bytearray()
        self._base = 0  # stream offset of self._buf[0]
        self._c = _Counters()
        # Stream offsets: where the UBX rule resumes (bytes before it are decided) and where the
        # accounting of the bytes between frames (NMEA, RTCM3, garbage) resumes; the second may
        # lag, on an RTCM3 frame that waits for a UBX decision after it.
        self._ubx_at = 0
        self._gap_at = 0

    @property
    def stats(self) -> FramerStats:
        c = self._c
        return FramerStats(
            bytes_in=c.bytes_in,
            frames=c.frames,
            frames_by_type=dict(c.frames_by_type),
            frame_bytes=c.frame_bytes,
            damaged_frames=c.bad_checksum + c.too_long + c.truncated,
            bad_checksum=c.bad_checksum,
            too_long=c.too_long,
            truncated=c.truncated,
            garbage_bytes=c.garbage_bytes,
            nmea_sentences=c.nmea_sentences,
            nmea_bytes=c.nmea_bytes,
            rtcm3_frames=c.rtcm3_frames,
            rtcm3_bytes=c.rtcm3_bytes,
            pending_bytes=len(self._buf),
        )

    def feed(self, chunk: bytes | bytearray | memoryview, t_host_ns: int) -> list[Frame]:
        """Add a chunk; return the frames it completed, in stream order."""
        self._c.bytes_in += len(chunk)
        self._buf += chunk
        return self._scan(t_host_ns, final=False)

    def flush(self, t_host_ns: int = 0) -> list[Frame]:
        """End of stream: frames still recoverable from the waiting bytes; the rest is damage."""
        return self._scan(t_host_ns, final=True)

    def _scan(self, t_host_ns: int, *, final: bool) -> list[Frame]:
        buf = self._buf
        n = len(buf)
        base = self._base
        c = self._c
        if n == 0:
            return []
        scan = scan_ubx(buf, self._ubx_at - base, n, self.max_payload, final=final)
        c.bad_checksum += scan.bad_checksum
        c.too_long += scan.too_long
        c.truncated += scan.truncated
        out: list[Frame] = []
        gap = self._gap_at - base
        if scan.start:
            # one copy of the bytes at hand, then each frame's raw and payload sliced from it
            data = bytes(buf)
            frame = _frame
            append = out.append
            for s, ln in zip(scan.start, scan.length, strict=True):
                if gap < s:
                    self._account_gap(buf, gap, s, hard=True, at_end=False)
                e = s + OVERHEAD + ln
                append(frame(data[s + 2], data[s + 3], data[s + 6 : e - 2], data[s:e], t_host_ns,
                             base + s))
                gap = e
            c.frames_by_type.update(map(_frame_key, out))
        c.frames += len(scan.start)
        c.frame_bytes += sum(scan.length) + OVERHEAD * len(scan.start)
        hold = scan.hold
        if gap < hold:
            gap = self._account_gap(buf, gap, hold, hard=final, at_end=hold == n and not final)
        keep = min(gap, hold)
        self._ubx_at = base + hold
        self._gap_at = base + gap
        if keep:
            del buf[:keep]
            self._base = base + keep
        return out

    def _account_gap(self, buf: bytearray, a: int, b: int, *, hard: bool, at_end: bool) -> int:
        """Count the bytes of ``buf[a:b]`` (between UBX frames) as NMEA, RTCM3 or garbage.

        ``hard``: ``b`` is a frame or the end of the stream, so nothing may cross it. Otherwise
        an item that may cross it waits (``at_end``: ``b`` is where the bytes at hand end).
        Returns where the accounting stopped (``b``, or the start of a waiting item).
        """
        c = self._c
        pos = a
        search = _CANDIDATE.search
        while pos < b:
            m = search(buf, pos, b)
            if m is None:
                c.garbage_bytes += b - pos
                return b
            i = m.start()
            c.garbage_bytes += i - pos
            if buf[i] == RTCM3_PREAMBLE:
                step = self._try_rtcm3(buf, i, b, hard) if self._rtcm3 else -1
            else:
                step = self._try_nmea(buf, i, b, at_end) if self._nmea else -1
            if step == 0:  # needs bytes beyond b
                return i
            if step < 0:  # not a valid message here: one byte of garbage, search on
                c.garbage_bytes += 1
                pos = i + 1
            else:
                pos = i + step
        return b

    def _try_rtcm3(self, buf: bytearray, i: int, b: int, hard: bool) -> int:
        if i + 3 > b:
            return -1 if hard else 0
        if buf[i + 1] & 0xFC:
            return -1
        length = ((buf[i + 1] & 0x03) << 8) | buf[i + 2]
        end = i + 3 + length + 3
        if end > b:
            return -1 if hard else 0
        body = memoryview(buf)[i : end - 3]
        try:
            ok = crc24q(body) == int.from_bytes(buf[end - 3 : end], "big")
        finally:
            body.release()
        if not ok:
            return -1
        self._c.rtcm3_frames += 1
        self._c.rtcm3_bytes += end - i
        return end - i

    def _try_nmea(self, buf: bytearray, i: int, b: int, at_end: bool) -> int:
        # A sentence is printable ASCII: it cannot cross a UBX sync word, so only the end of
        # the bytes at hand can leave it undecided. The pattern ends at the first line feed.
        stop = min(i + NMEA_MAX_LEN, b)
        m = _NMEA.match(buf, i, stop)
        if m is None:
            if at_end and b - i < NMEA_MAX_LEN and buf.find(b"\n", i, stop) < 0:
                return 0
            return -1
        if not _nmea_checksum_ok(m):
            return -1
        size = m.end() - i
        self._c.nmea_sentences += 1
        self._c.nmea_bytes += size
        return size


def iter_frames(
    data: bytes, t_host_ns: int = 0, max_payload: int = DEFAULT_MAX_PAYLOAD
) -> list[Frame]:
    """All frames of a complete byte string (convenience for tests and offline tools)."""
    framer = UbxFramer(max_payload)
    frames = framer.feed(data, t_host_ns)
    frames.extend(framer.flush(t_host_ns))
    return frames


# -- the same rule on whole arrays (offline bulk reading) ---------------------------------------


def _candidate_arrays(
    buf: bytes | bytearray, lo: int, n: int, max_payload: int
) -> tuple[IntArray, npt.NDArray[np.bool_], IntArray, IntArray, npt.NDArray[np.bool_]]:
    """Every sync word of ``buf[lo:n]`` with numpy: (start, header complete, payload length,
    claimed end, complete with a right checksum). Lengths and ends are 0 / ``start + 8`` where
    the header is not complete."""
    arr = np.frombuffer(buf, dtype=np.uint8, count=n)
    # every 0xB5 (one comparison over the data), then the second sync byte at those only
    c = np.flatnonzero(arr[lo : n - 1] == SYNC1).astype(np.int64) + lo
    c = c[arr[c + 1] == SYNC2]
    has_header = c + HEADER_LEN <= n
    length = np.zeros(c.size, dtype=np.int64)
    hc = c[has_header]
    length[has_header] = arr[hc + 4].astype(np.int64) | (arr[hc + 5].astype(np.int64) << 8)
    e = c + OVERHEAD + length
    complete = has_header & (length <= max_payload) & (e <= n)
    ok = np.zeros(c.size, dtype=bool)
    if complete.any():
        ok[complete] = _checksums_ok(arr, c[complete], e[complete])
    return c, has_header, length, e, ok


@dataclass(frozen=True, slots=True)
class UbxScanArrays:
    """What :func:`scan_ubx_arrays` decided: :class:`UbxScan` with numpy arrays."""

    start: IntArray
    length: IntArray
    bad_checksum: int
    too_long: int
    truncated: int
    hold: int


def scan_ubx_arrays(
    data: bytes | bytearray, lo: int, n: int, max_payload: int, *, final: bool
) -> UbxScanArrays:
    """:func:`scan_ubx`'s rule decided on whole arrays: the same frames, counts and ``hold``
    for the same arguments, without a Python step per sync word (for whole recordings and
    large blocks of them; ``tests/unit/test_framer_bulk.py`` holds the two to each other).

    The loop of :func:`scan_ubx` reduces to three facts. A *clean* candidate (complete, right
    checksum, no valid frame ending strictly inside it) is accepted unless it lies inside an
    accepted frame; clean candidates' ends never decrease in stream order (a later clean one
    that ended earlier would end inside the earlier one), so the accepted ones are the greedy
    chain over clean candidates: all of them when none overlaps the one before (the usual
    case, checked in one comparison), else one pass over the clean ones. A candidate inside an
    accepted frame is payload and is not counted. Every other candidate is damage by the first
    test of the loop it fails, or (not ``final``) undecided: ``hold`` is the first of those, and
    nothing after it is decided.
    """
    c, has_header, length, e, ok = _candidate_arrays(data, lo, n, max_payload)
    v_start = c[ok]
    # suffix minimum of valid ends, padded so that "no valid frame after" compares as false
    suffix_min = np.empty(v_start.size + 1, dtype=np.int64)
    suffix_min[-1] = np.iinfo(np.int64).max
    if v_start.size:
        suffix_min[:-1] = np.minimum.accumulate(e[ok][::-1])[::-1]
    inside = suffix_min[np.searchsorted(v_start, c, side="right")] < e
    clean = ok & ~inside
    cs, ce = c[clean], e[clean]
    if cs.size > 1 and bool((cs[1:] < ce[:-1]).any()):
        keep = []
        pos = lo
        for i, (s_, e_) in enumerate(zip(cs.tolist(), ce.tolist(), strict=True)):
            if s_ >= pos:
                keep.append(i)
                pos = e_
        cs, ce = cs[keep], ce[keep]
    # candidates inside an accepted frame (not its own sync word) are payload
    j = np.searchsorted(cs, c, side="right") - 1
    jj = np.maximum(j, 0)
    covered = (j >= 0) & (c < ce[jj]) if cs.size else np.zeros(c.size, dtype=bool)
    live = ~covered  # accepted frames and damage / undecided candidates
    accepted = live & clean
    no_header = ~has_header
    too_long = has_header & (length > max_payload)
    past_end = has_header & ~too_long & ~inside & (e > n)
    undecided = live & (no_header | past_end)
    hold = n
    if not final and undecided.any():
        hold = int(c[np.argmax(undecided)])
        before = c < hold
        live &= before
        accepted &= before
        cs, ce = cs[cs < hold], ce[cs < hold]
    damage = live & ~accepted
    truncated = int((damage & (no_header | past_end)).sum()) if final else 0
    n_long = int((damage & too_long).sum())
    n_bad = int((damage & ~no_header & ~too_long & ~past_end).sum())
    pos = int(ce[-1]) if ce.size else lo
    if not final and hold == n and n > max(lo, pos) and data[n - 1] == SYNC1:
        hold = n - 1  # may be the first half of a sync word
    return UbxScanArrays(cs, ce - cs - OVERHEAD, n_bad, n_long, truncated, hold)


_NMEA_ONLY = re.compile(rb"(\$[\x20-\x7e]*\r?\n)*")


class BetweenFrames:
    """Whether damaged data lies between consecutive frames: bytes between them that are not
    NMEA sentences (what a radio link that drops and garbles bytes leaves). Fed the same chunks
    as the framer, then asked of each frame it yields, in order."""

    KEEP_BYTES = 1 << 21
    """Bytes kept to look back at (a chunk or two; a gap longer than this counts as damage)."""

    def __init__(self) -> None:
        self._recent = bytearray()
        self._start = 0  # stream offset of _recent[0]
        self._frame_end = 0

    def feed(self, chunk: bytes) -> None:
        self._recent += chunk
        if len(self._recent) > 2 * self.KEEP_BYTES:
            cut = len(self._recent) - self.KEEP_BYTES
            del self._recent[:cut]
            self._start += cut

    def damaged_before(self, frame: Frame) -> bool:
        """True when non-NMEA bytes lie between the previous frame and this one."""
        damaged = False
        if frame.offset > self._frame_end:
            lo = self._frame_end - self._start
            gap = bytes(self._recent[max(lo, 0): frame.offset - self._start])
            damaged = lo < 0 or not _NMEA_ONLY.fullmatch(gap)
        self._frame_end = max(self._frame_end, frame.offset + len(frame.raw))
        return damaged
