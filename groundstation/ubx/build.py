"""Building UBX frames: header, length and checksum around a payload."""

from __future__ import annotations

import struct

from groundstation.ubx.framer import ubx_checksum


def build_frame(cls: int, mid: int, payload: bytes = b"") -> bytes:
    """A complete UBX frame (sync, class, id, little-endian length, payload, checksum)."""
    body = struct.pack("<BBH", cls, mid, len(payload)) + payload
    ck_a, ck_b = ubx_checksum(body)
    return b"\xb5\x62" + body + bytes((ck_a, ck_b))
