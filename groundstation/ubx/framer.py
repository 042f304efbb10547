"""Sans-I/O UBX framer: bytes in, checksum-verified frames out, nothing intact ever lost.

The framer never trusts the length field of a frame that fails: after a bad checksum, an
impossible length or a frame cut short at the end of the stream it resumes the search at the
byte after the failed sync word. A damaged frame therefore never swallows the frame that
follows it (RTKLIB and pyubx2 skip the claimed length and lose it, often a TIM-TM2).

NMEA sentences and RTCM3 frames interleaved with UBX are recognised (checksum / CRC verified)
and counted, so they are not mistaken for garbage. Every byte is accounted for: it is part of a
valid UBX frame, a valid NMEA sentence, a valid RTCM3 frame, or garbage.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from groundstation.records import Frame

SYNC1 = 0xB5
SYNC2 = 0x62
HEADER_LEN = 6
OVERHEAD = 8  # sync(2) + class + id + length(2) + checksum(2)
DEFAULT_MAX_PAYLOAD = 8192
NMEA_MAX_LEN = 120  # NMEA 0183 says 82; u-blox PUBX sentences run longer
RTCM3_PREAMBLE = 0xD3

_CANDIDATE = re.compile(rb"[\xb5$\xd3]")
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


def _nmea_ok(sentence: bytes) -> bool:
    m = _NMEA.fullmatch(sentence)
    if m is None:
        return False
    x = 0
    for b in m.group(1):
        x ^= b
    return x == int(m.group(2), 16)


@dataclass(frozen=True, slots=True)
class FramerStats:
    """A snapshot of the framer's counters.

    ``garbage_bytes`` counts every byte that is not part of a valid UBX frame, NMEA sentence or
    RTCM3 frame, including the bytes of damaged frames. ``damaged_frames`` counts sync words whose
    frame failed, by cause: bad checksum, length above the maximum, or cut off at end of stream.
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

    Feeding the same bytes in any chunking yields the same frames (only ``t_host_ns`` differs:
    a frame carries the time of the chunk that completed it). Call :meth:`flush` at the end of a
    stream to resolve bytes still waiting for more data.

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
        # Look-ahead while a frame waits for its claimed length: (its stream offset, the stream
        # offset from which the search for a valid inner frame goes on).
        self._lookahead: tuple[int, int] = (-1, 0)

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

    @property
    def stream_offset(self) -> int:
        """Bytes consumed so far (the offset the next fed byte will have)."""
        return self._c.bytes_in

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
        c = self._c
        out: list[Frame] = []
        pos = 0
        search = _CANDIDATE.search
        while pos < n:
            m = search(buf, pos)
            if m is None:
                c.garbage_bytes += n - pos
                pos = n
                break
            i = m.start()
            c.garbage_bytes += i - pos
            pos = i
            lead = buf[i]
            if lead == SYNC1:
                step = self._try_ubx(buf, i, n, t_host_ns, out, final)
            elif lead == RTCM3_PREAMBLE:
                step = self._try_rtcm3(buf, i, n, final) if self._rtcm3 else 1
            else:
                step = self._try_nmea(buf, i, n, final) if self._nmea else 1
            if step == 0:  # need more bytes to decide
                break
            if step < 0:  # not a valid message here: one byte of garbage, search on
                c.garbage_bytes += 1
                pos = i + 1
            else:
                pos = i + step
        if pos:
            del buf[:pos]
            self._base += pos
        return out

    def _try_ubx(
        self, buf: bytearray, i: int, n: int, t_host_ns: int, out: list[Frame], final: bool
    ) -> int:
        """Length of the valid frame at ``i``; 0 = wait for more bytes; -1 = not a frame."""
        c = self._c
        if i + 1 >= n:
            return -1 if final else 0
        if buf[i + 1] != SYNC2:
            return -1
        if i + HEADER_LEN > n:
            if final:
                c.truncated += 1
                return -1
            return 0
        length = buf[i + 4] | (buf[i + 5] << 8)
        if length > self.max_payload:
            c.too_long += 1
            return -1
        end = i + OVERHEAD + length
        if end > n:
            if final:
                c.truncated += 1
                return -1
            if self._valid_frame_inside(buf, i, n):
                # A complete, valid frame inside the claimed span proves this header false
                # (its length field is damage): give up on it now rather than hold every
                # later frame back until the claimed length has arrived.
                c.bad_checksum += 1
                return -1
            return 0
        raw = bytes(buf[i:end])
        ck_a, ck_b = ubx_checksum(memoryview(raw)[2:-2])
        if ck_a != raw[-2] or ck_b != raw[-1]:
            c.bad_checksum += 1
            return -1
        cls, mid = raw[2], raw[3]
        out.append(Frame(cls, mid, raw[6:-2], raw, t_host_ns, self._base + i))
        c.frames += 1
        c.frames_by_type[(cls, mid)] += 1
        c.frame_bytes += len(raw)
        return len(raw)

    def _valid_frame_inside(self, buf: bytearray, i: int, n: int) -> bool:
        """Whether a complete frame with a valid checksum starts after the sync word at ``i``
        (and within the ``n`` bytes at hand). Resumes where the last call stopped."""
        cand = self._base + i
        owner, resume = self._lookahead
        j = i + 2 if owner != cand else max(i + 2, resume - self._base)
        earliest_open: int | None = None
        while True:
            j = buf.find(b"\xb5\x62", j, n)
            if j < 0:
                break
            if j + HEADER_LEN > n:
                earliest_open = j if earliest_open is None else earliest_open
                break
            length = buf[j + 4] | (buf[j + 5] << 8)
            end = j + OVERHEAD + length
            if length <= self.max_payload and end <= n:
                body = memoryview(buf)[j + 2 : end - 2]
                try:
                    ck = ubx_checksum(body)
                finally:
                    body.release()
                if ck == (buf[end - 2], buf[end - 1]):
                    self._lookahead = (-1, 0)
                    return True
            elif length <= self.max_payload and earliest_open is None:
                earliest_open = j  # not complete yet: look at it again next time
            j += 1
        resume_at = earliest_open if earliest_open is not None else max(i + 2, n - 1)
        self._lookahead = (cand, self._base + resume_at)
        return False

    def _try_rtcm3(self, buf: bytearray, i: int, n: int, final: bool) -> int:
        if i + 3 > n:
            return -1 if final else 0
        if buf[i + 1] & 0xFC:
            return -1
        length = ((buf[i + 1] & 0x03) << 8) | buf[i + 2]
        end = i + 3 + length + 3
        if end > n:
            return -1 if final else 0
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

    def _try_nmea(self, buf: bytearray, i: int, n: int, final: bool) -> int:
        stop = buf.find(b"\n", i, i + NMEA_MAX_LEN)
        if stop < 0:
            if n - i < NMEA_MAX_LEN and not final:
                return 0
            return -1
        sentence = bytes(buf[i : stop + 1])
        if not _nmea_ok(sentence):
            return -1
        self._c.nmea_sentences += 1
        self._c.nmea_bytes += len(sentence)
        return len(sentence)


def iter_frames(
    data: bytes, t_host_ns: int = 0, max_payload: int = DEFAULT_MAX_PAYLOAD
) -> list[Frame]:
    """All frames of a complete byte string (convenience for tests and offline tools)."""
    framer = UbxFramer(max_payload)
    frames = framer.feed(data, t_host_ns)
    frames.extend(framer.flush(t_host_ns))
    return frames
